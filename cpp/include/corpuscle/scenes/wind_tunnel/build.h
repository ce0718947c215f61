// The wind tunnel built from its parameters (SI values, as python/corpuscle/kinds/
// wind_tunnel.py writes them) and made on an Exec with an index plug-in; D = 2 is the kind
// `wind-tunnel`, D = 3 `wind-tunnel-3d` (the same parameters, with 3-component channel
// corners: z is the periodic span).
#pragma once
#include <memory>
#include <string>
#include <vector>

#include "corpuscle/core/error.h"
#include "corpuscle/dem/build.h"
#include "corpuscle/physics/triangle_mesh.h"
#include "corpuscle/sim/kind_list.h"
#include "corpuscle/sim/params.h"
#include "corpuscle/sim/sim_impl.h"
#include "corpuscle/scenes/wind_tunnel/pipeline.h"

namespace cps::wt {

template <int D>
inline Vec<D> vecd(const ParamSource& p, const std::string& key, const std::string& kind) {
  auto v = p.numbers(key);
  if (int(v.size()) != D) throw Error(kind + ": parameter '" + key + "' needs " + std::to_string(D) + " numbers");
  Vec<D> r;
  for (int k = 0; k < D; ++k) r[k] = float(v[k]);
  return r;
}

// D = 3: the mesh body's triangle records (physics/triangle_mesh.h) from the arrays body_vertices
// (nv, 3; world coordinates) and body_faces (nf, 3; vertex numbers), and their box and centroid
// (the torque's reference point); none: no body. A mesh that is not closed and consistently
// oriented is refused (its fault named)
template <int D>
inline int body_records(const ArraySource* arrays, const std::string& kind, std::vector<float>& rec, float lo[3],
                        float hi[3], Vec3& ref) {
  if (!arrays || !arrays->has("body_vertices")) return 0;
  if (D != 3) throw Error(kind + ": a mesh body needs the 3-D tunnel (wind-tunnel-3d)");
  if (!arrays->has("body_faces")) throw Error(kind + ": body_vertices without body_faces");
  const ArrayView v = arrays->get("body_vertices"), f = arrays->get("body_faces");
  if (v.components != 3 || f.components != 3 || v.count < 4 || f.count < 4)
    throw Error(kind + ": the body's vertices and faces must be (n >= 4, 3)");
  if (v.count >= (1LL << 24)) throw Error(kind + ": the body has too many vertices (at most 2^24)");
  std::vector<double> V(size_t(3 * v.count));
  std::vector<int64_t> F(size_t(3 * f.count));
  for (size_t i = 0; i < V.size(); ++i) V[i] = double(v.data[i]);
  for (size_t i = 0; i < F.size(); ++i) F[i] = int64_t(f.data[i]);
  const std::string bad = write_triangle_records(V.data(), v.count, F.data(), f.count, rec);
  if (!bad.empty()) throw Error(kind + ": the body's mesh: " + bad);
  double c[3] = {0, 0, 0};
  for (int k = 0; k < 3; ++k) {
    lo[k] = 3e38f;
    hi[k] = -3e38f;
  }
  for (long long i = 0; i < v.count; ++i)
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::fmin(lo[k], v.data[3 * i + k]);
      hi[k] = std::fmax(hi[k], v.data[3 * i + k]);
      c[k] += double(v.data[3 * i + k]);
    }
  for (int k = 0; k < 3; ++k) ref[k] = float(c[k] / double(v.count));
  return int(f.count);
}

// the model; the airfoil polygon (counter-clockwise vertices, (n, 2)) comes as an array
template <int D>
inline Model<D> build_model(const ParamSource& p, const ArraySource* arrays) {
  const std::string kind = kind_name<D>();
  Model<D> m{};
  dem::read_spheres<D>(p, kind, m);  // n, radius, mass, the pair law, contact form, integrator, index, dt
  m.recycle_scattered = p.has("recycle_scattered") ? int(p.integer("recycle_scattered") != 0) : 0;
  m.wall = SpringDashpot{p.f("k_wall"), p.f("c_wall")};
  m.wing = SpringDashpot{p.f("k_wing"), p.f("c_wing")};
  m.periodic_z = D == 3 ? 1 : 0;  // the span
  m.lo = vecd<D>(p, "channel_lo", kind);
  m.hi = vecd<D>(p, "channel_hi", kind);
  if (!(m.hi[0] > m.lo[0]) || !(m.hi[1] - m.lo[1] > 2.0f * m.radius))
    throw Error(kind + ": the channel must be wider than a particle");
  // the periodic span: at least two contact reaches, so that a particle meets another at most
  // once (directly or through one image) and never itself (dem/model.h, span_image)
  if (D == 3 && !(m.hi[D - 1] - m.lo[D - 1] >= 4.0f * m.radius * (1.0f + 1e-4f)))
    throw Error(kind + ": the span (channel_hi[2] - channel_lo[2] = " + std::to_string(m.hi[D - 1] - m.lo[D - 1]) +
                ") must be at least 4 particle radii (" + std::to_string(4.0f * m.radius) + ")");
  m.speed = p.f("speed");
  m.thermal = p.f("thermal");
  m.quarter_chord = vecd<2>(p, "quarter_chord", kind);
  m.measure_start = p.number("measure_start");
  m.block_time = p.number("block_time");
  if (!(m.block_time > 0.0)) throw Error(kind + ": block_time must be positive");
  m.seed = unsigned(p.integer("seed") & 0xffffffffLL);
  m.conv_rows = p.has("conv_rows") ? int(p.integer("conv_rows")) : 0;
  if (m.conv_rows < 0 || m.conv_rows > kMaxRows)
    throw Error(kind + ": conv_rows must be 0 to " + std::to_string(kMaxRows));
  if (m.conv_rows > 0) {
    m.conv_ny = p.has("conv_ny") ? int(p.integer("conv_ny")) : m.conv_rows;
    m.conv_y0 = p.f("conv_y0");
    m.conv_dy = p.f("conv_dy");
    m.conv_dx = p.f("conv_dx");
    m.conv_z0 = p.has("conv_z0") ? p.f("conv_z0") : 0.0f;
    m.conv_dz = p.has("conv_dz") ? p.f("conv_dz") : 1.0f;
    if (m.conv_ny <= 0 || m.conv_rows % m.conv_ny != 0 || (D == 2 && m.conv_ny != m.conv_rows))
      throw Error(kind + ": conv_ny must divide conv_rows (and equal it in 2-D)");
    if (!(m.conv_dx > 2.0f * m.radius) || !(m.conv_dy > 2.0f * m.radius) || (D == 3 && !(m.conv_dz > 2.0f * m.radius)))
      throw Error(kind + ": the inflow conveyor's slots must be more than a diameter apart");
  }
  m.n_edges = 0;
  m.bbox = Box2{{{1e30f, 1e30f}}, {{-1e30f, -1e30f}}};
  if (arrays && arrays->has("airfoil")) {
    ArrayView a = arrays->get("airfoil");
    if (a.components != 2 || a.count < 3) throw Error(kind + ": the airfoil array must be (n >= 3, 2)");
    if (a.count > kMaxEdges)
      throw Error(kind + ": the airfoil has " + std::to_string(a.count) + " vertices, at most " +
                  std::to_string(kMaxEdges));
    PolygonVertices P{a.data, int(a.count)};
    polygon_write_edges(P, m.edges);
    m.n_edges = int(a.count);
    m.bbox = polygon_bbox(P);
  }
  std::vector<float> rec;  // (the records themselves are the pipeline's: make_with)
  m.n_tris = body_records<D>(arrays, kind, rec, m.body_lo, m.body_hi, m.body_ref);
  m.body_host = nullptr;
  return m;
}

template <class Exec, class Index, int D>
std::unique_ptr<Sim> make_with(Exec&& ex, const SimRequest& r) {
  using P = Pipeline<std::decay_t<Exec>, Index, D>;
  const std::string kind = kind_name<D>();
  auto m = std::make_unique<Model<D>>(build_model<D>(*r.params, r.arrays));  // 32 KiB: not on the stack
  // the mesh body's records, read by the pipeline's constructor (it builds their tree)
  std::vector<float> body;
  if (m->n_tris > 0) {
    float lo[3], hi[3];
    Vec3 ref;
    body_records<D>(r.arrays, kind, body, lo, hi, ref);
    m->body_host = body.data();
  }
  auto sim = std::make_unique<SimImpl<std::decay_t<Exec>, P>>(std::move(ex), *m, std::vector<typename P::SceneRecord>{P::initial_record(*m)},
                                                              r.device);
  for (const char* name : {"position", "velocity"}) {
    if (!r.arrays || !r.arrays->has(name)) throw Error(kind + ": no initial " + name + " array");
    ArrayView a = r.arrays->get(name);
    if (a.components != D || a.count != m->n)
      throw Error(kind + ": the initial " + name + " array must be (" + std::to_string(m->n) + ", " +
                  std::to_string(D) + ")");
    sim->upload(name, a.data, a.count);
  }
  return sim;
}

// the index plug-ins, the first the default
using Indexes = IndexList<GridIndex, LbvhIndex, AllPairsIndex>;

// the kind of dimension D (wind-tunnel, wind-tunnel-3d) in the list of kinds (sim/kinds.h)
template <int D>
struct Entry {
  static constexpr const char* name = kind_name<D>();
  using Indexes = wt::Indexes;
  template <class Exec>
  static std::unique_ptr<Sim> make(Exec&& ex, const SimRequest& r) {
    return Indexes::with(name, r.index, [&](auto index) {
      return make_with<Exec, decltype(index), D>(std::move(ex), r);
    });
  }
  template <class Exec>
  static double bytes(const SimRequest& r) {
    auto m = std::make_unique<Model<D>>(build_model<D>(*r.params, r.arrays));
    return Indexes::with(name, r.index, [&](auto index) {
      return Pipeline<Exec, decltype(index), D>::bytes_needed(*m);
    });
  }
};

}  // namespace cps::wt
