// Adaptive time step: the smallest of the advective (CFL), acoustic, force and viscous
// limits (Monaghan 1992; Morris, Fox & Zhu 1997, eq. 30), clamped to [dt_min, dt_max].
#pragma once
#include "corpuscle/core/hd.h"

namespace cps {

struct DtParams {
  float dt_min, dt_max;
  float cfl_advective, cfl_acoustic, cfl_force, cfl_viscous;
};

// vmax: largest particle (or body) speed; amax: largest acceleration; c0: sound speed;
// nu: kinematic viscosity (0 for none)
CPS_HD CPS_INLINE float choose_dt(const DtParams& p, float h, float vmax, float amax, float c0, float nu) {
  float dt = p.dt_max;
  if (vmax > 0.0f) dt = fmin2(dt, p.cfl_advective * h / vmax);
  dt = fmin2(dt, p.cfl_acoustic * h / (c0 + vmax));
  if (amax > 0.0f) dt = fmin2(dt, p.cfl_force * fsqrt(h / amax));
  if (nu > 0.0f) dt = fmin2(dt, p.cfl_viscous * h * h / nu);
  if (!finite(dt)) dt = p.dt_min;
  return fclamp(dt, p.dt_min, p.dt_max);
}

}  // namespace cps
