// The Magic 8-Ball's tables, declared once: its particle fields, the scalars of its
// per-scene record and its control. Each list is expanded where it is needed (the
// pipeline's views, sim/table.h's descriptions, the bindings, frames and checkpoints).
#pragma once
#include "corpuscle/scenes/magic8ball/model.h"

// X(name, C type, components, group, checkpointed, settable, storage, count):
// `storage` and `count` are expressions in the pipeline (cur: the current buffers,
// n: fluid particles, n_ghost: ghosts of the last rebuild)
#define CPS_M8_FIELDS(X)                                                                    \
  X(position, float, 3, "fluid", true, true, pos_[cur].data(), n)                           \
  X(velocity, float, 3, "fluid", true, true, vel_[cur].data(), n)                           \
  X(density, float, 1, "fluid", false, false, rho_.data(), n)                               \
  X(pressure, float, 1, "fluid", false, false, prs_.data(), n)                              \
  X(id, int, 1, "fluid", true, false, id_[cur].data(), n)                                   \
  X(acceleration, float, 3, "fluid", false, false, acc_.data(), n)                          \
  X(ghost_position, float, 3, "ghost", false, false, pos_[cur].data() + n, n_ghost)         \
  X(ghost_velocity, float, 3, "ghost", false, false, vel_[cur].data() + n, n_ghost)

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
