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

namespace cps {

// The CFL form of DualSPHysics (Monaghan & Kos 1999; Crespo et al. 2015, DualSPHysics paper):
//   dt = C min(dt_f, dt_cv),  dt_f = min_i sqrt(hs / |a_i|) = sqrt(hs / amax),
//   dt_cv = min_i hs / (c0 + max_j |mu_ij|) = hs / (c0 + mu_max),
// with mu_ij = hs v_ij . r_ij / (r_ij^2 + eta^2) (sph_mu in physics/sph_pair_terms.h; mu_max is
// the largest |mu_ij| over all pairs), hs the smoothing length (not the support radius), c0 the
// (largest) sound speed. choose_dt's acoustic limit h / (c0 + vmax) bounds the same thing by
// the largest speed instead of the pair term. With a laminar viscosity nu > 0 the viscous
// diffusion limit dt_nu = 0.125 hs^2 / nu (Morris, Fox & Zhu 1997, eq. 30) applies too, on its
// own coefficient (not scaled by the CFL number): an explicit diffusion step beyond it grows
// the shortest resolved wavelengths. nu = 0 (artificial viscosity) leaves DualSPHysics's form
// unchanged. Clamped to [dt_min, dt_max] as choose_dt is.
CPS_HD CPS_INLINE float sph_viscous_dt(float hs, float nu) { return 0.125f * hs * hs / nu; }

CPS_HD CPS_INLINE float choose_dt_cfl(float cfl, float hs, float amax, float c0, float mu_max, float nu,
                                      float dt_min, float dt_max) {
  float dt = hs / (c0 + mu_max);
  if (amax > 0.0f) dt = fmin2(dt, fsqrt(hs / amax));
  dt *= cfl;
  if (nu > 0.0f) dt = fmin2(dt, sph_viscous_dt(hs, nu));
  if (!finite(dt)) dt = dt_min;
  return fclamp(dt, dt_min, dt_max);
}

}  // namespace cps
