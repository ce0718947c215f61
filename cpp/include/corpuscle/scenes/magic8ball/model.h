// The Magic 8-Ball (seed 001): SPH fluid in a sphere with mirrored ghosts, a rigid cube die
// coupled two ways, shaking through the container frame, adaptive dt.
//
// Model (constant), Scene (the per-scene record: clock, state, diagnostics, scratch),
// Control (the input of the next step, in its own buffer) and Arrays (structure of arrays)
// are plain data; nothing here knows which backend runs it.
#pragma once
#include "corpuscle/physics/boundary.h"
#include "corpuscle/physics/rigid.h"
#include "corpuscle/physics/sph.h"
#include "corpuscle/physics/timestep.h"
#include "corpuscle/sim/table.h"
#include "corpuscle/spatial/cell_grid.h"

namespace cps::m8 {

constexpr int D = 3;
constexpr int kMaxShakes = 32;

// a time window of container shaking: linear acceleration and torque on the shell
struct ShakeWindow {
  double start, end;  // s, compared with the double clock
  Vec3 acc;
  Vec3 torque;
};

// constant parameters shared by every scene of a state (what a study varies per scene is in
// ScenePhysics, in each scene's record)
struct Model {
  int n_fluid;           // fluid slots of each scene, the batch-wide most (ghost slots: the same again)
  int n_scenes;          // independent scenes of the same model in one state (1: a single run)
  int max_neighbors;     // neighbour list capacity per particle (within the list radius)
  int max_near;          // capacity of the per-step list of neighbours within h
  int lanes;             // CUDA lanes per particle in the pair stages: 32 (a warp), 16, 8 or 4 (the CPU: one)
  int list_scan;         // lists: rebuilt by a scan of each particle's whole scene (1) or the cell walk (0)
  int wide_keys;         // a batch sorts 64-bit keys even where 32-bit ones hold them (a test's switch)
  int path;              // the step's path: -1 chosen (chip where a batch's scenes fit), 0 general, 1 chip
                         // (a device's), 2 chip also on the CPU (its tiles emulated: the tests' switch)
  double max_list_bytes; // the lists may grow to this on overflow (0: what the backend has free)
  float list_radius;     // neighbour lists and cells: h (1 + skin)
  float skin_distance;   // list_radius - h: how far pairs may close in before the lists are stale (0: every step)
  float h;               // smoothing length
  MuellerKernels<D> kern;  // Poly6, Spiky, viscosity (physics/sph_kernel_families.h)
  SphereWall wall;
  float shell_inertia;   // kg m^2
  float spin_damping;    // 1/s
  Vec3 gravity;          // lab frame
  ContactParams contact;
  BodyParams body;
  DtParams dt;
  CellGridSpec<D> grid;  // cells of the list radius over the sphere and its ghosts; tags: 0 fluid, 1 ghosts
  int n_shakes;
  ShakeWindow shakes[kMaxShakes];
};

// the parameters a study varies per scene: the fluid's (particle mass, stiffness, viscosity,
// ...), the die's size, mass and inertia, and how many of the scene's slots hold particles.
// A scene of n_active < Model::n_fluid particles keeps them in the first n_active slots of its
// range; the rest are inactive (keyed past every cell, never visited, never integrated).
struct ScenePhysics {
  SphParams sph;
  RigidBox die;
  float c0;              // sound speed (from sph)
  int n_active;          // fluid particles of the scene (at most Model::n_fluid)
};

// A slot's sort key within its scene: the grid's key of its cell with the layer as the tag
// (0: fluid, 1: ghost), 32-bit (build_model checks the width); an unused slot (an inactive
// fluid slot, a fluid particle without a ghost) gets all ones in those bits and sorts last.
// Each scene has its own cell table (the grid's two tags) at scene * cells_per_scene.
CPS_HD CPS_INLINE int key_bits(const Model& m) { return m.grid.key_bits; }
CPS_HD CPS_INLINE uint32_t unused_key(const Model& m) { return ~uint32_t(0) >> (32 - key_bits(m)); }
CPS_HD CPS_INLINE uint32_t cell_key(const Model& m, const Vec3& x, int layer) { return uint32_t(m.grid.key(x, layer)); }
CPS_HD CPS_INLINE size_t cells_per_scene(const Model& m) { return size_t(m.grid.table_size()); }

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

// reasons a run is stopped as unstable (Clock::bad; the first one raised is kept)
constexpr int kBadParticles = 1;  // a particle position or velocity went non-finite
constexpr int kBadDie = 2;        // the die's state went non-finite
constexpr int kBadSpeed = 3;      // a speed passed 100 times the sound speed
constexpr int kBadNeighbors = 4;  // a particle had more neighbours than its list holds

// the input of the next step, added to the shake schedule: written from the host into its
// own buffer, read by the step's first stage; changing it rebuilds nothing
struct Control {
  Vec3 acc;     // container linear acceleration (m/s^2)
  Vec3 torque;  // torque on the shell (N m)
};

// the per-scene record: one copy brings all of it to the host
struct Scene {
  Clock clock;
  ScenePhysics phys;     // constant: the scene's own parameters
  // state the next step reads (checkpointed)
  RigidState die;
  Quat shell_q;          // container orientation (container -> lab)
  Vec3 shell_omega;      // container angular velocity (container frame)
  long long rebuilds;    // steps that sorted and relisted
  // diagnostics: the reductions of the last step taken (or evaluation)
  StepSums sums;
  // scratch of the step in flight
  FrameMotion frame;     // this step's container-frame terms
  StepSums pending;      // this step's reductions, kept in sums once the step is taken
  float step_dt;         // the dt this step integrates with (0: the step is not taken)
  int rebuild[2];        // sort and relist in step s when rebuild[s & 1] (a new state: raised before step s)
  int moved[2];          // since the last rebuild: the largest squared displacement of a fluid particle
                         // ([0]) and of a ghost that matters ([1]), as float bits (measured by the
                         // integration; see moved_too_far)
  int n_ghost;           // ghost particles of the last rebuild
};


}  // namespace cps::m8
