// The SPH box's tables, declared once: its particle fields (the fluid, then the wall
// particles), the scalars of its per-scene record and its control.
#pragma once
#include "corpuscle/scenes/sph/model.h"
#include "corpuscle/sim/field_store.h"

// the fields that own their storage (sim/field_store.h): buffers of every slot, the fluid's
// first (a field's view: the fluid slots [0, nf))
// X(name, C type, components, group, checkpointed, settable, recorded, moves)
#define CPS_SPH_FIELDS(X)                                            \
  X(position, float, D, "fluid", true, true, true, true)             \
  X(velocity, float, D, "fluid", true, true, false, true)            \
  X(density, float, 1, "fluid", true, true, true, true)              \
  X(id, int, 1, "fluid", true, false, true, true)                    \
  X(velocity_prev, float, D, "fluid", true, false, false, true)      \
  X(density_prev, float, 1, "fluid", true, false, false, true)       \
  X(pressure, float, 1, "fluid", false, false, true, false)          \
  X(acceleration, float, D, "fluid", false, false, false, false)     \
  X(density_rate, float, 1, "fluid", false, false, false, false)     \
  X(shift_grad, float, D, "fluid", false, false, false, false)     \
  X(halo, int, 1, "fluid", false, true, false, true)

// the wall particles' views of those buffers (slots [nf, nf + nw)), and the fluid's transport-
// velocity difference v~ - v (`sph.transport_velocity`: buffers of its own, allocated only when
// on; none otherwise)
// X(name, C type, components, group, checkpointed, settable, storage, count)
#define CPS_SPH_WALL_FIELDS(X)                                                                 \
  X(wall_position, float, D, "wall", true, true, fields_.position.cur(cur) + nf, nw)          \
  X(wall_id, int, 1, "wall", true, false, fields_.id.cur(cur) + nf, nw)                      \
  X(wall_density, float, 1, "wall", true, true, fields_.density.cur(cur) + nf, nw)            \
  X(wall_density_prev, float, 1, "wall", true, false, fields_.density_prev.cur(cur) + nf, nw) \
  X(wall_pressure, float, 1, "wall", false, false, fields_.pressure.cur(cur) + nf, nw)         \
  X(wall_velocity, float, D, "wall", false, true, fields_.velocity.cur(cur) + nf, nw)       \
  X(transport, float, D, "transport", true, false, transport_view(cur), transport_count())

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
  X(probe_weight, float, kMaxProbes, probe_w, false)    \
  X(probe_series_count, long long, kMaxProbes, series_n, false) \
  X(probe_series_time, double, kMaxProbes * kProbeSeries, series_t, false) \
  X(probe_series_pressure, float, kMaxProbes * kProbeSeries, series_p, false) \
  X(body_pose, float, kMaxMovingBodies * kBodyPoseFloats, body_pose, false) \
  X(free_state, double, kMaxMovingBodies * kFreeStateDoubles, free_state, true) \
  X(body_force, double, kMaxMovingBodies * kBodyForceDoubles, body_force, false)

// X(name, C type, count, member of Control)
#define CPS_SPH_CONTROLS(X) X(acceleration, float, 3, acc)

namespace cps::sph {

// the arrays the stages take (slots in sorted order): the stored fields' pointers (`name`: the
// current buffers, `name_alt`: the other ones) and the step's own
template <int D>
struct Arrays {
  CPS_FIELD_PTRS(CPS_SPH_FIELDS)
  PairRecord<D>* rec;  // the pair loop's neighbour records of the sorted state: the position
                       // padded for one vector load (the lists' walk; 3-D: the density in the
                       // fourth float, the pair loop's rho_j), velocity and p / rho^2
  PairRho* pr;       // 2-D: the pair loop's rho and m / rho (the density diffusion's V_j)
  Vec<D>* x_build;   // `lists`: positions at the last build (sorted slots; null for other indexes)
  // the transport-velocity formulation (null when off): v~ - v of every slot (the current and
  // the other buffer, gathered by the reorder as a moving field) and the step's background push
  Vec<D>* transport;
  Vec<D>* transport_alt;
  Vec<D>* transport_acc;
  StepSums* items;
};

}  // namespace cps::sph
