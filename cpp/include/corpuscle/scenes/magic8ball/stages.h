// The Magic 8-Ball's stages: each a functor run by a backend's parallel_for over the
// particles (or one item per scene). Nothing here knows which backend runs it.
#pragma once
#include "corpuscle/core/atomics.h"
#include "corpuscle/core/lanes.h"
#include "corpuscle/spatial/allpairs.h"
#include "corpuscle/spatial/cell_grid.h"
#include "corpuscle/spatial/compact_grid.h"
#include "corpuscle/spatial/lane_walks.h"
#include "corpuscle/spatial/neighbor_list.h"
#include "corpuscle/scenes/magic8ball/tables.h"

namespace cps::m8 {

// the control of the container at time t: schedule plus API input
CPS_HD CPS_INLINE void control_at(const Model& m, const Control& u, double t, Vec3& acc, Vec3& torque) {
  acc = u.acc;
  torque = u.torque;
  for (int s = 0; s < m.n_shakes; ++s) {
    if (t >= m.shakes[s].start && t < m.shakes[s].end) {
      acc += m.shakes[s].acc;
      torque += m.shakes[s].torque;
    }
  }
}

// A state holds n_scenes independent scenes of n_fluid particles each. Slots: the fluid of
// scene s in [s n, (s + 1) n), its ghost slots in [N + s n, N + (s + 1) n) (N = all fluid);
// its cell table at s * cells_per_scene. A single run is a batch of one (the same layout as
// ever: fluid in [0, n), ghosts after it).
CPS_HD CPS_INLINE int total_fluid(const Model& m) { return m.n_fluid * m.n_scenes; }
// The per-item scene arithmetic of the stages that run every step, for a single run
// (Many = false: every scene index is 0 at compile time, as before batches existed; a
// division per item costs the default scene about 1%) or a batch (Many = true).
template <bool Many>
struct Scenes {
  // all fluid particles of the state
  CPS_HD static int fluid(const Model& m) { return Many ? total_fluid(m) : m.n_fluid; }
  // the scene of fluid particle i, and whether it is its scene's first
  CPS_HD static int of(const Model& m, int i) { return Many ? i / m.n_fluid : 0; }
  CPS_HD static bool first(const Model& m, int i) { return Many ? i % m.n_fluid == 0 : i == 0; }
  // the scene of slot j (fluid or ghost)
  CPS_HD static int of_slot(const Model& m, int j) {
    const int N = fluid(m);
    return of(m, j < N ? j : j - N);
  }
  // the grid of scene s: its own cell table
  CPS_HD static CellGridView<D> grid(const Model& m, CellGridView<D> g, int s) {
    if constexpr (Many) {
      g.cell_start += size_t(s) * cells_per_scene(m);
      g.cell_end += size_t(s) * cells_per_scene(m);
    }
    return g;
  }
};

// whether fluid slot i holds a particle: a scene of n_active particles uses the first n_active
// slots of its range (a single scene all of them)
CPS_HD CPS_INLINE bool active_slot(const Model& m, const Scene* g, int i) {
  return m.n_scenes == 1 || i % m.n_fluid < g[i / m.n_fluid].phys.n_active;
}

// cell keys of fluid particle i at x and of its ghost slot N + i, with identity values (an
// inactive slot is keyed past every cell: sorted to its segment's tail, never visited)
CPS_HD CPS_INLINE void write_keys(const Model& m, const Arrays& a, int i, const Vec3& x, bool active) {
  const int N = total_fluid(m);
  a.keys[i] = active ? cell_key(m, x, 0) : unused_key(m);
  a.keys[N + i] = active && needs_ghost(m.wall, x, m.list_radius) ? cell_key(m, mirror_position(m.wall, x), 1)
                                                                 : unused_key(m);
  a.idx[i] = i;
  a.idx[N + i] = N + i;
}

// this step's container frame from the shake schedule, the API control and the shell state
CPS_HD CPS_INLINE void prepare_frame(const Model& m, const Control& u, Scene& g) {
  Vec3 acc, torque;
  control_at(m, u, g.clock.time, acc, torque);
  FrameMotion f;
  f.gravity = qrotate_inv(g.shell_q, m.gravity);
  f.acc = acc;
  f.alpha = torque * (1.0f / m.shell_inertia) - g.shell_omega * m.spin_damping;
  f.omega = g.shell_omega;
  g.frame = f;
}

// items of the keys stage: the larger of the particle count and the cell tables
CPS_HD CPS_INLINE int keys_items(const Model& m) {
  int cells = int(cells_per_scene(m) * size_t(m.n_scenes));
  return total_fluid(m) > cells ? total_fluid(m) : cells;
}

// the work that starts a step: clear the cell tables, key every particle (the container
// frame is set by the step's density stage, from the control as it is then)
CPS_HD CPS_INLINE void start_step(const Model& m, const Arrays& a, int i, const Vec3* x, bool active) {
  if (size_t(i) < cells_per_scene(m) * size_t(m.n_scenes)) {
    a.cell_start[i] = 0u;
    a.cell_end[i] = 0u;
  }
  if (i < total_fluid(m)) {
    write_keys(m, a, i, *x, active);
    a.ghost_of[i] = -1;
  }
}

// stage 1 (first step, or after the state was replaced): start a step from the current state
struct KeysStage {
  const Model* model;
  Scene* g;
  Arrays a;
  CPS_HD void operator()(int i) const {
    const Model& m = *model;
    const bool fluid = i < total_fluid(m);
    Vec3 x = fluid ? a.position[i] : Vec3::zero();
    start_step(m, a, i, &x, fluid && active_slot(m, g, i));
    if (fluid && Scenes<true>::first(m, i)) {
      Scene* gs = g + Scenes<true>::of(m, i);
      gs->rebuild[gs->clock.step & 1] = 1;  // a new state is always sorted and listed
    }
  }
};

// Whether the lists of the last rebuild may miss a pair within h now. They hold every pair
// that was within the list radius h + s (s = skin_distance) then; a pair's distance shrinks
// by at most the sum of its two points' displacements since. With a the largest fluid
// displacement of the scene and b the largest of its ghosts that matter, every pair closed in
// by at most a + max(a, b) (fluid-fluid: 2a; fluid-ghost: a + b; ghosts pair with fluid only),
// so the lists stand while a + max(a, b) <= s. A ghost is measured exactly (its particle's
// mirror image now against the one at the rebuild: the mirror map stretches tangential
// motion by (2R - r) / r), and only while its particle is within 1.001 h of the wall: a ghost
// at 2R - r is at least R - r from all fluid (which stays within R), so beyond that it meets
// no fluid within h. A particle without a ghost since the rebuild started further than h + s
// from the wall, moved at most a <= s / 2, so its missing image is further than h from all fluid.
CPS_HD CPS_INLINE bool moved_too_far(const Model& m, const Scene* g) {
  if (!(m.skin_distance > 0.0f)) return true;  // no skin: every step
  const float a = fsqrt(bits_float(g->moved[0])), b = fsqrt(bits_float(g->moved[1]));
  return !(a + fmax2(a, b) <= m.skin_distance);  // and when a displacement is not finite
}
// whether this step sorts, reorders and relists: a new state asked for it (rebuild[]), or the
// last step's integration moved the scene too far for its lists (moved, kept from that
// integration until this step's finalize); the rest of the time the order and the lists of
// the last rebuild stand
CPS_HD CPS_INLINE bool rebuilding(const Model& m, const Scene* g) {
  return g->rebuild[g->clock.step & 1] != 0 || moved_too_far(m, g);
}
// the ghost of a particle at x can meet fluid within h (see moved_too_far)
CPS_HD CPS_INLINE bool ghost_matters(const Model& m, const Vec3& x) {
  const float inner = m.wall.radius - 1.001f * m.h;
  return !(inner > 0.0f) || norm2(x) > inner * inner;
}

struct RebuildFlag {
  const Model* model;
  const Scene* g;
  CPS_HD bool operator()() const { return rebuilding(*model, g); }
};

// a batch of several scenes sorts 64-bit keys: the segment (fluid or ghosts of one scene)
// above the cell key; a scene that does not rebuild keeps its order (its slots' own index
// as the key), so every scene's order is what it would be alone
struct SelectKeysStage {
  const Model* model;
  const Scene* g;
  Arrays a;
  CPS_HD void operator()(int j) const {
    const Model& m = *model;
    const int N = total_fluid(m), s = Scenes<true>::of_slot(m, j);
    const Scene* gs = g + s;
    const int layer = j < N ? 0 : 1;
    const int begin = layer * N + s * m.n_fluid;
    const uint32_t k = rebuilding(m, gs) && !halted(gs) ? a.keys[j] : uint32_t(j - begin);
    const uint32_t segment = uint32_t(layer * m.n_scenes + s);
    if (a.key_low_bits) a.keys[j] = (segment << a.key_low_bits) | k;  // in place: this item's own key, read above
    else a.keys64[j] = (uint64_t(segment) << 32) | uint64_t(k);
  }
};

// whether segment `seg` of a batch's segmented sort (slots [seg n, (seg + 1) n): the fluid of
// scene seg, or for seg >= n_scenes the ghosts of scene seg - n_scenes) is sorted: its scene
// rebuilds this step. Sorted by the cell keys alone, each segment gets the order the sort of
// every segment at once (SelectKeysStage) gives it; a segment not sorted keeps its order, and
// the reorder then reads neither its sorted keys nor its permutation
struct SegmentRebuilds {
  const Model* model;
  const Scene* g;
  CPS_HD bool operator()(int seg) const {
    const Scene* gs = g + seg % model->n_scenes;
    return rebuilding(*model, gs) && !halted(gs);
  }
};

// the sorted cell key of slot j (a batch's: the low half of its 64-bit key)
template <bool Many>
CPS_HD CPS_INLINE uint32_t sorted_key(const Arrays& a, int j) {
  if constexpr (Many)
    return a.key_low_bits ? a.keys_sorted[j] & ((1u << a.key_low_bits) - 1u) : uint32_t(a.keys64_sorted[j]);
  else return a.keys_sorted[j];
}

// stage 2: gather particle arrays into sorted order, build ghosts, record cell ranges; when
// not rebuilding, carry the arrays over in their order (ghosts were moved by the integration)
template <bool Many>
struct ReorderStage {
  const Model* model;
  Scene* g;
  Arrays a;
  CPS_HD void operator()(int j) const {
    const Model& m = *model;
    using S = Scenes<Many>;
    const int n = m.n_fluid, N = S::fluid(m), s = S::of_slot(m, j);
    Scene* gs = g + s;
    const bool fluid = j < N;
    const int begin = (fluid ? 0 : N) + s * n, end = begin + n;  // this slot's segment
    if (!rebuilding(m, gs) || halted(gs)) {
      if (fluid || j - begin < gs->n_ghost) a.gather(j, j);
      return;
    }
    const uint32_t sentinel = unused_key(m);
    const uint32_t k = sorted_key<Many>(a, j);
    const bool last = j + 1 == end || sorted_key<Many>(a, j + 1) != k;
    if (k < sentinel) {
      // the cell's range in the scene's table (layer 1: the ghost half)
      const size_t slot = size_t(s) * cells_per_scene(m) + size_t(m.grid.slot_of_key(k));
      if (j == begin || sorted_key<Many>(a, j - 1) != k) a.cell_start[slot] = uint32_t(j);
      if (last) a.cell_end[slot] = uint32_t(j + 1);
    }
    if (k >= sentinel) {
      if (fluid) a.gather(j, a.perm[j]);  // an inactive slot (its segment's tail) keeps its values
      if (!fluid && j == begin) gs->n_ghost = 0;  // no ghost in this scene
      return;
    }
    int o = a.perm[j];
    if (o < N) {
      a.gather(j, o);  // every field that moves with the particle
      a.x_build[j] = a.position[o];
    } else {
      int f = o - N;
      Vec3 x = a.position[f];
      a.position_alt[j] = mirror_position(m.wall, x);
      a.velocity_alt[j] = mirror_velocity(x, a.velocity[f]);
      a.id_alt[j] = -1;
      a.ghost_of[f] = j;
    }
    if (!fluid && (j + 1 == end || sorted_key<Many>(a, j + 1) >= sentinel)) gs->n_ghost = j + 1 - begin;
  }
};

// a visitor that does nothing (a walk that only lists)
struct NoVisit {
  template <class V>
  CPS_HD void operator()(int, const V&, float) const {}
};

// the index plug-ins of this kind (the registry names them)
struct ListsIndex {
  static constexpr const char* name = index_name::lists;
  static constexpr bool lists = true, cells = true, compact = false;
};
struct GridIndex {
  static constexpr const char* name = index_name::grid;
  static constexpr bool lists = false, cells = true, compact = false;
};
// the cells in chunks of a warp through shared memory (spatial/compact_grid.h); one scene
struct CompactIndex {
  static constexpr const char* name = index_name::compact;
  static constexpr bool lists = false, cells = true, compact = true;
};
struct AllPairsIndex {
  static constexpr const char* name = index_name::allpairs;
  static constexpr bool lists = false, cells = false, compact = false;
};

// the two pair stages for each index: the density (and, for lists, the listing) and the forces
template <class Index, bool Many>
struct PairWalk {
  // visit the density neighbours of i (within the list radius for lists, else h); returns
  // (count within the list radius, count within h) as lists need them
  template <class Lanes, class V>
  CPS_HD static void density(const Model& m, const Scene* g, const Arrays& a, const CellGridView<D>& grid, int i,
                             const Vec3& x, const Lanes& L, V& v, int& count, int& kept) {
    NoVisit none;
    if constexpr (Index::lists) {
      const RowLists lists = listed(m, a), near = nearby(m, a);
      int* list = lists.row(i);
      if (!rebuilding(m, g)) count = a.nbr_count[i];
      else if (m.list_scan) count = list_scene(m, g, grid, i, x, L, list);
      else count = for_each_in_cells(L, grid, x, none, list, m.max_neighbors);
      kept = lists.walk_compacting(L, i, count, grid.pos, x, v, m.kern.support2(), near);
    } else if constexpr (Index::cells) {
      kept = count = for_each_in_cells(L, grid, x, v, nullptr, 0);
    } else {
      kept = count = all_pairs(m, g, grid, i, x, L, v);
    }
  }
  // the lists by a scan of i's whole scene (every fluid particle, then its ghosts) instead of
  // the cell walk: the same neighbours within the list radius, in index order. For small
  // scenes (h a good part of the container radius) the 27 cells around a particle hold most
  // of its scene anyway, in many short cell ranges; the scan walks it in full rounds
  template <class Lanes>
  CPS_HD static int list_scene(const Model& m, const Scene* g, const CellGridView<D>& grid, int i, const Vec3& x,
                               const Lanes& L, int* list) {
    const int n = m.n_fluid, s = Scenes<Many>::of(m, i), ghosts = Scenes<Many>::fluid(m) + s * n;
    const AllPairsView<D> all = every_slot(m, grid, grid.r2);
    const int count = all.list_range(L, s * n, s * n + (Many ? g->phys.n_active : n), x, list, m.max_neighbors, 0);
    return all.list_range(L, ghosts, ghosts + g->n_ghost, x, list, m.max_neighbors, count);
  }
  // every fluid particle of i's scene, then its ghosts
  template <class Lanes, class V>
  CPS_HD static int all_pairs(const Model& m, const Scene* g, const CellGridView<D>& grid, int i, const Vec3& x,
                              const Lanes& L, V& v) {
    const int n = m.n_fluid, s = Scenes<Many>::of(m, i), ghosts = Scenes<Many>::fluid(m) + s * n;
    const AllPairsView<D> all = every_slot(m, grid, m.kern.support2());
    return all.gather_range(L, s * n, s * n + (Many ? g->phys.n_active : n), x, v) +
           all.gather_range(L, ghosts, ghosts + g->n_ghost, x, v);
  }
  // the lists: every neighbour within the list radius (rebuilds), and those of them within h
  // (every step, for the force stage)
  CPS_HD static RowLists listed(const Model& m, const Arrays& a) { return RowLists{a.nbr, a.nbr_count, m.max_neighbors}; }
  CPS_HD static RowLists nearby(const Model& m, const Arrays& a) { return RowLists{a.near, a.near_count, m.max_near}; }
  // the all-pairs view of every slot of the state (fluid and ghosts of every scene), queried
  // with squared radius r2; a particle walks its own scene's ranges of it
  CPS_HD static AllPairsView<D> every_slot(const Model& m, const CellGridView<D>& grid, float r2) {
    return AllPairsView<D>{grid.pos, 2 * Scenes<Many>::fluid(m), r2};
  }
  template <class Lanes, class V>
  CPS_HD static void forces(const Model& m, const Scene* g, const Arrays& a, const CellGridView<D>& grid, int i,
                            const Vec3& x, const Lanes& L, V& fv) {
    if constexpr (Index::lists) {
      nearby(m, a).walk(L, i, grid.pos, x, fv);
    } else if constexpr (Index::cells) {
      for_each_in_cells(L, grid, x, fv, nullptr, 0);
    } else {
      all_pairs(m, g, grid, i, x, L, fv);
    }
  }
};

// stage 3: density (Poly6 over fluid and ghosts) and Tait pressure of fluid particles,
// copied to each particle's ghost. On rebuilds the cells are walked to list every particle
// within the list radius; every step the list is walked for the density and its entries
// within h are copied to a short list for the force stage.
// Near the die the kernel is cut by its surface: the sum is renormalised by the fluid share
// of the kernel (Poly6's box_fraction), as if mirrored fluid filled the die, so the
// pressure there, and with it the buoyancy the contacts transmit, is hydrostatic.
// whether fluid slot i of scene s is left alone this step: its scene halted, or (a batch) the
// slot is past the scene's particles
template <bool Many>
CPS_HD CPS_INLINE bool idle_slot(const Model& m, const Scene* gs, int i, int s) {
  return halted(gs) || (Many && i - s * m.n_fluid >= gs->phys.n_active);
}

// particle i's density at x from its Poly6 kernel sum: renormalised by the fluid share of the
// kernel the die leaves (box_fraction), then floored (every path's density stage)
CPS_HD CPS_INLINE float density_of(const Model& m, const ScenePhysics& P, const RigidState& die, const Vec3& x,
                                   float sum) {
  const float cut = m.kern.poly6.box_fraction(P.die.half, qrotate_inv(die.q, x - die.x));
  return finish_density(P.sph, sum / (1.0f - fmin2(cut, 0.5f)));
}

template <class Index, bool Many>
struct DensityStage {
  const Model* model;
  Scene* g;
  const Control* ctl;
  Arrays a;
  CellGridView<D> grid;
  // the walk by lanes (lists, grid, allpairs)
  template <class Lanes>
  CPS_HD void operator()(int i, const Lanes& L) const {
    const Model& m = *model;
    using S = Scenes<Many>;
    const int s = S::of(m, i);
    Scene* gs = g + s;
    if (idle_slot<Many>(m, gs, i, s)) return;
    DensityVisitor<D> v{m.kern};
    Vec3 x = a.position[i];
    int count = 0, kept = 0;
    PairWalk<Index, Many>::density(m, gs, a, S::grid(m, grid, s), i, x, L, v, count, kept);
    float sum = L.sum(v.sum);
    if (!L.leader()) return;
    write(i, s, gs, x, sum, count, kept);
  }
  // the compact index's begin / visit / end (spatial/compact_grid.h: a lane per particle of
  // a chunk of the fluid)
  using Acc = float;
  CPS_HD float begin(int) const { return 0.0f; }
  CPS_HD void visit(float& sum, int, int, const Vec3&, float r2) const { sum += DensityVisitor<D>::term(model->kern, r2); }
  CPS_HD void end(int i, float& sum) const {
    const int s = Scenes<Many>::of(*model, i);
    Scene* gs = g + s;
    if (!idle_slot<Many>(*model, gs, i, s)) write(i, s, gs, a.position[i], sum, 0, 0);
  }
  // particle i's density and pressure from its kernel sum (and the lists' counts)
  CPS_HD void write(int i, int s, Scene* gs, const Vec3& x, float sum, int count, int kept) const {
    const Model& m = *model;
    const ScenePhysics& P = gs->phys;
    const bool rebuild = rebuilding(m, gs);
    if (Scenes<Many>::first(m, i)) prepare_frame(m, ctl[s], *gs);  // read by the force stage and the finalize
    if constexpr (Index::lists) {
      a.near_count[i] = kept;
      if (count > m.max_neighbors || kept > m.max_near) raise_first(&gs->clock.bad, kBadNeighbors);
      if (rebuild) a.nbr_count[i] = count;
    }
    if (rebuild) a.ghost_slot[i] = a.ghost_of[a.perm[i]];
    const float rho = density_of(m, P, gs->die, x, sum);
    const float p = tait_pressure(P.sph, rho);
    const ForceTerms t = ForceTerms::of(rho, p);
    a.density[i] = rho;
    a.pressure[i] = p;
    a.terms[i] = t;
    // the ghost of this particle carries the same density and pressure
    int ghost = a.ghost_slot[i];
    if (ghost >= 0) {
      a.density[ghost] = rho;
      a.pressure[ghost] = p;
      a.terms[ghost] = t;
    }
  }
};

// particle i's acceleration (pair sums, container frame, die contact) and XSPH correction
// from its pair sums f, and its item of the step's reductions (every path's force stage)
CPS_HD CPS_INLINE StepSums particle_forces(const Model& m, const Scene& g, const ScenePhysics& P, const Vec3& x,
                                           const Vec3& v, float rho, const ForceSum<D>& f, Vec3& acc_out,
                                           Vec3& xsph_out) {
  Vec3 acc = ForcePairs<D>::acceleration(P.sph, f) + frame_acceleration(g.frame, x, v);
  StepSums s = StepSums::identity();
  // die: contact spring + drag on the particle, reaction on the die
  Vec3 ad;
  if (body_contact(m.contact, P.die, g.die, x, v, ad)) {
    acc += ad;
    Vec3 F = ad * (-P.sph.mass);
    s.force = F;
    s.torque = cross(x - g.die.x, F);
    s.contacts = 1;
  }
  acc_out = acc;
  xsph_out = ForcePairs<D>::xsph_correction(P.sph, f);
  float err = rho / P.sph.rest_density - 1.0f;
  s.vmax2 = norm2(v);
  s.amax2 = norm2(acc);
  s.rho_err = err < 0.0f ? -err : err;
  s.rho_sum = rho;
  s.ke = 0.5f * P.sph.mass * s.vmax2;
  return s;
}

// stage 4: SPH forces (over the neighbours the density stage listed), XSPH, container-frame
// terms and die coupling of fluid particles; the per-particle contributions to this step's
// reductions (the reduction of a step not taken is discarded; idle slots are not reduced)
template <class Index, bool Many>
struct ForceStage {
  const Model* model;
  const Scene* g;
  Arrays a;
  CellGridView<D> grid;
  // the walk by lanes (lists, grid, allpairs)
  template <class Lanes>
  CPS_HD void operator()(int i, const Lanes& L) const {
    const Model& m = *model;
    using S = Scenes<Many>;
    const int sc = S::of(m, i);
    const Scene* gs = g + sc;
    if (idle_slot<Many>(m, gs, i, sc)) return;
    const ScenePhysics P = gs->phys;  // a copy: constant for the whole walk
    ForceVisitor<D> fv(m.kern, P.sph, a.velocity, a.density, a.terms, i, S::fluid(m));
    Vec3 x = a.position[i];
    PairWalk<Index, Many>::forces(m, gs, a, S::grid(m, grid, sc), i, x, L, fv);
    fv.reduce(L);
    if (!L.leader()) return;
    write(i, gs, P, x, fv.s);
  }
  // the compact index's begin / visit / end
  using Acc = ForceSum<D>;
  CPS_HD ForcePairs<D> pairs() const {
    return ForcePairs<D>{model->kern, a.velocity, a.density, a.terms, Scenes<Many>::fluid(*model)};
  }
  CPS_HD Acc begin(int i) const { return pairs().begin(i); }
  CPS_HD void visit(Acc& f, int, int j, const Vec3& d, float r2) const { pairs().add(f, j, d, r2); }
  CPS_HD void end(int i, Acc& f) const {
    const int sc = Scenes<Many>::of(*model, i);
    const Scene* gs = g + sc;
    if (!idle_slot<Many>(*model, gs, i, sc)) write(i, gs, gs->phys, a.position[i], f);
  }
  // particle i's acceleration, XSPH correction and reduction item from its pair sums
  CPS_HD void write(int i, const Scene* gs, const ScenePhysics& P, const Vec3& x, const ForceSum<D>& f) const {
    a.items[i] = particle_forces(*model, *gs, P, x, a.velocity[i], a.density[i], f, a.acceleration[i], a.xsph[i]);
  }
};

// the largest speed of a step (fluid or die), and the dt its reductions select, before the
// end-time clipping
CPS_HD CPS_INLINE float max_speed(const StepSums& s, const RigidState& die) {
  return fmax2(fsqrt(s.vmax2), norm(die.v));
}
CPS_HD CPS_INLINE float sums_dt(const Model& m, const ScenePhysics& P, const StepSums& s, const RigidState& die) {
  return choose_dt(m.dt, m.h, max_speed(s, die), fsqrt(s.amax2), P.c0, P.sph.viscosity / P.sph.rest_density);
}

// a batch's reductions, one scene per tile, in the CPU backend's fixed order (kReduceChunks
// chunks of the scene's items, each summed in order by a lane, then the chunks combined in
// order by lane 0): each scene's sums are what it gets alone, on every backend
constexpr int kSceneReduceChunks = 64;  // = CpuExec::kReduceChunks, the tile's lanes
struct SceneReduceStage {
  const Model* model;
  const Scene* g;
  const StepSums* items;
  StepSums* out;
  template <class Tile>
  CPS_HD void operator()(int s, Tile& t) const {
    static_assert(Tile::kSize == kSceneReduceChunks, "one lane per chunk");
    const int n = g[s].phys.n_active, base = s * model->n_fluid;
    const int chunk = (n + kSceneReduceChunks - 1) / kSceneReduceChunks;
    StepSums* parts = t.template shared<StepSums>(kSceneReduceChunks);
    t.lanes([&](int c) {
      StepSums part = StepSums::identity();
      const int b = c * chunk, e = b + chunk < n ? b + chunk : n;
      for (int k = b; k < e; ++k) part = StepSums::combine(part, items[base + k]);
      parts[c] = part;
    });
    t.sync();
    t.lanes([&](int c) {
      if (c != 0) return;
      StepSums total = StepSums::identity();
      for (int k = 0; k < kSceneReduceChunks; ++k) total = StepSums::combine(total, parts[k]);
      out[s] = total;
    });
  }
};
// the tile launch of it
template <class Exec>
void reduce_scenes(Exec& ex, int scenes, const SceneReduceStage& f) {
  ex.template for_each_tile<kSceneReduceChunks>(scenes, f, sizeof(StepSums) * kSceneReduceChunks);
}

// an evaluation's reductions, kept as the scenes' sums
struct StoreSumsStage {
  Scene* g;
  const StepSums* sums;
  CPS_HD void operator()(int s) const { g[s].sums = sums[s]; }
};

// stage 5 (one item per scene): dt, die and container integration, clock; the step's sums
// are the scene's pending ones, or a batch's from `sums`
struct FinalizeStage {
  const Model* model;
  Scene* g;
  const StepSums* sums = nullptr;
  CPS_HD void operator()(int scene) const {
    const Model& m = *model;
    Scene& G = g[scene];
    Clock& C = G.clock;
    if (clock_at_end(C)) {
      G.step_dt = 0.0f;
      return;
    }
    if (C.bad) {
      // found before integrating (this step's lists overflowed), or raised by the last
      // step's integration: the kept state is the last one integrated
      if (C.bad_step < 0) C.bad_step = C.bad == kBadNeighbors ? C.step + 1 : C.step;
      G.step_dt = 0.0f;
      return;
    }
    G.rebuilds += rebuilding(m, &G) ? 1 : 0;
    G.rebuild[C.step & 1] = 0;  // this step's readers are done with its flag
    G.moved[0] = G.moved[1] = 0;  // and with the displacements: this step's integration measures them anew
    const StepSums& S = sums ? sums[scene] : G.pending;
    bool last;
    const float dt = clip_to_end(C, sums_dt(m, G.phys, S, G.die), last);
    // faults found before integrating: a non-finite state is not integrated (the state
    // stays as it was); a runaway speed is integrated once more and then stops the run
    int fault = 0;
    if (!finite(S.vmax2) || !finite(S.amax2)) fault = kBadParticles;
    const bool runaway = !fault && max_speed(S, G.die) > 100.0f * G.phys.c0;
    // the die under the fluid's reaction, then kept inside the sphere
    RigidState d = G.die;
    if (!fault) {
      integrate_box(G.phys.die, m.body, G.frame, S.force, S.torque, dt, d);
      keep_box_in_sphere(G.phys.die, m.wall.radius, m.body.restitution, d);
      if (!finite(d.x[0] + d.x[1] + d.x[2] + d.v[0] + d.v[1] + d.v[2] + d.q.w + d.q.x + d.q.y + d.q.z +
                  d.w_body[0] + d.w_body[1] + d.w_body[2]))
        fault = kBadDie;
    }
    if (fault) {
      C.bad = fault;
      C.bad_step = C.step + 1;
      G.step_dt = 0.0f;
      return;
    }
    G.die = d;
    G.sums = S;
    // the container shell: angular velocity and orientation
    G.shell_omega += G.frame.alpha * dt;
    G.shell_q = qintegrate_body(G.shell_q, G.shell_omega, dt);
    G.step_dt = dt;
    advance_clock(C, dt, last);  // land exactly on the end time and stop there
    if (runaway) {
      C.bad = kBadSpeed;
      C.bad_step = C.step;
    }
  }
};

// one fluid particle's step of dt = gs->step_dt (symplectic Euler, XSPH-corrected drift, the
// wall), its ghost (where it has one: *xg, *vg) moved with it, and how far both moved since
// the last rebuild raised into gs->moved (every path's integration)
CPS_HD CPS_INLINE void integrate_particle(const Model& m, Scene* gs, const Vec3& acc, const Vec3& xsph, const Vec3& xb,
                                          Vec3& x, Vec3& v, Vec3* xg, Vec3* vg) {
  const float dt = gs->step_dt;
  v = v + acc * dt;
  x = x + (v + xsph) * dt;
  reflect_at_wall(m.wall, x, v);
  if (!finite(x[0] + x[1] + x[2] + v[0] + v[1] + v[2])) raise_first(&gs->clock.bad, kBadParticles);
  // the ghost follows its particle between rebuilds
  if (xg) {
    const Vec3 g = mirror_position(m.wall, x);
    *xg = g;
    *vg = mirror_velocity(x, v);
    if (ghost_matters(m, x)) atomic_max_above(&gs->moved[1], float_bits(norm2(g - mirror_position(m.wall, xb))));
  }
  // how far it moved since the last rebuild: the next step relists when the scene moved
  // too far for its lists (moved_too_far)
  atomic_max_above(&gs->moved[0], float_bits(norm2(x - xb)));
}

// stage 6: integrate fluid (symplectic Euler, XSPH-corrected drift), enforce the wall, and
// start the next step (its keys, cleared cell table and frame) in the same pass
template <bool Many>
struct IntegrateStage {
  const Model* model;
  Scene* g;
  Arrays a;
  CPS_HD void operator()(int i) const {
    const Model& m = *model;
    Vec3 x = Vec3::zero();
    const bool fluid = i < Scenes<Many>::fluid(m);
    Scene* gs = g + (fluid ? Scenes<Many>::of(m, i) : 0);
    // a step that was not taken (halted before integrating) leaves the particles as they are,
    // and so do inactive slots (a batch's; a single run has none)
    const bool active = fluid && (!Many || active_slot(m, g, i));
    const bool taken = active && gs->step_dt > 0.0f;
    if (fluid && !taken) x = a.position[i];
    if (fluid && taken) {
      Vec3 v = a.velocity[i];
      x = a.position[i];
      const int ghost = a.ghost_slot[i];
      integrate_particle(m, gs, a.acceleration[i], a.xsph[i], a.x_build[i], x, v, ghost >= 0 ? a.position + ghost : nullptr,
                         ghost >= 0 ? a.velocity + ghost : nullptr);
      a.position[i] = x;
      a.velocity[i] = v;
    }
    start_step(m, a, i, &x, active);
  }
};

// the face (1..6) whose outward normal points most toward the container's +z window
CPS_HD CPS_INLINE int window_face(const Quat& q) {
  // faces: +x=1, +y=2, +z=3, -z=4, -y=5, -x=6 (opposite faces sum to 7)
  const int face_pos[3] = {1, 2, 3};
  Vec3 ez{{0.0f, 0.0f, 1.0f}};
  Vec3 up = qrotate_inv(q, ez);  // window direction in the body frame
  int best = 0;
  float bv = -1.0f;
  for (int k = 0; k < 3; ++k) {
    float c = up[k] < 0.0f ? -up[k] : up[k];
    if (c > bv) { bv = c; best = k; }
  }
  return up[best] >= 0.0f ? face_pos[best] : 7 - face_pos[best];
}

}  // namespace cps::m8
