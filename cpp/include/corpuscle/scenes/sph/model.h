// Weakly compressible SPH in a closed box (seed 002's fluid box, and the Martin & Moyce dam
// break): the kinds `fluid-box`, `dam-break` (3-D) and `dam-break-2d`, one model generic in
// the dimension D.
//
// The model is DualSPHysics's (Crespo et al. 2015, Comput. Phys. Commun. 187; Dominguez et al.
// 2022, Comput. Part. Mech. 9): the continuity equation for the density, Tait's equation of
// state, the symmetric pressure gradient, Monaghan's artificial or the laminar viscosity,
// optional delta-SPH density diffusion (physics/sph_pair_terms.h), the CFL time step of
// physics/timestep.h (choose_dt_cfl) and the Verlet scheme (or symplectic Euler).
//
// Walls are dynamic boundary particles (DBC: Crespo, Gomez-Gesteira & Dalrymple 2007,
// Comput. Mater. Continua 5; DualSPHysics's default): layers of fixed particles on a lattice
// outside each face of the box, as deep as the kernel support, whose density evolves with the
// continuity equation from the fluid around them (and never falls below rho0), so their Tait
// pressure rises as fluid approaches and pushes it back. Chosen over mirrored ghosts because it
// works for any wall shape with no geometry in the pair loop, it is what the DualSPHysics
// reference runs use (so the side-by-side timing compares like with like), and it keeps one
// pair loop for every particle.
//
// Slots: fluid particles in [0, n_fluid), wall particles in [n_fluid, n) in every sorted
// order (they are keyed with tag 0 and 1 of the cell grid).
#pragma once
#include "corpuscle/physics/sph_kernel_families.h"
#include "corpuscle/scenes/sph/bodies.h"
#include "corpuscle/physics/sph_pair_terms.h"
#include "corpuscle/physics/tait.h"
#include "corpuscle/physics/timestep.h"
#include "corpuscle/sim/table.h"
#include "corpuscle/spatial/cell_grid.h"
#include "corpuscle/spatial/periodic.h"

namespace cps::sph {

constexpr int kMaxProbes = 64;  // probe points per scene
constexpr int kProbeSeries = 32;  // samples per probe the record holds between drains (probe.h)
constexpr int kTagFluid = 0, kTagWall = 1;

// time integration
constexpr int kVerlet = 0;           // Verlet (Monaghan 1994; DualSPHysics's default), one pair pass a step
constexpr int kSymplecticEuler = 1;  // v += a dt, x += v dt, rho += drho dt (needs a small CFL: the
                                     // explicit density-velocity coupling grows acoustic modes)

constexpr int kArtificialViscosity = 0;  // Monaghan 1992
constexpr int kLaminarViscosity = 1;     // Lo & Shao 2002 (DualSPHysics's "laminar")

// constant per-scene parameters
template <int D>
struct Model {
  int n_fluid, n_wall;
  SphKernelSet<D> kernels;  // density (interpolation) and gradient kernels, support h
  float h;                  // support radius
  float hs;                 // smoothing length of the pair terms (DualSPHysics's h)
  float mass;               // of every particle (fluid and wall): rho0 dp^D
  float rho0, c0, gamma, B; // Tait: p = B ((rho / rho0)^gamma - 1), B = c0^2 rho0 / gamma
  int viscosity;            // kArtificialViscosity / kLaminarViscosity
  ArtificialViscosity av;
  LaminarViscosity lv;
  DensityDiffusion dd;
  float cfl, dt_min, dt_max;
  int integrator;           // kVerlet / kSymplecticEuler
  int verlet_steps;         // Verlet: an Euler step every this many steps (DualSPHysics: 40)
  Vec<D> gravity;
  Vec<D> lo, hi;            // the box the fluid is held in (the walls' inner faces)
  Vec<D> domain_lo, domain_hi;  // the box with its wall layers (the cell grid's domain)
  // periodic axes (`boundary.periodic`): no walls across them, the domain's extent along them
  // (the box's) is the period; every index finds neighbours by the minimum image and the
  // integration wraps the positions (spatial/periodic.h)
  Periodic<D> per;
  // a background pressure added in the pressure gradient only (`fluid.background_pressure`;
  // 0 by default): a constant that keeps the pressure positive where the flow's own is
  // negative (a vortex's core), so the pair forces stay repulsive and the particles do not
  // clump (the tensile instability; Morris et al. 1997, Adami et al. 2013). The pressure
  // fields and probes report the equation of state's p without it.
  float p_back;
  // particle shifting (`sph.shifting` = A; 0: off, the default): each step a fluid particle
  // moves by -A hs |v| dt grad C, C = sum_j V_j W_ij its neighbours' volume fraction (Skillen
  // et al. 2013 as DualSPHysics has it; Lind et al. 2012), which keeps the particles evenly
  // spread where the flow stretches them (a vortex), with no free surface in the box. For the
  // canonical flows (periodic, closed boxes); the free-surface correction is not made.
  float shift_a;
  // the transport-velocity formulation (`sph.transport_velocity`; off by default; Adami, Hu &
  // Adams 2013, physics/sph_pair_terms.h): the fluid moves with v + dv~, dv~ = dt / 2 of the
  // push of the background pressure tvf_pb (Pa) over the step, stored per particle (the
  // pipeline's transport buffers, allocated only when on), and the momentum equation gains the
  // extra stress rho v dv~; the continuity equation sees the transport velocity. For flows with
  // no free surface (the push pulls a free surface apart)
  int tvf;
  float tvf_pb;
  // the `lists` index: slot lists within list_radius = h (1 + skin), built on the steps that
  // sort and reused until a particle has moved more than skin h / 2 since (rebuild_disp2 is
  // that distance squared); max_neighbors entries per slot (grown on overflow). Other
  // indexes: list_radius = h, unused.
  float list_radius;
  float rebuild_disp2;
  int max_neighbors;
  // the `lists` index's storage: 0 the slot lists' four bytes an entry (max_neighbors entries a
  // slot), 1 delta-coded bytes (spatial/delta_list.h: max_neighbors bytes a slot); the same
  // entries in the same order either way
  int list_delta;
  // the `lists` pair pass: lanes sharing a particle's list (1, 2, 4 or 8; CUDA threads, the CPU
  // runs them in turn); 0 in the parameters: chosen by the pipeline (auto_list_lanes)
  int lanes;
  // the pair pass's terms fixed at compile time when the model is the default one (Wendland
  // C2, artificial viscosity, Fourtakas diffusion: InteractStage<D, DefaultTerms>, every index
  // and backend); 0: always dispatched at run time (the same functions: on the CPU the same
  // sums bit for bit, on CUDA up to the compiler's contractions, which tests check)
  int fixed_terms;
  // ties within a cell of the sort broken by the particle's id (`sph.order_by_id`; always on
  // in a scene split over ranks): every particle's neighbours are then walked in an order that
  // does not depend on how the particles came to their slots, so a run split over ranks is
  // bitwise the run of one process with the key on (scenes/sph/ranks.h). 0: ties keep the
  // slots' last order (the default: one sort pass fewer)
  int order_by_id;
  // moving bodies (scenes/sph/bodies.h): their prescribed motions; the wall particles of each
  // follow its pose (the motion tables in the pipeline's buffer)
  int n_moving;
  BodyMotion motion[kMaxMovingBodies];
  // free bodies among them (kBodyFree) and the tank's contact on their particles
  // (bodies.h's tank_contact: the distance r0, the stiffness k and damping c per unit mass)
  int n_free;
  float contact_r0, contact_k, contact_c;
  int n_probes;
  float probes[kMaxProbes * D];
  // the kinematic viscosity the time step's diffusion limit needs (0 with artificial viscosity)
  CPS_HD float laminar_nu() const { return viscosity == kLaminarViscosity ? lv.nu0 : 0.0f; }
  CPS_HD Vec<D> probe(int k) const {
    Vec<D> x;
    for (int c = 0; c < D; ++c) x[c] = probes[k * D + c];
    return x;
  }
  // the probes' faces and sampling (probe.h): shape (kProbePoint, kProbeDisc, kProbeSquare),
  // size (m: the disc's diameter, the square's side), unit normal, sample points, interval (s;
  // 0: every step)
  int probe_shape[kMaxProbes];
  float probe_size[kMaxProbes];
  float probe_normal[kMaxProbes * D];
  int probe_samples[kMaxProbes];
  float probe_interval[kMaxProbes];
};

// Tait's equation of state (physics/tait.h): p = B ((rho / rho0)^gamma - 1)
template <int D>
CPS_HD CPS_INLINE float tait_pressure(const Model<D>& m, float rho) {
  return cps::tait_pressure(rho, m.rho0, m.B, m.gamma);
}

// per-step reductions over the particles (combined in a fixed order per backend)
struct StepSums {
  float amax2;      // largest squared fluid acceleration
  float vmax2;      // largest squared fluid speed
  float mu_max;     // largest |mu_ij| over the pairs (DualSPHysics's dt_cv)
  float ke;         // fluid kinetic energy
  float rho_min, rho_max;  // fluid density range
  float p_max;      // largest pressure (fluid and walls)
  long long nbrs;   // neighbours (within the support, self excluded) summed over the fluid
  int bad;          // particles with a non-finite rate

  CPS_HD static StepSums identity() {
    StepSums s;
    s.amax2 = s.vmax2 = s.mu_max = s.ke = 0.0f;
    s.rho_min = 3.402823466e38f;
    s.rho_max = -3.402823466e38f;
    s.p_max = -3.402823466e38f;
    s.nbrs = 0;
    s.bad = 0;
    return s;
  }
  CPS_HD static StepSums combine(const StepSums& a, const StepSums& b) {
    StepSums s;
    s.amax2 = fmax2(a.amax2, b.amax2);
    s.vmax2 = fmax2(a.vmax2, b.vmax2);
    s.mu_max = fmax2(a.mu_max, b.mu_max);
    s.ke = a.ke + b.ke;
    s.rho_min = fmin2(a.rho_min, b.rho_min);
    s.rho_max = fmax2(a.rho_max, b.rho_max);
    s.p_max = fmax2(a.p_max, b.p_max);
    s.nbrs = a.nbrs + b.nbrs;
    s.bad = a.bad + b.bad;
    return s;
  }
};
struct SumsOp {
  CPS_HD StepSums operator()(const StepSums& a, const StepSums& b) const { return StepSums::combine(a, b); }
};

constexpr int kBadParticles = 1;  // a density, velocity or position went non-finite
constexpr int kBadNeighbors = 2;  // a neighbour list overflowed (grown and the step repeated when memory allows)

// the input of the next step: a body acceleration added to gravity (shaking or tilting the
// box in its own frame: sloshing)
struct Control {
  float acc[3];
};

// the per-scene record
struct Scene {
  Clock clock;
  StepSums sums;     // the last step's reductions (diagnostics)
  StepSums pending;  // this step's, kept in sums once the step is taken
  float step_dt;     // the dt this step integrates with (0: not taken)
  int rebuild;             // `lists`: this step sorts and relists (raised by the last step's
                           // integration when a particle moved more than skin h / 2 since the build)
  long long rebuilds;      // `lists`: the steps taken that relisted
  long long outside;       // fluid particles outside the box after the last step
  long long outside_max;   // the most there were after any step
  // probes: pressure, velocity and the Shepard sum sum_j W_j V_j of the state a step starts
  // from (kernel interpolation over the fluid, DualSPHysics's MeasureTool), at probe_time
  double probe_time;
  float probe_p[kMaxProbes];
  float probe_v[kMaxProbes * 3];
  float probe_w[kMaxProbes];
  // the probes' series (probe.h): each probe's samples in a ring of kProbeSeries (slot
  // series_n % kProbeSeries), series_n the samples taken so far, series_next the time the
  // next one is due; the host drains the ring at least every kProbeSeries steps
  long long series_n[kMaxProbes];
  double series_next[kMaxProbes];
  double series_t[kMaxProbes * kProbeSeries];
  float series_p[kMaxProbes * kProbeSeries];
  // the moving bodies' poses at clock.time (bodies.h: c, R, v_c, w each)
  float body_pose[kMaxMovingBodies * kBodyPoseFloats];
  // the free bodies' states (bodies.h: c, q, v_c, w; checkpointed) and the force and torque
  // (about the centre of mass) of the fluid and the tank's contact in the last step's state
  double free_state[kMaxMovingBodies * kFreeStateDoubles];
  double body_force[kMaxMovingBodies * kBodyForceDoubles];
};

// what the pair loop reads of a neighbour j besides its position, packed for one vector load
// each (the same values as the arrays they come from): velocity (3-D; 2-D: the first two) and
// p / rho^2 in 16 bytes, rho and m / rho in 8 (2-D; 3-D: rho in the padding of the record's position)
struct alignas(16) PairVel {
  float v[3];
  float pr2;
};
struct alignas(8) PairRho {
  float rho, vol;
};
// a neighbour's record in the pair loop: its padded position (3-D: rho in the fourth float) and
// its PairVel in one 32-byte sector, so the position the walk loads brings the rest with it (one
// sector a neighbour, not one from each of two arrays)
template <int D>
struct alignas(32) PairRecord {
  VecA<D> x;
  PairVel pv;
};
static_assert(sizeof(PairRecord<3>) == 32 && sizeof(PairRecord<2>) == 32, "a record is one 32-byte sector");

}  // namespace cps::sph
