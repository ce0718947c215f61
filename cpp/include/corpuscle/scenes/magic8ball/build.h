// The Magic 8-Ball built from its parameters (SI values, as python/corpuscle/kinds/
// magic8ball.py writes them) and made on an Exec with an index plug-in.
#pragma once
#include <cstdio>
#include <memory>
#include <string>

#include "corpuscle/core/error.h"
#include "corpuscle/sim/kind_list.h"
#include "corpuscle/sim/params.h"
#include "corpuscle/sim/sim_impl.h"
#include "corpuscle/scenes/magic8ball/pipeline.h"

namespace cps::m8 {

// CUDA lanes per particle in the pair stages when the scene does not say (sph.lanes = 0): a
// warp each for states that need them to fill the GPU (one scene of a few thousand particles:
// 32 lanes per particle is what keeps the device busy); kWideLanes for states of at least
// kWideParticles (a large batch), where narrower groups waste less of a warp's last round
// over ~130-230 neighbours, reduce in fewer shuffles and share the per-particle tail (run by
// one lane of each group). Not yet measured against 32: benchmarks/batch_speed_device.sh.
constexpr int kWideLanes = 8;
constexpr long long kWideParticles = 1LL << 18;
inline int auto_lanes(const Model& m) {
  return (long long)m.n_fluid * m.n_scenes >= kWideParticles ? kWideLanes : 32;
}
// how the lists are rebuilt when the scene does not say (sph.list_build = auto): a scan of the
// whole scene for scenes of at most kScanSlots particle slots (where the 27 cells around a
// particle hold most of its scene anyway), the cell walk for larger ones. At 4,096 scenes of
// 1,000 particles the cells were faster on the H200 (87.7 against 82.7 steps/s, 2026-12-02):
// the scan is kept for scenes of at most 500
constexpr int kScanSlots = 500;
inline int auto_list_scan(const Model& m) { return m.n_fluid <= kScanSlots ? 1 : 0; }

inline Model build_model(const ParamSource& p) {
  Model m{};
  m.n_fluid = int(p.integer("n_fluid"));
  m.n_scenes = p.has("n_scenes") ? int(p.integer("n_scenes")) : 1;
  if (m.n_scenes < 1 || (long long)m.n_scenes * m.n_fluid > (1LL << 29))
    throw Error("magic8ball: n_scenes must be at least 1 and n_scenes * n_fluid at most 2^29");
  m.h = p.f("h");
  m.kern = MuellerKernels<D>::make(m.h);
  m.max_neighbors = int(p.integer("max_neighbors"));
  m.max_near = int(p.integer("max_near"));
  m.max_list_bytes = p.has("max_list_bytes") ? p.number("max_list_bytes") : 0.0;
  m.list_radius = p.f("list_radius");
  m.skin_distance = p.f("skin_distance");
  if (!(m.skin_distance >= 0.0f)) throw Error("magic8ball: skin_distance must not be negative");
  m.lanes = p.has("lanes") ? int(p.integer("lanes")) : 0;
  if (m.lanes == 0) m.lanes = auto_lanes(m);
  m.wide_keys = p.has("wide_keys") && p.integer("wide_keys") != 0 ? 1 : 0;
  m.path = p.has("path") ? int(p.integer("path")) : -1;
  if (m.path < -1 || m.path > 2)
    throw Error("magic8ball: path must be -1 (chosen), 0 (general), 1 (chip) or 2 (chip, also on the CPU), got " +
                std::to_string(m.path));
  m.list_scan = p.has("list_scan") ? int(p.integer("list_scan")) : -1;
  if (m.list_scan < 0) m.list_scan = auto_list_scan(m);
  if (m.list_scan > 1) throw Error("magic8ball: list_scan must be 0 (cells), 1 (scan) or -1 (automatic)");
  if (m.lanes != 4 && m.lanes != 8 && m.lanes != 16 && m.lanes != 32)
    throw Error("magic8ball: lanes must be 4, 8, 16 or 32 (0: chosen by the state's size), got " +
                std::to_string(m.lanes));
  m.wall = SphereWall{p.f("radius"), p.f("wall_restitution"), p.f("wall_friction")};
  m.shell_inertia = p.f("shell_inertia");
  m.spin_damping = p.f("spin_damping");
  m.gravity = p.vec3("gravity");
  m.contact = ContactParams{p.f("contact_margin"), p.f("contact_stiffness"), p.f("contact_drag")};
  m.body = BodyParams{p.f("die_linear_damping"), p.f("die_angular_damping"), p.f("die_restitution")};
  m.dt = DtParams{p.f("dt_min"), p.f("dt_max"), p.f("cfl_advective"), p.f("cfl_acoustic"), p.f("cfl_force"),
                  p.f("cfl_viscous")};
  // the grid covers the sphere and the ghosts mirrored up to the list radius beyond it
  float ext = m.wall.radius + m.list_radius;
  m.grid = make_cell_grid<D>(Vec3{{-ext, -ext, -ext}}, Vec3{{ext, ext, ext}}, m.list_radius, 2);
  if (m.grid.key_bits > 32) {
    char msg[320];
    std::snprintf(msg, sizeof msg,
                  "magic8ball: container.radius = %g m spans %d cells per axis of the neighbour radius h (1 + "
                  "sph.skin) = %g m, more than 32-bit sort keys hold: lower container.radius or raise sph.h "
                  "(sph.scale_h = false)",
                  double(m.wall.radius), m.grid.dims[0], double(m.list_radius));
    throw Error(msg);
  }
  auto shakes = p.tables("shakes");
  if (shakes.size() > size_t(kMaxShakes))
    throw Error("magic8ball: at most " + std::to_string(kMaxShakes) + " shake windows");
  m.n_shakes = int(shakes.size());
  for (int s = 0; s < m.n_shakes; ++s) {
    const ParamSource& w = *shakes[s];
    m.shakes[s] = ShakeWindow{w.number("start"), w.number("end"), w.vec3("acceleration"), w.vec3("torque")};
  }
  return m;
}

// the die at the start: position, velocity, orientation (w, x, y, z), angular velocity in
// the container frame
inline RigidState die_from(const ParamSource& d) {
  RigidState s;
  s.x = d.vec3("position");
  s.v = d.vec3("velocity");
  auto q = d.numbers("orientation");
  if (q.size() != 4) throw Error("magic8ball: die_initial.orientation needs 4 numbers");
  s.q = qnormalize(Quat{float(q[0]), float(q[1]), float(q[2]), float(q[3])});
  s.w_body = qrotate_inv(s.q, d.vec3("angular_velocity"));
  return s;
}

// the parameters of one scene: the batch-wide ones, where the scene's own table (`own`, from
// the list `scenes`) does not give them (mass, stiffness, viscosity, die_half, die_mass,
// die_inertia, n_fluid: the particles of the scene, at most the batch's n_fluid slots)
inline ScenePhysics scene_physics(const ParamSource& p, const ParamSource* own, int slots, int scene) {
  auto num = [&](const char* k) { return own && own->has(k) ? own->f(k) : p.f(k); };
  auto vec = [&](const char* k) { return own && own->has(k) ? own->vec3(k) : p.vec3(k); };
  ScenePhysics s{};
  s.sph.mass = num("mass");
  s.sph.rest_density = p.f("rest_density");
  s.sph.stiffness = num("stiffness");
  s.sph.gamma = p.f("gamma");
  s.sph.viscosity = num("viscosity");
  s.sph.xsph = p.f("xsph");
  s.sph.density_floor = p.f("density_floor");
  s.c0 = tait_sound_speed(s.sph);
  s.die = RigidBox{vec("die_half"), num("die_mass"), vec("die_inertia")};
  s.n_active = own && own->has("n_fluid") ? int(own->integer("n_fluid")) : slots;
  if (s.n_active < 1 || s.n_active > slots)
    throw Error("magic8ball: scenes[" + std::to_string(scene) + "].n_fluid must be in 1.." + std::to_string(slots) +
                " (the batch's n_fluid), got " + std::to_string(s.n_active));
  if (!(s.sph.mass > 0.0f) || !(s.sph.stiffness > 0.0f) || !(s.sph.viscosity >= 0.0f) || !(s.die.mass > 0.0f) ||
      !(s.die.half[0] > 0.0f && s.die.half[1] > 0.0f && s.die.half[2] > 0.0f))
    throw Error("magic8ball: scenes[" + std::to_string(scene) +
                "]: mass, stiffness, die_mass and die_half must be positive, viscosity not negative");
  return s;
}

// one initial record per scene: `die_initial` is one table (every scene) or a list of one
// table per scene (`die_initial_scenes`); `scenes`, where given, one table of parameters per
// scene (scene_physics)
template <class P>
std::vector<Scene> initial_records(const ParamSource& p, const Model& m) {
  const int scenes = m.n_scenes;
  std::vector<std::unique_ptr<ParamSource>> own;
  if (p.has("scenes")) {
    own = p.tables("scenes");
    if (int(own.size()) != scenes) throw Error("magic8ball: scenes needs " + std::to_string(scenes) + " tables");
  }
  std::vector<std::unique_ptr<ParamSource>> dies;
  if (p.has("die_initial_scenes")) {
    dies = p.tables("die_initial_scenes");
    if (int(dies.size()) != scenes)
      throw Error("magic8ball: die_initial_scenes needs " + std::to_string(scenes) + " tables");
  }
  const RigidState die0 = dies.empty() ? die_from(*p.table("die_initial")) : RigidState{};
  std::vector<Scene> out;
  for (int s = 0; s < scenes; ++s) {
    ScenePhysics phys = scene_physics(p, own.empty() ? nullptr : own[s].get(), m.n_fluid, s);
    if (scenes == 1 && phys.n_active != m.n_fluid)
      throw Error("magic8ball: a single scene has n_fluid particles (scenes[0].n_fluid must equal it)");
    out.push_back(P::initial_record(dies.empty() ? die0 : die_from(*dies[s]), phys));
  }
  return out;
}

template <class Exec, class Index>
std::unique_ptr<Sim> make_with(Exec&& ex, const SimRequest& r) {
  using P = Pipeline<std::decay_t<Exec>, Index>;
  Model m = build_model(*r.params);
  auto sim = std::make_unique<SimImpl<std::decay_t<Exec>, P>>(std::move(ex), m,
                                                              initial_records<P>(*r.params, m), r.device);
  // the initial particles
  for (const char* name : {"position", "velocity"}) {
    if (!r.arrays || !r.arrays->has(name)) throw Error(std::string("magic8ball: no initial ") + name + " array");
    ArrayView a = r.arrays->get(name);
    const long long n = (long long)m.n_fluid * m.n_scenes;
    if (a.components != 3 || a.count != n)
      throw Error(std::string("magic8ball: the initial ") + name + " array must be (" + std::to_string(n) +
                  ", 3): the scenes' particles one scene after another");
    sim->upload(name, a.data, a.count);
  }
  return sim;
}

// the index plug-ins of this kind, the first the default
using Indexes = IndexList<ListsIndex, GridIndex, CompactIndex, AllPairsIndex>;

// the kind in the list of kinds (sim/kinds.h)
struct Entry {
  static constexpr const char* name = "magic8ball";
  using Indexes = m8::Indexes;
  template <class Exec>
  static std::unique_ptr<Sim> make(Exec&& ex, const SimRequest& r) {
    return Indexes::with(name, r.index, [&](auto index) { return make_with<Exec, decltype(index)>(std::move(ex), r); });
  }
  template <class Exec>
  static double bytes(const SimRequest& r) {
    Model m = build_model(*r.params);
    return Indexes::with(name, r.index, [&](auto index) { return Pipeline<Exec, decltype(index)>::bytes_needed(m); });
  }
};

}  // namespace cps::m8
