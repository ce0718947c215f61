// The wind tunnel (seed 000): a soft-sphere gas streaming past an airfoil in a channel with
// walls top and bottom; particles leaving on the right re-enter at the inflow with free-stream
// statistics (constant count, steady flow); the reaction on the airfoil (lift, drag, moment
// about the quarter chord) is summed every step and averaged in blocks.
//
// The dimension is a template parameter: D = 2 is the seed's scene (`wind-tunnel`); D = 3
// (`wind-tunnel-3d`) is the same channel with a span along z, periodic (a particle leaving
// through z = hi re-enters at z = lo, and contacts reach across: the span-periodic channel of a
// 2-D section test, with no end walls and so no end-wall boundary layers), and the airfoil
// section extruded across the whole span: its contact is the 2-D polygon one in x-y, the z
// component untouched, and its force has no z component. Every stage is the same code for
// both (stages.h); what differs is behind `if constexpr (D == 3)`.
//
// Model (constant), Scene (the per-scene record: clock, diagnostics, the block averages),
// Control (the input of the next step) and Arrays (structure of arrays) are plain data.
#pragma once
#include "corpuscle/dem/mesh_body.h"
#include "corpuscle/dem/model.h"
#include "corpuscle/physics/dem.h"
#include "corpuscle/physics/polygon.h"
#include "corpuscle/physics/polygon_grid.h"
#include "corpuscle/sim/table.h"
#include "corpuscle/spatial/cell_grid.h"

namespace cps::wt {

constexpr int kMaxEdges = 1024;  // airfoil polygon capacity (edges): e398 has 61, naca4 200
constexpr int kMaxBlocks = 64;   // block averages of the forces kept in the record
constexpr int kMaxRows = 16384;  // inflow conveyor rows (the cold beam's lattice rows)

using dem::kForwardEuler;     // x += v dt, v += a dt (the seed's)
using dem::kSymplecticEuler;  // v += a dt, x += v dt

// constant per-scene parameters: the soft spheres' (dem/model.h: n, radius, mass, the
// pair law, the contact form, the integrator, the channel as the index's domain lo/hi, the
// grid cell, the tree's stack, the dt rule; D = 3: z periodic) and the tunnel's own
template <int D>
struct Model : dem::SoftSpheres<D> {
  static_assert(D == 2 || D == 3, "the wind tunnel is 2-D or 3-D");
  // (lo, hi: the channel: inflow x = lo[0], outflow x = hi[0], walls y = lo[1], hi[1];
  // D = 3: the periodic span z in [lo[2], hi[2]))
  int recycle_scattered; // 1: a particle that touched the airfoil re-enters at the inflow when it
                         // reaches a wall (walls send no scattered particle back: free-molecular
                         // validation); 0: walls reflect every particle
  SpringDashpot wall;    // particle-wall (top and bottom)
  SpringDashpot wing;    // particle-airfoil
  float speed;           // free-stream speed U (along +x)
  float thermal;         // per-component thermal velocity spread / U (0: the seed's cold beam)
  Vec2 quarter_chord;    // moment reference point (in x-y; D = 3: the quarter-chord line along z)
  double measure_start;  // s: forces are averaged from here on (the steady part)
  double block_time;     // s: initial length of an averaging block (doubled when all are full)
  unsigned seed;         // re-entry random numbers
  // the cold beam's inflow (stages.h, "The inflow conveyor"): a lattice of slots moving in at
  // the stream's speed, conv_rows rows, conv_ny heights dy apart from conv_y0 (D = 3: in
  // conv_rows / conv_ny layers dz apart from conv_z0 across the span), columns dx apart; 0 rows:
  // re-entry at a uniformly random height (a thermal or collisionless gas)
  int conv_rows, conv_ny;
  float conv_y0, conv_dy, conv_dx, conv_z0, conv_dz;
  int n_edges;
  Box2 bbox;             // of the airfoil (in x-y)
  float edges[kEdgeStride * kMaxEdges];  // polygon edge records (polygon.h)
  PolygonGridCells foil_cells;  // the edges' grid (polygon_grid.h; its tables: the pipeline's buffers)
  // D = 3: a fixed body from a closed triangle mesh (a `[[bodies]]` entry), its triangles held
  // in the engine's LBVH (dem/mesh_body.h: built once by the pipeline's constructor from the
  // host records body_host, which only that constructor reads); contact by signed distance
  // with the law `wing`, its reaction summed as the airfoil's (force; moment about body_ref)
  int n_tris;               // 0: no body
  const float* body_host;   // the host triangle records (physics/triangle.h), construction only
  float body_lo[3], body_hi[3];  // the mesh's box
  Vec3 body_ref;            // the torque's reference point (the body's centroid)
  MeshTreeView body;        // the queries (device pointers)
  CPS_HD PolygonEdges airfoil() const { return PolygonEdges{edges, n_edges}; }
  // the airfoil through its grid: the contact and push-out queries (the same hits as airfoil())
  CPS_HD PolygonGrid airfoil_grid() const { return PolygonGrid{airfoil(), foil_cells}; }
};

// per-step reductions (combined in a fixed order per backend)
template <int D>
struct StepSums {
  float vmax2;       // largest squared speed
  float ke;          // kinetic energy
  Vec<D> force;      // on the airfoil (minus the particles' airfoil contact forces; D = 3: the whole
                     // span's, z component 0)
  float moment;      // on the airfoil about the quarter chord (counter-clockwise = nose up; about z)
  Vec<D> wall_force;   // the walls' forces on the particles
  Vec<D> total_force;  // every contact force on the particles (pairs cancel)
  Vec3 torque;       // D = 3: on the mesh body about its reference point (0 without one)
  int contacts;      // particles touching the airfoil (or the mesh body)

  CPS_HD static StepSums identity() {
    StepSums s;
    s.vmax2 = s.ke = s.moment = 0.0f;
    s.force = s.wall_force = s.total_force = Vec<D>::zero();
    s.torque = Vec3::zero();
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
    s.torque = a.torque + b.torque;
    s.contacts = a.contacts + b.contacts;
    return s;
  }
};

using dem::kBadParticles;  // a particle position or velocity went non-finite
using dem::kBadTraversal;  // an LBVH traversal stack would have overflowed

// the input of the next step
struct Control {
  float speed_scale;  // the re-entering free stream's speed is U (1 + speed_scale)
  float pitch;        // degrees added to the angle of attack (nose up), about the quarter chord
};

// the per-scene record
template <int D>
struct Scene {
  Clock clock;
  StepSums<D> sums;     // the last step's reductions (diagnostics)
  StepSums<D> pending;    // this step's, kept in sums once the step is taken
  float step_dt;        // the dt this step integrates with (0: not taken)
  long long recycled;   // particles re-entered at the inflow so far
  long long pushouts;   // particles projected out of the airfoil or back into the channel
  // block averages of the airfoil force since measure_start: time integrals of lift,
  // drag and moment per block (full blocks: block_len each; the last one partial)
  double block_len;
  int nblocks;          // full blocks
  double cur_t, cur_lift, cur_drag, cur_moment;  // the block in progress
  double blk_lift[kMaxBlocks], blk_drag[kMaxBlocks], blk_moment[kMaxBlocks];  // block means
  // the inflow conveyor: how far the stream has moved in since t = 0 (the slots' phase), the
  // next free column of each row, each row's claim of this step (the smallest id wanting it;
  // INT_MAX between steps) and this step's leaving particles
  double inflow_x;
  int conv_next[kMaxRows];
  int conv_claim[kMaxRows];
  int n_leaving;
};


}  // namespace cps::wt
