// The Magic 8-Ball's stages: each a functor run by a backend's parallel_for over the
// particles (or one item per scene). Nothing here knows which backend runs it.
#pragma once
#include "corpuscle/core/lanes.h"
#include "corpuscle/scenes/magic8ball/model.h"

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

// raise a flag from many threads: the largest code wins, whatever the order
CPS_HD CPS_INLINE void raise_flag(int* p, int code) {
#ifdef __CUDA_ARCH__
  atomicMax(p, code);
#else
  int seen = __atomic_load_n(p, __ATOMIC_RELAXED);
  while (seen < code && !__atomic_compare_exchange_n(p, &seen, code, true, __ATOMIC_RELAXED, __ATOMIC_RELAXED)) {
  }
#endif
}

// raise an instability reason: the first one raised stays (each stage raises one reason,
// so the kept reason is that of the earliest stage that found a fault)
CPS_HD CPS_INLINE void raise_first(int* p, int code) {
#ifdef __CUDA_ARCH__
  atomicCAS(p, 0, code);
#else
  int zero = 0;
  __atomic_compare_exchange_n(p, &zero, code, false, __ATOMIC_RELAXED, __ATOMIC_RELAXED);
#endif
}

// a scene whose run is over (end time reached) or unsound: its steps are no-ops that only
// carry the arrays over
CPS_HD CPS_INLINE bool halted(const Scene* g) { return g->clock.done != 0 || g->clock.bad != 0; }

// cell keys of fluid particle i at x and of its ghost slot n + i, with identity values
CPS_HD CPS_INLINE void write_keys(const Model& m, const Arrays& a, int i, const Vec3& x) {
  const int n = m.n_fluid;
  a.keys[i] = m.grid.key(x, 0);
  a.keys[n + i] = needs_ghost(m.wall, x, m.list_radius) ? m.grid.key(mirror_position(m.wall, x), 1) : m.grid.sentinel();
  a.idx[i] = i;
  a.idx[n + i] = n + i;
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

// items of the keys stage: the larger of the particle count and the cell table
CPS_HD CPS_INLINE int keys_items(const Model& m) {
  int cells = int(2 * m.grid.ncells);
  return m.n_fluid > cells ? m.n_fluid : cells;
}

// the work that starts a step: clear the cell table, key every particle (the container
// frame is set by the step's density stage, from the control as it is then)
CPS_HD CPS_INLINE void start_step(const Model& m, const Arrays& a, int i, const Vec3* x) {
  if (uint32_t(i) < 2 * m.grid.ncells) {
    a.cell_start[i] = 0u;
    a.cell_end[i] = 0u;
  }
  if (i < m.n_fluid) {
    write_keys(m, a, i, *x);
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
    Vec3 x = i < m.n_fluid ? a.pos[i] : Vec3::zero();
    start_step(m, a, i, &x);
    if (i == 0) g->rebuild[g->clock.step & 1] = 1;  // a new state is always sorted and listed
  }
};

// whether this step sorts, reorders and relists (the rest of the time the order and the
// neighbour lists of the last rebuild stand: nothing moved more than the skin allows)
CPS_HD CPS_INLINE bool rebuilding(const Scene* g) { return g->rebuild[g->clock.step & 1] != 0; }

struct RebuildFlag {
  const Scene* g;
  CPS_HD bool operator()() const { return rebuilding(g); }
};

// stage 2: gather particle arrays into sorted order, build ghosts, record cell ranges; when
// not rebuilding, carry the arrays over in their order (ghosts were moved by the integration)
struct ReorderStage {
  const Model* model;
  Scene* g;
  Arrays a;
  CPS_HD void operator()(int j) const {
    const Model& m = *model;
    const int n = m.n_fluid, cap = 2 * n;
    if (!rebuilding(g) || halted(g)) {
      if (j < n + g->n_ghost) {
        a.pos_alt[j] = a.pos[j];
        a.vel_alt[j] = a.vel[j];
        a.id_alt[j] = a.id[j];
      }
      return;
    }
    mark_cell_range(m.grid, a.keys_sorted, j, cap, a.cell_start, a.cell_end);
    const uint32_t sentinel = m.grid.sentinel();
    if (a.keys_sorted[j] >= sentinel) return;
    int o = a.perm[j];
    if (o < n) {
      a.pos_alt[j] = a.pos[o];
      a.vel_alt[j] = a.vel[o];
      a.id_alt[j] = a.id[o];
      a.x_build[j] = a.pos[o];
    } else {
      int f = o - n;
      Vec3 x = a.pos[f];
      a.pos_alt[j] = mirror_position(m.wall, x);
      a.vel_alt[j] = mirror_velocity(x, a.vel[f]);
      a.id_alt[j] = -1;
      a.ghost_of[f] = j;
    }
    if (j + 1 == cap || a.keys_sorted[j + 1] >= sentinel) g->n_ghost = j + 1 - n;
  }
};

// a visitor that does nothing (a walk that only lists)
struct NoVisit {
  template <class V>
  CPS_HD void operator()(int, const V&, float) const {}
};

// the index plug-ins of this kind (the registry names them)
struct ListsIndex {
  static constexpr const char* name = "lists";
  static constexpr bool lists = true, cells = true;
};
struct GridIndex {
  static constexpr const char* name = "grid";
  static constexpr bool lists = false, cells = true;
};
struct AllPairsIndex {
  static constexpr const char* name = "allpairs";
  static constexpr bool lists = false, cells = false;
};

// the two pair stages for each index: the density (and, for lists, the listing) and the forces
template <class Index>
struct PairWalk {
  // visit the density neighbours of i (within the list radius for lists, else h); returns
  // (count within the list radius, count within h) as lists need them
  template <class Lanes, class V>
  CPS_HD static void density(const Model& m, const Scene* g, const Arrays& a, const GridView<D>& grid, int i,
                             const Vec3& x, const Lanes& L, V& v, int& count, int& kept) {
    NoVisit none;
    if constexpr (Index::lists) {
      int* list = a.nbr + size_t(i) * size_t(m.max_neighbors);
      if (rebuilding(g)) count = L.for_each_neighbor_listing(grid, x, true, none, list, m.max_neighbors);
      else count = a.nbr_count[i];
      int* near = a.near + size_t(i) * size_t(m.max_near);
      kept = L.for_each_listed_compacting(list, count < m.max_neighbors ? count : m.max_neighbors, grid.pos, x, v,
                                          m.kern.h2, near, m.max_near);
    } else if constexpr (Index::cells) {
      kept = count = L.for_each_neighbor_listing(grid, x, true, v, nullptr, 0);
    } else {
      kept = count = L.for_each_in_range(grid.pos, 0, m.n_fluid + g->n_ghost, x, m.kern.h2, v);
    }
  }
  template <class Lanes, class V>
  CPS_HD static void forces(const Model& m, const Scene* g, const Arrays& a, const GridView<D>& grid, int i,
                            const Vec3& x, const Lanes& L, V& fv) {
    if constexpr (Index::lists) {
      int count = a.near_count[i];
      L.for_each_listed(a.near + size_t(i) * size_t(m.max_near), count < m.max_near ? count : m.max_near, grid.pos,
                        x, fv);
    } else if constexpr (Index::cells) {
      L.for_each_neighbor_listing(grid, x, true, fv, nullptr, 0);
    } else {
      L.for_each_in_range(grid.pos, 0, m.n_fluid + g->n_ghost, x, m.kern.h2, fv);
    }
  }
};

// stage 3: density (Poly6 over fluid and ghosts) and Tait pressure of fluid particles,
// copied to each particle's ghost. On rebuilds the cells are walked to list every particle
// within the list radius; every step the list is walked for the density and its entries
// within h are copied to a short list for the force stage.
// Near the die the kernel is cut by its surface: the sum is renormalised by the fluid share
// of the kernel (SphKernels::box_fraction), as if mirrored fluid filled the die, so the
// pressure there, and with it the buoyancy the contacts transmit, is hydrostatic.
template <class Index>
struct DensityStage {
  const Model* model;
  Scene* g;
  const Control* ctl;
  Arrays a;
  GridView<D> grid;
  template <class Lanes>
  CPS_HD void operator()(int i, const Lanes& L) const {
    if (halted(g)) return;
    const Model& m = *model;
    DensityVisitor<D> v{m.kern};
    Vec3 x = a.pos[i];
    const bool rebuild = rebuilding(g);
    int count = 0, kept = 0;
    PairWalk<Index>::density(m, g, a, grid, i, x, L, v, count, kept);
    float sum = L.sum(v.sum);
    if (!L.leader()) return;
    if (i == 0) prepare_frame(m, *ctl, *g);  // read by the force stage and the finalize
    if constexpr (Index::lists) {
      a.near_count[i] = kept;
      if (count > m.max_neighbors || kept > m.max_near) raise_first(&g->clock.bad, kBadNeighbors);
      if (rebuild) a.nbr_count[i] = count;
    }
    if (rebuild) a.ghost_slot[i] = a.ghost_of[a.perm[i]];
    float cut = m.kern.box_fraction(m.die.half, qrotate_inv(g->die.q, x - g->die.x));
    float rho = finish_density(m.sph, sum / (1.0f - fmin2(cut, 0.5f)));
    float p = tait_pressure(m.sph, rho);
    a.rho[i] = rho;
    a.prs[i] = p;
    // the ghost of this particle carries the same density and pressure
    int gs = a.ghost_slot[i];
    if (gs >= 0) {
      a.rho[gs] = rho;
      a.prs[gs] = p;
    }
  }
};

// stage 4: SPH forces (over the neighbours the density stage listed), XSPH, container-frame
// terms and die coupling of fluid particles; the per-particle contributions to this step's
// reductions
template <class Index>
struct ForceStage {
  const Model* model;
  const Scene* g;
  Arrays a;
  GridView<D> grid;
  template <class Lanes>
  CPS_HD void operator()(int i, const Lanes& L) const {
    if (halted(g)) return;  // the reduction of a step not taken is discarded
    const Model& m = *model;
    ForceVisitor<D> fv(m.kern, m.sph, a.vel, a.rho, a.prs, i, m.n_fluid);
    Vec3 x = a.pos[i];
    PairWalk<Index>::forces(m, g, a, grid, i, x, L, fv);
    fv.reduce(L);
    if (!L.leader()) return;
    Vec3 v = a.vel[i];
    Vec3 acc = fv.acceleration() + frame_acceleration(g->frame, x, v);
    StepSums s = StepSums::identity();
    // die: contact spring + drag on the particle, reaction on the die
    Vec3 ad;
    if (body_contact(m.contact, m.die, g->die, x, v, ad)) {
      acc += ad;
      Vec3 F = ad * (-m.sph.mass);
      s.force = F;
      s.torque = cross(x - g->die.x, F);
      s.contacts = 1;
    }
    a.acc[i] = acc;
    a.xsph[i] = fv.xsph_correction();
    float rho = a.rho[i];
    float err = rho / m.sph.rest_density - 1.0f;
    s.vmax2 = norm2(v);
    s.amax2 = norm2(acc);
    s.rho_err = err < 0.0f ? -err : err;
    s.rho_sum = rho;
    s.ke = 0.5f * m.sph.mass * s.vmax2;
    a.items[i] = s;
  }
};

// the largest speed of a step (fluid or die), and the dt its reductions select, before the
// end-time clipping
CPS_HD CPS_INLINE float max_speed(const StepSums& s, const RigidState& die) {
  return fmax2(fsqrt(s.vmax2), norm(die.v));
}
CPS_HD CPS_INLINE float sums_dt(const Model& m, const StepSums& s, const RigidState& die) {
  return choose_dt(m.dt, m.h, max_speed(s, die), fsqrt(s.amax2), m.c0, m.sph.viscosity / m.sph.rest_density);
}

// stage 5 (one item per scene): dt, die and container integration, clock
struct FinalizeStage {
  const Model* model;
  Scene* g;
  CPS_HD void operator()(int) const {
    const Model& m = *model;
    Scene& G = *g;
    Clock& C = G.clock;
    if (C.done || C.time >= C.end_time) {
      C.done = 1;
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
    G.rebuilds += G.rebuild[C.step & 1];
    G.rebuild[C.step & 1] = 0;  // this step's readers are done with its flag
    const StepSums& S = G.pending;
    float dt = sums_dt(m, S, G.die);
    const bool last = C.time + double(dt) >= C.end_time;
    if (last) dt = float(C.end_time - C.time);
    // faults found before integrating: a non-finite state is not integrated (the state
    // stays as it was); a runaway speed is integrated once more and then stops the run
    int fault = 0;
    if (!finite(S.vmax2) || !finite(S.amax2)) fault = kBadParticles;
    const bool runaway = !fault && max_speed(S, G.die) > 100.0f * m.c0;
    // the die under the fluid's reaction, then kept inside the sphere
    RigidState d = G.die;
    if (!fault) {
      integrate_box(m.die, m.body, G.frame, S.force, S.torque, dt, d);
      keep_box_in_sphere(m.die, m.wall.radius, m.body.restitution, d);
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
    C.dt = dt;
    C.time = last ? C.end_time : C.time + double(dt);  // land exactly on the end time
    C.done = last ? 1 : 0;                              // and stop there: later steps are no-ops
    C.step += 1;
    if (runaway) {
      C.bad = kBadSpeed;
      C.bad_step = C.step;
    }
  }
};

// stage 6: integrate fluid (symplectic Euler, XSPH-corrected drift), enforce the wall, and
// start the next step (its keys, cleared cell table and frame) in the same pass
struct IntegrateStage {
  const Model* model;
  Scene* g;
  Arrays a;
  CPS_HD void operator()(int i) const {
    const Model& m = *model;
    Vec3 x = Vec3::zero();
    // a step that was not taken (halted before integrating) leaves the particles as they are
    const bool taken = g->step_dt > 0.0f;
    if (i < m.n_fluid && !taken) x = a.pos[i];
    if (i < m.n_fluid && taken) {
      float dt = g->step_dt;
      Vec3 v = a.vel[i] + a.acc[i] * dt;
      x = a.pos[i] + (v + a.xsph[i]) * dt;
      reflect_at_wall(m.wall, x, v);
      if (!finite(x[0] + x[1] + x[2] + v[0] + v[1] + v[2])) raise_first(&g->clock.bad, kBadParticles);
      a.pos[i] = x;
      a.vel[i] = v;
      // the ghost follows its particle between rebuilds
      int gs = a.ghost_slot[i];
      if (gs >= 0) {
        a.pos[gs] = mirror_position(m.wall, x);
        a.vel[gs] = mirror_velocity(x, v);
      }
      // moved too far for the lists: the next step rebuilds (the clock is already the next)
      if (norm2(x - a.x_build[i]) > m.rebuild_disp2) raise_flag(&g->rebuild[g->clock.step & 1], 1);
    }
    start_step(m, a, i, &x);
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
