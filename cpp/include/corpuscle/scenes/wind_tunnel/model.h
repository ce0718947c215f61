// The wind tunnel (seed 000): a 2-D soft-sphere gas streaming past an airfoil in a channel
// with walls top and bottom; particles leaving on the right re-enter at the inflow with
// free-stream statistics (constant count, steady flow); the reaction on the airfoil (lift,
// drag, moment about the quarter chord) is summed every step and averaged in blocks.
//
// Model (constant), Scene (the per-scene record: clock, diagnostics, the block averages),
// Control (the input of the next step) and Arrays (structure of arrays) are plain data.
#pragma once
#include "corpuscle/physics/dem.h"
#include "corpuscle/physics/polygon.h"
#include "corpuscle/physics/polygon_grid.h"
#include "corpuscle/sim/table.h"
#include "corpuscle/spatial/cell_grid.h"

namespace cps::wt {

constexpr int D = 2;
constexpr int kMaxEdges = 1024;  // airfoil polygon capacity (edges): e398 has 61, naca4 200
constexpr int kMaxBlocks = 64;   // block averages of the forces kept in the record

constexpr int kForwardEuler = 0;     // x += v dt, v += a dt (the seed's)
constexpr int kSymplecticEuler = 1;  // v += a dt, x += v dt

// constant per-scene parameters
struct Model {
  int n;                 // particles
  int integrator;        // kForwardEuler / kSymplecticEuler
  float radius, mass;
  int collide;           // particle-particle contacts on (1) or off (0: a collisionless gas)
  int reflexive;         // 0: gather (each particle sums its own contacts: reproducible);
                         // 1: reflexive (each pair once, the reaction added by atomics);
                         // 2: reflexive with warp-aggregated atomics on the device
  int recycle_scattered; // 1: a particle that touched the airfoil re-enters at the inflow when it
                         // reaches a wall (walls send no scattered particle back: free-molecular
                         // validation); 0: walls reflect every particle
  SpringDashpot pp;      // particle-particle
  SpringDashpot wall;    // particle-wall (top and bottom)
  SpringDashpot wing;    // particle-airfoil
  Vec2 lo, hi;           // the channel: inflow x = lo[0], outflow x = hi[0], walls y = lo[1], hi[1]
  float speed;           // free-stream speed U (along +x)
  float thermal;         // per-component thermal velocity spread / U (0: the seed's cold beam)
  float cell;            // the broad-phase grid's cell edge (m), at least a contact diameter
  int lbvh_stack;        // LBVH traversal stack entries per thread (shared memory on the device)
  float dt_fraction;     // the fastest particle moves at most this fraction of the radius per step
  float dt_max;
  Vec2 quarter_chord;    // moment reference point
  double measure_start;  // s: forces are averaged from here on (the steady part)
  double block_time;     // s: initial length of an averaging block (doubled when all are full)
  unsigned seed;         // re-entry random numbers
  int n_edges;
  Box2 bbox;             // of the airfoil, widened by the radius
  float edges[kEdgeStride * kMaxEdges];  // polygon edge records (polygon.h)
  PolygonGridCells foil_cells;  // the edges' grid (polygon_grid.h; its tables: the pipeline's buffers)
  CPS_HD PolygonEdges airfoil() const { return PolygonEdges{edges, n_edges}; }
  // the airfoil through its grid: the contact and push-out queries (the same hits as airfoil())
  CPS_HD PolygonGrid airfoil_grid() const { return PolygonGrid{airfoil(), foil_cells}; }
};

// per-step reductions (combined in a fixed order per backend)
struct StepSums {
  float vmax2;       // largest squared speed
  float ke;          // kinetic energy
  Vec2 force;        // on the airfoil (minus the particles' airfoil contact forces)
  float moment;      // on the airfoil about the quarter chord (counter-clockwise = nose up)
  Vec2 wall_force;   // the walls' forces on the particles
  Vec2 total_force;  // every contact force on the particles (pairs cancel)
  int contacts;      // particles touching the airfoil

  CPS_HD static StepSums identity() {
    StepSums s;
    s.vmax2 = s.ke = s.moment = 0.0f;
    s.force = s.wall_force = s.total_force = Vec2::zero();
    s.contacts = 0;
    return s;
  }
  CPS_HD static StepSums combine(const StepSums& a, const StepSums& b) {
    StepSums s;
    s.vmax2 = fmax2(a.vmax2, b.vmax2);
    s.ke = a.ke + b.ke;
    s.force = a.force + b.force;
    s.moment = a.moment + b.moment;
    s.wall_force = a.wall_force + b.wall_force;
    s.total_force = a.total_force + b.total_force;
    s.contacts = a.contacts + b.contacts;
    return s;
  }
};
struct SumsOp {
  CPS_HD StepSums operator()(const StepSums& a, const StepSums& b) const { return StepSums::combine(a, b); }
};

constexpr int kBadParticles = 1;  // a particle position or velocity went non-finite
constexpr int kBadTraversal = 2;  // an LBVH traversal stack would have overflowed

// the input of the next step
struct Control {
  float speed_scale;  // the re-entering free stream's speed is U (1 + speed_scale)
  float pitch;        // degrees added to the angle of attack (nose up), about the quarter chord
};

// the per-scene record
struct Scene {
  Clock clock;
  StepSums sums;        // the last step's reductions (diagnostics)
  StepSums pending;     // this step's, kept in sums once the step is taken
  float step_dt;        // the dt this step integrates with (0: not taken)
  long long recycled;   // particles re-entered at the inflow so far
  long long pushouts;   // particles projected out of the airfoil or back into the channel
  // block averages of the airfoil force since measure_start: time integrals of lift,
  // drag and moment per block (full blocks: block_len each; the last one partial)
  double block_len;
  int nblocks;          // full blocks
  double cur_t, cur_lift, cur_drag, cur_moment;  // the block in progress
  double blk_lift[kMaxBlocks], blk_drag[kMaxBlocks], blk_moment[kMaxBlocks];  // block means
};

// structure of arrays; particles sorted by cell every step
struct Arrays {
  Vec2 *pos, *vel, *pos_alt, *vel_alt;
  int *id, *id_alt;
  int *scattered, *scattered_alt;  // 1: touched the airfoil since it (re-)entered
  float* number_density;           // particles per unit area around each (grid cell block)
  Vec2* force;       // contact force on each particle (this step)
  float* pressure;   // sum of contact-force magnitudes (the seed's "pressure")
  int* contacts;     // overlapping neighbours, walls and airfoil
  StepSums* items;
};

}  // namespace cps::wt
