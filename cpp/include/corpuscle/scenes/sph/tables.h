// The SPH box's tables, declared once: its particle fields (the fluid, then the wall
// particles), the scalars of its per-scene record and its control.
#pragma once
#include "corpuscle/scenes/sph/model.h"

// X(name, C type, components, group, checkpointed, settable, storage, count)
// (cur: the current buffers, nf: fluid particles in slots [0, nf), nw: wall particles after them)
#define CPS_SPH_FIELDS(X)                                                          \
  X(position, float, D, "fluid", true, true, pos_[cur].data(), nf)                 \
  X(velocity, float, D, "fluid", true, true, vel_[cur].data(), nf)                 \
  X(density, float, 1, "fluid", true, true, rho_[cur].data(), nf)                  \
  X(id, int, 1, "fluid", true, false, id_[cur].data(), nf)                         \
  X(velocity_prev, float, D, "fluid", true, false, velm_[cur].data(), nf)          \
  X(density_prev, float, 1, "fluid", true, false, rhom_[cur].data(), nf)           \
  X(pressure, float, 1, "fluid", false, false, prs_.data(), nf)                    \
  X(acceleration, float, D, "fluid", false, false, acc_.data(), nf)                \
  X(density_rate, float, 1, "fluid", false, false, drho_.data(), nf)               \
  X(wall_position, float, D, "wall", true, true, pos_[cur].data() + nf, nw)        \
  X(wall_density, float, 1, "wall", true, true, rho_[cur].data() + nf, nw)         \
  X(wall_density_prev, float, 1, "wall", true, false, rhom_[cur].data() + nf, nw)  \
  X(wall_pressure, float, 1, "wall", false, false, prs_.data() + nf, nw)

// X(name, C type, count, member of Scene, checkpointed)
#define CPS_SPH_SCALARS(X)                              \
  CPS_CLOCK_SCALARS(X)                                  \
  X(sums_amax2, float, 1, sums.amax2, true)             \
  X(sums_vmax2, float, 1, sums.vmax2, true)             \
  X(sums_mu_max, float, 1, sums.mu_max, true)           \
  X(sums_ke, float, 1, sums.ke, true)                   \
  X(sums_rho_min, float, 1, sums.rho_min, true)         \
  X(sums_rho_max, float, 1, sums.rho_max, true)         \
  X(sums_p_max, float, 1, sums.p_max, true)             \
  X(sums_nbrs, long long, 1, sums.nbrs, true)           \
  X(rebuilds, long long, 1, rebuilds, true)             \
  X(outside, long long, 1, outside, true)               \
  X(outside_max, long long, 1, outside_max, true)       \
  X(probe_time, double, 1, probe_time, false)           \
  X(probe_pressure, float, kMaxProbes, probe_p, false)  \
  X(probe_velocity, float, 3 * kMaxProbes, probe_v, false) \
  X(probe_weight, float, kMaxProbes, probe_w, false)

// X(name, C type, count, member of Control)
#define CPS_SPH_CONTROLS(X) X(acceleration, float, 3, acc)
