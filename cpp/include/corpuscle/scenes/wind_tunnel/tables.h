// The wind tunnel's tables, declared once: its particle fields, the scalars of its
// per-scene record and its control (expanded as the Magic 8-Ball's are).
#pragma once
#include "corpuscle/scenes/wind_tunnel/model.h"
#include "corpuscle/sim/field_store.h"

// the fields that own their storage (sim/field_store.h): the spheres' (dem/model.h) and the
// tunnel's own; D: the Pipeline's dimension
// X(name, C type, components, group, checkpointed, settable, recorded, moves)
#define CPS_WT_OWN_FIELDS(X) \
  X(scattered, int, 1, "fluid", true, false, false, true)  /* 1: touched the airfoil since it (re-)entered */
#define CPS_WT_FIELDS(X) CPS_DEM_MOVING_FIELDS(X) CPS_WT_OWN_FIELDS(X) CPS_DEM_STEP_FIELDS(X)

// X(name, C type, count, member of Scene, checkpointed)
#define CPS_WT_SCALARS(X) \
  CPS_CLOCK_SCALARS(X)                                      \
  X(sums_vmax2, float, 1, sums.vmax2, true)                       \
  X(sums_ke, float, 1, sums.ke, true)                             \
  X(airfoil_force, float, D, sums.force, true)                    \
  X(airfoil_moment, float, 1, sums.moment, true)                  \
  X(wall_force, float, D, sums.wall_force, true)                  \
  X(total_force, float, D, sums.total_force, true)                \
  X(body_torque, float, 3, sums.torque, true)                    \
  X(airfoil_contacts, int, 1, sums.contacts, true)                \
  X(recycled, long long, 1, recycled, true)                       \
  X(pushouts, long long, 1, pushouts, true)                       \
  X(block_len, double, 1, block_len, true)                        \
  X(nblocks, int, 1, nblocks, true)                               \
  X(block_t, double, 1, cur_t, true)                              \
  X(block_lift_sum, double, 1, cur_lift, true)                    \
  X(block_drag_sum, double, 1, cur_drag, true)                    \
  X(block_moment_sum, double, 1, cur_moment, true)                \
  X(blocks_lift, double, kMaxBlocks, blk_lift, true)              \
  X(blocks_drag, double, kMaxBlocks, blk_drag, true)              \
  X(blocks_moment, double, kMaxBlocks, blk_moment, true)         \
  X(inflow_distance, double, 1, inflow_x, true)                   \
  X(conveyor_next, int, kMaxRows, conv_next, true)

// X(name, C type, count, member of Control)
#define CPS_WT_CONTROLS(X)              \
  X(speed_scale, float, 1, speed_scale) \
  X(pitch, float, 1, pitch)

namespace cps::wt {

// structure of arrays; particles sorted by cell every step: the spheres' fields (dem::Arrays),
// the tunnel's own, a reorder that gathers every moving field of the table, and the step's
template <int D>
struct Arrays : dem::Arrays<D> {
  CPS_FIELD_MEMBERS(CPS_WT_OWN_FIELDS)
  CPS_FIELD_GATHER(CPS_WT_FIELDS)
  StepSums<D>* items;
  int* leaving;      // this step's leaving particles (slots; -1 once placed on the conveyor)
};

}  // namespace cps::wt
