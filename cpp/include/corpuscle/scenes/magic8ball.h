// The Magic 8-Ball (seed 001): SPH fluid in a sphere with mirrored ghosts, a rigid cube die
// coupled two ways, shaking through the container frame, adaptive dt.
//
// Model (constant), Globals (per-scene mutable scalars that live with the particles, on the
// device under CUDA) and Arrays (structure of arrays) are plain data; each stage below is a
// functor run by a backend's parallel_for. Nothing here knows which backend runs it.
#pragma once
#include "corpuscle/core/lanes.h"
#include "corpuscle/physics/boundary.h"
#include "corpuscle/physics/rigid.h"
#include "corpuscle/physics/sph.h"
#include "corpuscle/physics/timestep.h"
#include "corpuscle/spatial/grid.h"

namespace cps::m8 {

constexpr int D = 3;
constexpr int kMaxShakes = 32;

// a time window of container shaking: linear acceleration and torque on the shell
struct ShakeWindow {
  float start, end;
  Vec3 acc;
  Vec3 torque;
};

// constant per-scene parameters
struct Model {
  int n_fluid;           // fluid particles (ghost slots: the same number again)
  int max_neighbors;     // neighbour list capacity per particle (within the list radius)
  int max_near;          // capacity of the per-step list of neighbours within h
  float list_radius;     // neighbour lists and cells: h (1 + skin)
  float rebuild_disp2;   // rebuild once a particle moved this far (squared) since the last one
  float h;               // smoothing length = cell size
  SphParams sph;
  SphKernels<D> kern;
  float c0;              // sound speed
  SphereWall wall;
  float shell_inertia;   // kg m^2
  float spin_damping;    // 1/s
  Vec3 gravity;          // lab frame
  RigidBox die;
  ContactParams contact;
  BodyParams body;
  DtParams dt;
  GridSpec<D> grid;
  int n_shakes;
  ShakeWindow shakes[kMaxShakes];
};

// per-step reductions over the fluid (combined with StepSums::combine, a fixed order per backend)
struct StepSums {
  float vmax2, amax2;    // largest squared speed / acceleration
  float rho_err;         // largest |rho/rho0 - 1|
  float rho_sum;         // for the mean density
  float ke;              // kinetic energy (J)
  Vec3 force, torque;    // reaction on the die
  int contacts;          // particles touching the die

  CPS_HD static StepSums identity() {
    StepSums s;
    s.vmax2 = s.amax2 = s.rho_err = s.rho_sum = s.ke = 0.0f;
    s.force = s.torque = Vec3::zero();
    s.contacts = 0;
    return s;
  }
  CPS_HD static StepSums combine(const StepSums& a, const StepSums& b) {
    StepSums s;
    s.vmax2 = fmax2(a.vmax2, b.vmax2);
    s.amax2 = fmax2(a.amax2, b.amax2);
    s.rho_err = fmax2(a.rho_err, b.rho_err);
    s.rho_sum = a.rho_sum + b.rho_sum;
    s.ke = a.ke + b.ke;
    s.force = a.force + b.force;
    s.torque = a.torque + b.torque;
    s.contacts = a.contacts + b.contacts;
    return s;
  }
};
struct SumsOp {
  CPS_HD StepSums operator()(const StepSums& a, const StepSums& b) const { return StepSums::combine(a, b); }
};

// reasons a run is stopped as unstable (the first one raised is kept)
constexpr int kBadParticles = 1;  // a particle position or velocity went non-finite
constexpr int kBadDie = 2;        // the die's state went non-finite
constexpr int kBadSpeed = 3;      // a speed passed 100 times the sound speed
constexpr int kBadNeighbors = 4;  // a particle had more neighbours than its list holds

// per-scene mutable scalars
struct Globals {
  double time;
  double end_time;       // steps after it are no-ops (dt = 0)
  long long step;
  float dt;              // the dt of the last step
  int n_ghost;
  int done;              // end_time reached: later steps are no-ops
  int bad;               // why the run is unsound (kBad*, the first raised), 0 while it is sound;
                         // once raised, later steps are no-ops
  long long bad_step;    // the step that went bad (the state is kept at bad_step - 1 when the
                         // failure was found before integrating, at bad_step when after)
  RigidState die;
  Quat shell_q;          // container orientation (container -> lab)
  Vec3 shell_omega;      // container angular velocity (container frame)
  FrameMotion frame;     // this step's container-frame terms
  Vec3 user_acc, user_torque;  // control set through the API, added to the schedule
  StepSums sums;         // the reductions of the last step taken (or evaluation)
  StepSums pending;      // this step's reductions, kept in sums once the step is taken
  int rebuild[2];        // sort and relist in step s when rebuild[s & 1] (raised by step s - 1)
  long long rebuilds;    // steps that sorted and relisted
};

// structure of arrays; fluid in [0, n_fluid), ghosts after it, capacity 2 n_fluid
struct Arrays {
  Vec3 *pos, *vel, *pos_alt, *vel_alt;
  float *rho, *prs;
  int *id, *id_alt;      // fluid: persistent particle id; ghost: -1
  uint32_t *keys, *keys_sorted;
  int *idx, *perm;
  int *ghost_of;         // fluid index before the sort -> its ghost's sorted slot, or -1
  int *ghost_slot;       // sorted fluid index -> its ghost's slot, or -1 (kept between rebuilds)
  Vec3* x_build;         // positions at the last rebuild
  Vec3 *acc, *xsph;
  StepSums* items;
  int *nbr, *nbr_count;  // neighbour lists within the list radius (max_neighbors per fluid particle)
  int *near, *near_count;  // this step's neighbours within h (max_near per particle), for the forces
  uint32_t *cell_start, *cell_end;
};

// the control of the container at time t: schedule plus API input
CPS_HD CPS_INLINE void control_at(const Model& m, const Globals& g, double t, Vec3& acc, Vec3& torque) {
  acc = g.user_acc;
  torque = g.user_torque;
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
CPS_HD CPS_INLINE bool halted(const Globals* g) { return g->done != 0 || g->bad != 0; }

// cell keys of fluid particle i at x and of its ghost slot n + i, with identity values
CPS_HD CPS_INLINE void write_keys(const Model& m, const Arrays& a, int i, const Vec3& x) {
  const int n = m.n_fluid;
  a.keys[i] = m.grid.key(x, 0);
  a.keys[n + i] = needs_ghost(m.wall, x, m.list_radius) ? m.grid.key(mirror_position(m.wall, x), 1) : m.grid.sentinel();
  a.idx[i] = i;
  a.idx[n + i] = n + i;
}

// this step's container frame from the shake schedule, the API control and the shell state
CPS_HD CPS_INLINE void prepare_frame(const Model& m, Globals& g) {
  Vec3 acc, torque;
  control_at(m, g, g.time, acc, torque);
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

// the work that starts a step: clear the cell table, key every particle, set the frame
CPS_HD CPS_INLINE void start_step(const Model& m, Globals* g, const Arrays& a, int i, const Vec3* x) {
  if (uint32_t(i) < 2 * m.grid.ncells) {
    a.cell_start[i] = 0u;
    a.cell_end[i] = 0u;
  }
  if (i < m.n_fluid) {
    write_keys(m, a, i, *x);
    a.ghost_of[i] = -1;
  }
  if (i == 0) prepare_frame(m, *g);
}

// stage 1 (first step, or after the state was replaced): start a step from the current state
struct KeysStage {
  const Model* model;
  Globals* g;
  Arrays a;
  CPS_HD void operator()(int i) const {
    const Model& m = *model;
    Vec3 x = i < m.n_fluid ? a.pos[i] : Vec3::zero();
    start_step(m, g, a, i, &x);
    if (i == 0) g->rebuild[g->step & 1] = 1;  // a new state is always sorted and listed
  }
};

// whether this step sorts, reorders and relists (the rest of the time the order and the
// neighbour lists of the last rebuild stand: nothing moved more than the skin allows)
CPS_HD CPS_INLINE bool rebuilding(const Globals* g) { return g->rebuild[g->step & 1] != 0; }

struct RebuildFlag {
  const Globals* g;
  CPS_HD bool operator()() const { return rebuilding(g); }
};

// stage 2: gather particle arrays into sorted order, build ghosts, record cell ranges; when
// not rebuilding, carry the arrays over in their order (ghosts were moved by the integration)
struct ReorderStage {
  const Model* model;
  Globals* g;
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

// stage 3: density (Poly6 over fluid and ghosts) and Tait pressure of fluid particles,
// copied to each particle's ghost. On rebuilds the cells are walked to list every particle
// within the list radius; every step the list is walked for the density and its entries
// within h are copied to a short list for the force stage.
// Near the die the kernel is cut by its surface: the sum is renormalised by the fluid share
// of the kernel (SphKernels::box_fraction), as if mirrored fluid filled the die, so the
// pressure there, and with it the buoyancy the contacts transmit, is hydrostatic.
struct DensityStage {
  const Model* model;
  Globals* g;
  Arrays a;
  GridView<D> grid;
  template <class Lanes>
  CPS_HD void operator()(int i, const Lanes& L) const {
    if (halted(g)) return;
    const Model& m = *model;
    DensityVisitor<D> v{m.kern};
    Vec3 x = a.pos[i];
    int* list = a.nbr + size_t(i) * size_t(m.max_neighbors);
    const bool rebuild = rebuilding(g);
    int count;
    NoVisit none;
    if (rebuild) {
      // walk the cells and list every particle within h (1 + skin)
      count = L.for_each_neighbor_listing(grid, x, true, none, list, m.max_neighbors);
    } else {
      count = a.nbr_count[i];
    }
    // walk the list: the density, and this step's neighbours within h for the forces
    int* near = a.near + size_t(i) * size_t(m.max_near);
    int kept = L.for_each_listed_compacting(list, count < m.max_neighbors ? count : m.max_neighbors, grid.pos, x, v,
                                            m.kern.h2, near, m.max_near);
    float sum = L.sum(v.sum);
    if (!L.leader()) return;
    a.near_count[i] = kept;
    if (count > m.max_neighbors || kept > m.max_near) raise_first(&g->bad, kBadNeighbors);
    if (rebuild) {
      a.nbr_count[i] = count;
      a.ghost_slot[i] = a.ghost_of[a.perm[i]];
    }
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
struct ForceStage {
  const Model* model;
  const Globals* g;
  Arrays a;
  GridView<D> grid;
  template <class Lanes>
  CPS_HD void operator()(int i, const Lanes& L) const {
    if (halted(g)) return;  // the reduction of a step not taken is discarded
    const Model& m = *model;
    ForceVisitor<D> fv(m.kern, m.sph, a.vel, a.rho, a.prs, i, m.n_fluid);
    Vec3 x = a.pos[i];
    int count = a.near_count[i];
    L.for_each_listed(a.near + size_t(i) * size_t(m.max_near), count < m.max_near ? count : m.max_near, grid.pos, x,
                      fv);
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
  Globals* g;
  CPS_HD void operator()(int) const {
    const Model& m = *model;
    Globals& G = *g;
    if (G.done || G.time >= G.end_time) {
      G.done = 1;
      G.dt = 0.0f;
      return;
    }
    if (G.bad) {
      // found before integrating (this step's lists overflowed), or raised by the last
      // step's integration: the kept state is the last one integrated
      if (G.bad_step < 0) G.bad_step = G.bad == kBadNeighbors ? G.step + 1 : G.step;
      G.dt = 0.0f;
      return;
    }
    G.rebuilds += G.rebuild[G.step & 1];
    G.rebuild[G.step & 1] = 0;  // this step's readers are done with its flag
    const StepSums& S = G.pending;
    float dt = sums_dt(m, S, G.die);
    const bool last = G.time + double(dt) >= G.end_time;
    if (last) dt = float(G.end_time - G.time);
    // faults found before integrating: the step is not taken, the state stays sound
    int fault = 0;
    if (!finite(S.vmax2) || !finite(S.amax2)) fault = kBadParticles;
    else if (max_speed(S, G.die) > 100.0f * m.c0) fault = kBadSpeed;
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
      G.bad = fault;
      G.bad_step = G.step + 1;
      G.dt = 0.0f;
      return;
    }
    G.die = d;
    G.sums = S;
    // the container shell: angular velocity and orientation
    G.shell_omega += G.frame.alpha * dt;
    G.shell_q = qintegrate_body(G.shell_q, G.shell_omega, dt);
    G.dt = dt;
    G.time = last ? G.end_time : G.time + double(dt);  // land exactly on the end time
    G.done = last ? 1 : 0;                              // and stop there: later steps are no-ops
    G.step += 1;
  }
};

// stage 6: integrate fluid (symplectic Euler, XSPH-corrected drift), enforce the wall, and
// start the next step (its keys, cleared cell table and frame) in the same pass
struct IntegrateStage {
  const Model* model;
  Globals* g;
  Arrays a;
  CPS_HD void operator()(int i) const {
    const Model& m = *model;
    Vec3 x = Vec3::zero();
    // a step that was not taken (halted before integrating) leaves the particles as they are
    const bool taken = g->dt > 0.0f;
    if (i < m.n_fluid && !taken) x = a.pos[i];
    if (i < m.n_fluid && taken) {
      float dt = g->dt;
      Vec3 v = a.vel[i] + a.acc[i] * dt;
      x = a.pos[i] + (v + a.xsph[i]) * dt;
      reflect_at_wall(m.wall, x, v);
      if (!finite(x[0] + x[1] + x[2] + v[0] + v[1] + v[2])) raise_first(&g->bad, kBadParticles);
      a.pos[i] = x;
      a.vel[i] = v;
      // the ghost follows its particle between rebuilds
      int gs = a.ghost_slot[i];
      if (gs >= 0) {
        a.pos[gs] = mirror_position(m.wall, x);
        a.vel[gs] = mirror_velocity(x, v);
      }
      // moved too far for the lists: the next step rebuilds (g->step is already the next)
      if (norm2(x - a.x_build[i]) > m.rebuild_disp2) raise_flag(&g->rebuild[g->step & 1], 1);
    }
    start_step(m, g, a, i, &x);
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
