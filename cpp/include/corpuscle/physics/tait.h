// Tait's equation of state (Batchelor 1967; Monaghan 1994), p = B ((rho / rho0)^gamma - 1),
// its inverse, and the stiffness B and sound speed c0 that go with it: the one definition the
// 8-ball (physics/sph.h), the SPH box (scenes/sph/model.h, build.h) and, through the bindings
// (tait_pressure, tait_density, ... of corpuscle._core), Python's hydrostatic start use. T is
// float in the core; Python asks in double (core/real.h).
#pragma once

#include "corpuscle/core/real.h"

namespace cps {

// p = B ((rho / rho0)^gamma - 1) (negative below rho0; the 8-ball clamps it, the box does not)
template <class T>
CPS_HD CPS_INLINE T tait_pressure(T rho, T rho0, T B, T gamma) {
  return B * (tpow(rho / rho0, gamma) - T(1));
}

// the density at pressure p: rho = rho0 (1 + p / B)^(1 / gamma)
template <class T>
CPS_HD CPS_INLINE T tait_density(T p, T rho0, T B, T gamma) {
  return rho0 * tpow(T(1) + p / B, T(1) / gamma);
}

// the stiffness for a sound speed c0 at rest: B = c0^2 rho0 / gamma
template <class T>
CPS_HD CPS_INLINE T tait_stiffness(T c0, T rho0, T gamma) {
  return c0 * c0 * rho0 / gamma;
}

// the sound speed at rest density: c0 = sqrt(gamma B / rho0)
template <class T>
CPS_HD CPS_INLINE T tait_sound_speed(T B, T rho0, T gamma) {
  return tsqrt(gamma * B / rho0);
}

}  // namespace cps
