// The Magic 8-Ball's tables, declared once: its particle fields, the scalars of its
// per-scene record and its control. Each list is expanded where it is needed (the
// pipeline's views, sim/table.h's descriptions, the bindings, frames and checkpoints).
#pragma once
#include "corpuscle/scenes/magic8ball/model.h"
#include "corpuscle/sim/field_store.h"

// the fields that own their storage (sim/field_store.h): buffers of every slot, the fluid's
// [0, N) then the ghosts' [N, 2 N) (a field's view: the fluid slots)
// X(name, C type, components, group, checkpointed, settable, recorded, moves)
#define CPS_M8_FIELDS(X)                                             \
  X(position, float, 3, "fluid", true, true, true, true)             \
  X(velocity, float, 3, "fluid", true, true, false, true)            \
  X(density, float, 1, "fluid", false, false, true, false)           \
  X(pressure, float, 1, "fluid", false, false, true, false)          \
  X(id, int, 1, "fluid", true, false, true, true)                    \
  X(acceleration, float, 3, "fluid", false, false, false, false)

// the ghosts' views of those buffers (slots [n, n + n_ghost) of a single scene)
// X(name, C type, components, group, checkpointed, settable, storage, count)
#define CPS_M8_GHOST_FIELDS(X)                                                                \
  X(ghost_position, float, 3, "ghost", false, false, fields_.position.cur(cur) + n, n_ghost) \
  X(ghost_velocity, float, 3, "ghost", false, false, fields_.velocity.cur(cur) + n, n_ghost)

// X(name, C type, count, member of Scene, checkpointed)
#define CPS_M8_SCALARS(X) \
  CPS_CLOCK_SCALARS(X)                                      \
  X(die_position, float, 3, die.x, true)                        \
  X(die_velocity, float, 3, die.v, true)                        \
  X(die_orientation, float, 4, die.q, true)                     \
  X(die_angular_velocity_body, float, 3, die.w_body, true)      \
  X(shell_orientation, float, 4, shell_q, true)                 \
  X(shell_angular_velocity, float, 3, shell_omega, true)        \
  X(rebuilds, long long, 1, rebuilds, true)                     \
  X(sums_vmax2, float, 1, sums.vmax2, true)                     \
  X(sums_amax2, float, 1, sums.amax2, true)                     \
  X(sums_rho_err, float, 1, sums.rho_err, true)                 \
  X(sums_rho_sum, float, 1, sums.rho_sum, true)                 \
  X(sums_ke, float, 1, sums.ke, true)                           \
  X(sums_force, float, 3, sums.force, true)                     \
  X(sums_torque, float, 3, sums.torque, true)                   \
  X(sums_contacts, int, 1, sums.contacts, true)                 \
  X(n_ghost, int, 1, n_ghost, false)

// X(name, C type, count, member of Control)
#define CPS_M8_CONTROLS(X)          \
  X(acceleration, float, 3, acc)    \
  X(torque, float, 3, torque)

namespace cps::m8 {

// structure of arrays; fluid in [0, n_fluid), ghosts after it, capacity 2 n_fluid: the stored
// fields' pointers (tables.h: `name`, the current buffers, `name_alt`, the other ones; id:
// the fluid's persistent particle id, a ghost's -1) and the step's own
struct Arrays {
  CPS_FIELD_PTRS(CPS_M8_FIELDS)
  ForceTerms* terms;     // p / rho^2 and 1 / rho of every slot (the force pass's per-particle terms)
  uint32_t *keys, *keys_sorted;
  uint64_t *keys64, *keys64_sorted;  // a batch's segmented keys (several scenes)
  int key_low_bits;      // a batch's keys: 32-bit in keys / keys_sorted, the cell key in the low key_low_bits
                         // (0: 64-bit in keys64 / keys64_sorted, the cell key in the low 32)
  int *idx, *perm;
  int *ghost_of;         // fluid index before the sort -> its ghost's sorted slot, or -1
  int *ghost_slot;       // sorted fluid index -> its ghost's slot, or -1 (kept between rebuilds)
  Vec3* x_build;         // positions at the last rebuild
  Vec3* xsph;
  StepSums* items;
  int *nbr, *nbr_count;  // neighbour lists within the list radius (max_neighbors per fluid particle)
  int *near, *near_count;  // this step's neighbours within h (max_near per particle), for the forces
  uint32_t *cell_start, *cell_end;
};

}  // namespace cps::m8
