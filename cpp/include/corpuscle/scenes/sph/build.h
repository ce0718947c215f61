// The SPH box built from its parameters (SI values, as python/corpuscle/kinds/sph_box.py
// writes them) and made on an Exec with an index plug-in.
#pragma once
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "corpuscle/core/error.h"
#include "corpuscle/sim/kind_list.h"
#include "corpuscle/sim/params.h"
#include "corpuscle/sim/sim_impl.h"
#include "corpuscle/scenes/sph/pipeline.h"

namespace cps::sph {

template <int D>
inline Vec<D> vecd(const ParamSource& p, const std::string& key, const char* kind) {
  auto v = p.numbers(key);
  if (int(v.size()) != D) throw Error(std::string(kind) + ": parameter '" + key + "' needs " + std::to_string(D) + " numbers");
  Vec<D> r;
  for (int k = 0; k < D; ++k) r[k] = float(v[k]);
  return r;
}

// the probes' faces and sampling (probe.h) from probe_shape, probe_size, probe_normal (D
// numbers each), probe_samples and probe_interval, one entry per probe; absent: points sampled
// every step (what a scene without face probes writes)
template <int D>
inline void build_probe_faces(Model<D>& m, const ParamSource& p, const char* kind) {
  const std::string k(kind);
  for (int q = 0; q < m.n_probes; ++q) {
    m.probe_shape[q] = kProbePoint;
    m.probe_size[q] = 0.0f;
    m.probe_samples[q] = 1;
    m.probe_interval[q] = 0.0f;
    for (int c = 0; c < D; ++c) m.probe_normal[q * D + c] = c == 0 ? 1.0f : 0.0f;
  }
  if (!p.has("probe_shape")) return;
  const auto shape = p.numbers("probe_shape"), size = p.numbers("probe_size"), normal = p.numbers("probe_normal"),
             samples = p.numbers("probe_samples"), interval = p.numbers("probe_interval");
  const size_t n = size_t(m.n_probes);
  if (shape.size() != n || size.size() != n || samples.size() != n || interval.size() != n || normal.size() != n * D)
    throw Error(k + ": probe_shape, probe_size, probe_samples, probe_interval need one number per probe and "
                    "probe_normal " + std::to_string(D) + " per probe");
  for (int q = 0; q < m.n_probes; ++q) {
    const int sh = int(shape[q]), ns = int(samples[q]);
    if (sh != kProbePoint && sh != kProbeDisc && sh != kProbeSquare && sh != kProbeGauge)
      throw Error(k + ": probe_shape must be 0 (point), 1 (disc), 2 (square) or 3 (gauge), got " +
                  std::to_string(shape[q]));
    if (ns < 1 || ns > kMaxProbeSamples || (sh == kProbePoint && ns != 1) || (sh == kProbeGauge && ns < 2))
      throw Error(k + ": probe_samples must be 1 to " + std::to_string(kMaxProbeSamples) + " (a point: 1, a gauge: 2 or more), got " +
                  std::to_string(samples[q]));
    if (D == 3 && sh == kProbeSquare) {
      const int r = int(std::sqrt(double(ns)) + 0.5);
      if (r * r != ns) throw Error(k + ": a square probe's probe_samples must be a square number, got " + std::to_string(ns));
    }
    if (!(size[q] >= 0.0) || !finite(float(size[q])) || (sh != kProbePoint && !(size[q] > 0.0)))
      throw Error(k + ": probe_size must be positive and finite, got " + std::to_string(size[q]));
    if (!(interval[q] >= 0.0) || !finite(float(interval[q])))
      throw Error(k + ": probe_interval must be >= 0 and finite, got " + std::to_string(interval[q]));
    double n2 = 0.0;
    for (int c = 0; c < D; ++c) n2 += normal[q * D + c] * normal[q * D + c];
    if (!(n2 > 0.0) || !std::isfinite(n2)) throw Error(k + ": probe_normal must be a non-zero finite vector");
    for (int c = 0; c < D; ++c) m.probe_normal[q * D + c] = float(normal[q * D + c] / std::sqrt(n2));
    m.probe_shape[q] = sh;
    m.probe_size[q] = float(size[q]);
    m.probe_samples[q] = ns;
    m.probe_interval[q] = float(interval[q]);
  }
}

template <class KindT>
inline Model<KindT::D> build_model(const ParamSource& p) {
  constexpr int D = KindT::D;
  const char* kind = KindT::name;
  Model<D> m{};
  m.n_fluid = int(p.integer("n_fluid"));
  m.n_wall = int(p.integer("n_wall"));
  if (m.n_fluid <= 0 || m.n_wall < 0) throw Error(std::string(kind) + ": n_fluid must be positive, n_wall >= 0");
  const long long kernel = p.integer("kernel");
  if (kernel < 0 || kernel >= kSphKernelKinds) throw Error(std::string(kind) + ": unknown kernel code " + std::to_string(kernel));
  m.h = p.f("h");
  m.hs = p.f("hs");
  if (!(m.h > 0.0f) || !(m.hs > 0.0f)) throw Error(std::string(kind) + ": h and hs must be positive");
  m.kernels = SphKernelSet<D>::make(SphKernelKind(kernel), m.h);
  m.mass = p.f("mass");
  m.rho0 = p.f("rho0");
  m.c0 = p.f("c0");
  m.gamma = p.f("gamma");
  m.B = tait_stiffness(m.c0, m.rho0, m.gamma);
  m.shift_a = p.has("shifting") ? p.f("shifting") : 0.0f;
  if (!(m.shift_a >= 0.0f) || !finite(m.shift_a))
    throw Error(std::string(kind) + ": shifting must be finite and >= 0, got " + std::to_string(m.shift_a));
  m.p_back = p.has("background_pressure") ? p.f("background_pressure") : 0.0f;
  if (!(m.p_back >= 0.0f) || !finite(m.p_back))
    throw Error(std::string(kind) + ": background_pressure must be finite and >= 0, got " + std::to_string(m.p_back));
  m.tvf = p.has("transport_velocity") ? int(p.integer("transport_velocity")) : 0;
  m.tvf_pb = p.has("transport_pressure") ? p.f("transport_pressure") : 0.0f;
  if ((m.tvf != 0 && m.tvf != 1) || !(m.tvf_pb >= 0.0f) || !finite(m.tvf_pb))
    throw Error(std::string(kind) + ": transport_velocity must be 0 or 1 and transport_pressure finite and >= 0");
  m.viscosity = int(p.integer("viscosity"));
  if (m.viscosity != kArtificialViscosity && m.viscosity != kLaminarViscosity)
    throw Error(std::string(kind) + ": viscosity must be 0 (artificial) or 1 (laminar)");
  m.av = ArtificialViscosity::make(p.f("alpha"), p.f("beta"), m.hs);
  m.lv = LaminarViscosity::make(p.f("nu"), m.hs);
  const long long diffusion = p.integer("diffusion");
  const float delta = p.f("delta");
  const Vec<D> g = vecd<D>(p, "gravity", kind);
  const float gmag = g[D - 1] < 0.0f ? -g[D - 1] : g[D - 1];  // (the vertical: a body force along another axis
                                                              // is no hydrostatic head for the diffusion)
  if (diffusion == 0) m.dd = DensityDiffusion::none();
  else if (diffusion == 1) m.dd = DensityDiffusion::molteni(delta, m.hs, m.c0);
  else if (diffusion == 2) m.dd = DensityDiffusion::fourtakas(delta, m.hs, m.c0, m.rho0, m.gamma, gmag);
  else throw Error(std::string(kind) + ": diffusion must be 0 (none), 1 (Molteni) or 2 (Fourtakas)");
  m.cfl = p.f("cfl");
  m.dt_min = p.f("dt_min");
  m.dt_max = p.f("dt_max");
  m.integrator = int(p.integer("integrator"));
  m.verlet_steps = int(p.integer("verlet_steps"));
  if (m.integrator != kVerlet && m.integrator != kSymplecticEuler)
    throw Error(std::string(kind) + ": integrator must be 0 (Verlet) or 1 (symplectic Euler)");
  if (m.verlet_steps < 1) throw Error(std::string(kind) + ": verlet_steps must be at least 1");
  m.gravity = g;
  m.lo = vecd<D>(p, "box_lo", kind);
  m.hi = vecd<D>(p, "box_hi", kind);
  m.domain_lo = vecd<D>(p, "domain_lo", kind);
  m.domain_hi = vecd<D>(p, "domain_hi", kind);
  const long long periodic = p.has("periodic") ? p.integer("periodic") : 0;
  if (periodic < 0 || periodic >= (1LL << D))
    throw Error(std::string(kind) + ": periodic must be a mask of the " + std::to_string(D) + " axes, got " + std::to_string(periodic));
  m.per = Periodic<D>::make(unsigned(periodic), m.domain_lo, m.domain_hi);
  for (int k = 0; k < D; ++k)
    if (m.per.on(k) && (m.domain_lo[k] != m.lo[k] || m.domain_hi[k] != m.hi[k]))
      throw Error(std::string(kind) + ": a periodic axis's domain must be the box (no wall layers across it)");
  // the lists index's parameters (other indexes: list_radius = h, unused)
  m.list_radius = p.has("list_radius") ? p.f("list_radius") : m.h;
  const float rebuild = p.has("rebuild_distance") ? p.f("rebuild_distance") : 0.0f;
  m.rebuild_disp2 = rebuild * rebuild;
  m.max_neighbors = p.has("max_neighbors") ? int(p.integer("max_neighbors")) : 1;
  if (!(m.list_radius >= m.h) || !finite(m.list_radius))
    throw Error(std::string(kind) + ": list_radius must be at least h, got " + std::to_string(m.list_radius));
  if (!(rebuild >= 0.0f) || !(2.0f * rebuild <= m.list_radius - m.h + 1e-6f * m.h))
    throw Error(std::string(kind) + ": rebuild_distance must be in [0, (list_radius - h) / 2], got " + std::to_string(rebuild));
  if (m.max_neighbors < 1) throw Error(std::string(kind) + ": max_neighbors must be at least 1");
  m.list_delta = p.has("list_delta") ? int(p.integer("list_delta")) : 0;
  if (m.list_delta != 0 && m.list_delta != 1)
    throw Error(std::string(kind) + ": list_delta must be 0 or 1, got " + std::to_string(p.integer("list_delta")));
  if (m.list_delta == 1 && m.max_neighbors < 5)
    throw Error(std::string(kind) + ": delta-coded lists need max_neighbors >= 5 bytes, got " +
                std::to_string(m.max_neighbors));
  m.lanes = p.has("lanes") ? int(p.integer("lanes")) : 0;
  if (m.lanes != 0 && m.lanes != 1 && m.lanes != 2 && m.lanes != 4 && m.lanes != 8)
    throw Error(std::string(kind) + ": lanes must be 0 (automatic), 1, 2, 4 or 8, got " + std::to_string(p.integer("lanes")));
  m.fixed_terms = p.has("fixed_terms") ? int(p.integer("fixed_terms")) : 1;
  m.order_by_id = p.has("order_by_id") ? int(p.integer("order_by_id")) : 0;
  // moving bodies (bodies.h): per body kind, row0, rows, c0 (3), a0 (3, degrees), velocity (3),
  // angular velocity (3, rad/s)
  m.n_moving = p.has("n_moving") ? int(p.integer("n_moving")) : 0;
  m.n_free = 0;
  if (m.n_moving < 0 || m.n_moving > kMaxMovingBodies)
    throw Error(std::string(kind) + ": " + std::to_string(m.n_moving) + " moving bodies, at most " + std::to_string(kMaxMovingBodies));
  if (m.n_moving > 0) {
    constexpr int per = 15;
    auto bm = p.numbers("body_motion");
    if (int(bm.size()) != per * m.n_moving)
      throw Error(std::string(kind) + ": body_motion needs " + std::to_string(per) + " numbers a moving body");
    for (int b = 0; b < m.n_moving; ++b) {
      const double* q = bm.data() + per * b;
      BodyMotion& mo = m.motion[b];
      mo.kind = int(q[0]);
      if (mo.kind != kBodyVelocity && mo.kind != kBodyTable && mo.kind != kBodyFree)
        throw Error(std::string(kind) + ": body_motion kind must be 1 (velocity), 2 (table) or 3 (free)");
      mo.row0 = int(q[1]);
      mo.rows = int(q[2]);
      for (int k = 0; k < 3; ++k) {
        mo.c0[k] = q[3 + k];
        mo.a0[k] = q[6 + k];
        mo.vel[k] = q[9 + k];
        mo.omega[k] = q[12 + k];
      }
      mo.mass = 0.0;
      for (int k = 0; k < 9; ++k) mo.inertia[k] = 0.0;
      mo.w0 = mo.nw = 0;
      if (mo.kind == kBodyFree) m.n_free += 1;
    }
  }
  // free bodies (bodies.h): per moving body its mass and inertia in its own frame (10 numbers;
  // read for the free ones), and the tank's contact: r0 (m), k (1/s^2), c (1/s)
  if (m.n_free > 0) {
    auto bf = p.numbers("body_free");
    if (int(bf.size()) != 10 * m.n_moving)
      throw Error(std::string(kind) + ": body_free needs 10 numbers a moving body (mass, inertia 3 x 3)");
    for (int b = 0; b < m.n_moving; ++b) {
      BodyMotion& mo = m.motion[b];
      if (mo.kind != kBodyFree) continue;
      mo.mass = bf[10 * b];
      for (int k = 0; k < 9; ++k) mo.inertia[k] = bf[10 * b + 1 + k];
      if (!(mo.mass > 0.0) || !(mo.inertia[0] > 0.0) || !(mo.inertia[4] > 0.0) || !(mo.inertia[8] > 0.0))
        throw Error(std::string(kind) + ": free body " + std::to_string(b) + " needs a positive mass and inertia");
    }
    auto bc = p.numbers("body_contact");
    if (bc.size() != 3 || !(bc[0] >= 0.0) || !(bc[1] >= 0.0) || !(bc[2] >= 0.0))
      throw Error(std::string(kind) + ": body_contact needs 3 numbers >= 0 (r0, k, c)");
    m.contact_r0 = float(bc[0]);
    m.contact_k = float(bc[1]);
    m.contact_c = float(bc[2]);
  }
  auto probes = p.numbers("probes");
  if (probes.size() % D != 0) throw Error(std::string(kind) + ": probes need " + std::to_string(D) + " numbers each");
  m.n_probes = int(probes.size() / D);
  if (m.n_probes > kMaxProbes)
    throw Error(std::string(kind) + ": " + std::to_string(m.n_probes) + " probes, at most " + std::to_string(kMaxProbes));
  for (size_t k = 0; k < probes.size(); ++k) m.probes[k] = float(probes[k]);
  build_probe_faces(m, p, kind);
  return m;
}

template <class Exec, class Index, class KindT>
std::unique_ptr<Sim> make_with(Exec&& ex, const SimRequest& r) {
  using P = Pipeline<std::decay_t<Exec>, Index, KindT>;
  constexpr int D = KindT::D;
  const std::string kind = KindT::name;
  auto m = std::make_unique<Model<D>>(build_model<KindT>(*r.params));
  auto sim = std::make_unique<SimImpl<std::decay_t<Exec>, P>>(std::move(ex), *m,
                                                              std::vector<Scene>{P::initial_record(*m)}, r.device);
  struct Want {
    const char* name;
    int comps;
    long long count;
  };
  const Want wants[] = {{"position", D, m->n_fluid},     {"velocity", D, m->n_fluid},
                        {"density", 1, m->n_fluid},      {"wall_position", D, m->n_wall},
                        {"wall_density", 1, m->n_wall}};
  for (const Want& w : wants) {
    if (!r.arrays || !r.arrays->has(w.name)) throw Error(kind + ": no initial " + w.name + " array");
    ArrayView a = r.arrays->get(w.name);
    if (a.components != w.comps || a.count != w.count)
      throw Error(kind + ": the initial " + w.name + " array must be (" + std::to_string(w.count) + ", " +
                  std::to_string(w.comps) + ")");
    if (w.count > 0) sim->upload(w.name, a.data, a.count);
  }
  // moving walls (a lid): the wall particles' prescribed velocity (zero where not given)
  if (r.arrays && r.arrays->has("wall_velocity") && m->n_wall > 0) {
    ArrayView a = r.arrays->get("wall_velocity");
    if (a.components != D || a.count != m->n_wall)
      throw Error(kind + ": the initial wall_velocity array must be (" + std::to_string(m->n_wall) + ", " + std::to_string(D) + ")");
    sim->upload("wall_velocity", a.data, a.count);
  }
  // moving bodies: their motion tables, each wall particle's body and offset in its frame
  if (m->n_moving > 0) {
    auto get = [&](const char* name, int comps, long long count) -> ArrayView {
      if (!r.arrays || !r.arrays->has(name)) throw Error(kind + ": no " + name + " array (the scene has moving bodies)");
      ArrayView a = r.arrays->get(name);
      if (a.components != comps || (count >= 0 && a.count != count))
        throw Error(kind + ": the " + name + " array must be (" + (count >= 0 ? std::to_string(count) : "rows") + ", " +
                    std::to_string(comps) + ")");
      return a;
    };
    const ArrayView body = get("wall_body", 1, m->n_wall), local = get("wall_local", 3, m->n_wall);
    const bool tables = r.arrays->has("body_table");
    const ArrayView table = tables ? get("body_table", kBodyTableCols, -1) : ArrayView{};
    sim->pipeline().set_bodies(table.data, table.count, body.data, local.data);
  }
  return sim;
}

// the index plug-ins, the first the default: the lists (2.5 to 3 times the grid's steps/s on
// the H200 at 131,072 and 1,048,576 particles, 2026-12-02; faster on the CPU too)
using Indexes = IndexList<ListsIndex, GridIndex, CompactIndex, AllPairsIndex>;

template <class KindT, class Exec>
std::unique_ptr<Sim> make(Exec&& ex, const SimRequest& r) {
  return Indexes::with(KindT::name, r.index, [&](auto index) {
    return make_with<Exec, decltype(index), KindT>(std::move(ex), r);
  });
}

template <class KindT, class Exec>
double bytes(const SimRequest& r) {
  auto m = std::make_unique<Model<KindT::D>>(build_model<KindT>(*r.params));
  return Indexes::with(KindT::name, r.index, [&](auto index) {
    return Pipeline<Exec, decltype(index), KindT>::bytes_needed(*m);
  });
}

// a kind of this pipeline (fluid-box, dam-break, dam-break-2d) in the list of kinds (sim/kinds.h)
template <class KindT>
struct Entry {
  static constexpr const char* name = KindT::name;
  using Indexes = sph::Indexes;
  template <class Exec>
  static std::unique_ptr<Sim> make(Exec&& ex, const SimRequest& r) {
    return sph::make<KindT>(std::forward<Exec>(ex), r);
  }
  template <class Exec>
  static double bytes(const SimRequest& r) {
    return sph::bytes<KindT, Exec>(r);
  }
};

}  // namespace cps::sph
