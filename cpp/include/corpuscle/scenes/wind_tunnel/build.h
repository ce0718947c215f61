// The wind tunnel built from its parameters (SI values, as python/corpuscle/kinds/
// wind_tunnel.py writes them) and made on an Exec with an index plug-in.
#pragma once
#include <memory>
#include <string>
#include <vector>

#include "corpuscle/core/error.h"
#include "corpuscle/sim/params.h"
#include "corpuscle/sim/sim_impl.h"
#include "corpuscle/scenes/wind_tunnel/pipeline.h"

namespace cps::wt {

inline Vec2 vec2(const ParamSource& p, const std::string& key) {
  auto v = p.numbers(key);
  if (v.size() != 2) throw Error("wind-tunnel: parameter '" + key + "' needs 2 numbers");
  return Vec2{{float(v[0]), float(v[1])}};
}

// the model; the airfoil polygon (counter-clockwise vertices, (n, 2)) comes as an array
inline Model build_model(const ParamSource& p, const ArraySource* arrays) {
  Model m{};
  m.n = int(p.integer("n"));
  m.integrator = int(p.integer("integrator"));
  if (m.integrator != kForwardEuler && m.integrator != kSymplecticEuler)
    throw Error("wind-tunnel: integrator must be 0 (forward Euler) or 1 (symplectic Euler)");
  m.radius = p.f("radius");
  m.cell = p.has("cell") ? p.f("cell") : 0.0f;
  if (!(m.cell >= 0.0f) || !finite(m.cell)) throw Error("wind-tunnel: cell must be finite and not negative");
  m.lbvh_stack = p.has("lbvh_stack") ? int(p.integer("lbvh_stack")) : kLbvhStack;
  if (m.lbvh_stack < 1 || m.lbvh_stack > kLbvhMaxStack)
    throw Error("wind-tunnel: lbvh_stack must be 1 to " + std::to_string(kLbvhMaxStack) + ", got " +
                std::to_string(m.lbvh_stack));
  m.mass = p.f("mass");
  m.collide = p.has("collide") ? int(p.integer("collide") != 0) : 1;
  m.reflexive = p.has("reflexive") ? int(p.integer("reflexive")) : 0;
  if (m.reflexive < 0 || m.reflexive > 2) throw Error("wind-tunnel: reflexive must be 0, 1 or 2");
  m.recycle_scattered = p.has("recycle_scattered") ? int(p.integer("recycle_scattered") != 0) : 0;
  m.pp = SpringDashpot{p.f("k"), p.f("c")};
  m.wall = SpringDashpot{p.f("k_wall"), p.f("c_wall")};
  m.wing = SpringDashpot{p.f("k_wing"), p.f("c_wing")};
  m.lo = vec2(p, "channel_lo");
  m.hi = vec2(p, "channel_hi");
  if (!(m.hi[0] > m.lo[0]) || !(m.hi[1] - m.lo[1] > 2.0f * m.radius))
    throw Error("wind-tunnel: the channel must be wider than a particle");
  m.speed = p.f("speed");
  m.thermal = p.f("thermal");
  m.dt_fraction = p.f("dt_fraction");
  m.dt_max = p.f("dt_max");
  m.quarter_chord = vec2(p, "quarter_chord");
  m.measure_start = p.number("measure_start");
  m.block_time = p.number("block_time");
  if (!(m.block_time > 0.0)) throw Error("wind-tunnel: block_time must be positive");
  m.seed = unsigned(p.integer("seed") & 0xffffffffLL);
  m.n_edges = 0;
  m.bbox = Box2{{{1e30f, 1e30f}}, {{-1e30f, -1e30f}}};
  if (arrays && arrays->has("airfoil")) {
    ArrayView a = arrays->get("airfoil");
    if (a.components != 2 || a.count < 3) throw Error("wind-tunnel: the airfoil array must be (n >= 3, 2)");
    if (a.count > kMaxEdges)
      throw Error("wind-tunnel: the airfoil has " + std::to_string(a.count) + " vertices, at most " +
                  std::to_string(kMaxEdges));
    PolygonVertices P{a.data, int(a.count)};
    polygon_write_edges(P, m.edges);
    m.n_edges = int(a.count);
    m.bbox = polygon_bbox(P);
  }
  return m;
}

template <class Exec, class Index>
std::unique_ptr<Sim> make_with(Exec&& ex, const SimRequest& r) {
  using P = Pipeline<std::decay_t<Exec>, Index>;
  auto m = std::make_unique<Model>(build_model(*r.params, r.arrays));  // 32 KiB: not on the stack
  auto sim = std::make_unique<SimImpl<std::decay_t<Exec>, P>>(std::move(ex), *m, std::vector<typename P::SceneRecord>{P::initial_record(*m)},
                                                              r.device);
  for (const char* name : {"position", "velocity"}) {
    if (!r.arrays || !r.arrays->has(name)) throw Error(std::string("wind-tunnel: no initial ") + name + " array");
    ArrayView a = r.arrays->get(name);
    if (a.components != 2 || a.count != m->n)
      throw Error(std::string("wind-tunnel: the initial ") + name + " array must be (" + std::to_string(m->n) +
                  ", 2)");
    sim->upload(name, a.data, a.count);
  }
  return sim;
}

inline const std::vector<std::string>& index_names() {
  static const std::vector<std::string> names = {GridIndex::name, LbvhIndex::name, AllPairsIndex::name};
  return names;
}

template <class Exec>
std::unique_ptr<Sim> make(Exec&& ex, const SimRequest& r) {
  const std::string& idx = r.index.empty() ? index_names()[0] : r.index;
  if (idx == GridIndex::name) return make_with<Exec, GridIndex>(std::move(ex), r);
  if (idx == AllPairsIndex::name) return make_with<Exec, AllPairsIndex>(std::move(ex), r);
  if (idx == LbvhIndex::name) return make_with<Exec, LbvhIndex>(std::move(ex), r);
  throw Error("wind-tunnel: unknown index '" + idx + "' (indexes: grid, lbvh, allpairs)");
}

template <class Exec>
double bytes(const SimRequest& r) {
  auto m = std::make_unique<Model>(build_model(*r.params, r.arrays));
  return Pipeline<Exec, GridIndex>::bytes_needed(*m);
}

}  // namespace cps::wt
