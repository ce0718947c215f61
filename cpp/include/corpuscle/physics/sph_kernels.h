// SPH smoothing kernels of Mueller, Charypar & Gross (2003), "Particle-based fluid simulation
// for interactive applications", SCA 2003: Poly6 (density), Spiky gradient (pressure) and the
// viscosity-kernel Laplacian, in 2-D and 3-D, all with compact support h.
#pragma once
#include "corpuscle/core/vec.h"

namespace cps {

template <int D>
struct SphKernels {
  float h, h2;
  float poly6_c;    // W_poly6(r) = poly6_c (h^2 - r^2)^3
  float spiky_c;    // grad W_spiky(r) = -spiky_c (h - r)^2 r_hat
  float visc_lap_c; // lap W_visc(r) = visc_lap_c (h - r)

  CPS_HD static SphKernels make(float h) {
    SphKernels k;
    k.h = h;
    k.h2 = h * h;
    float h4 = k.h2 * k.h2;
    if constexpr (D == 3) {
      // Mueller et al. 2003, eqs. (20), (21), (22)
      k.poly6_c = 315.0f / (64.0f * kPi * h4 * h4 * h);
      k.spiky_c = 45.0f / (kPi * h4 * k.h2);
      k.visc_lap_c = 45.0f / (kPi * h4 * k.h2);
    } else {
      // the same kernels normalised over the disc
      k.poly6_c = 4.0f / (kPi * h4 * h4);
      k.spiky_c = 30.0f / (kPi * h4 * h);
      k.visc_lap_c = 40.0f / (kPi * h4 * h);
    }
    return k;
  }

  // Poly6 from the squared distance
  CPS_HD float poly6(float r2) const {
    if (r2 >= h2) return 0.0f;
    float t = h2 - r2;
    return poly6_c * t * t * t;
  }
  // Spiky gradient with respect to x_i, for d = x_i - x_j at distance r > 0
  CPS_HD Vec<D> spiky_grad(const Vec<D>& d, float r) const {
    if (r >= h || r <= 0.0f) return Vec<D>::zero();
    float t = h - r;
    return d * (-spiky_c * t * t / r);
  }
  // the same with 1 / r given (no division)
  CPS_HD Vec<D> spiky_grad(const Vec<D>& d, float r, float rinv) const {
    if (r >= h || r <= 0.0f) return Vec<D>::zero();
    float t = h - r;
    return d * (-spiky_c * t * t * rinv);
  }
  // fraction of the Poly6 kernel's mass beyond a plane at signed distance d from the particle
  // (d > 0: plane outside the particle), 3-D: Gamma(s) = 1/2 - 315/256 F(s), s = d/h, with
  // F(s) = s - 4 s^3/3 + 6 s^5/5 - 4 s^7/7 + s^9/9 the antiderivative of (1 - s^2)^4
  CPS_HD float poly6_beyond_plane(float d) const {
    static_assert(D == 3, "the half-space fraction is derived for 3-D Poly6");
    float s = fclamp(d / h, -1.0f, 1.0f);
    float s2 = s * s;
    float F = s * (1.0f + s2 * (-4.0f / 3.0f + s2 * (6.0f / 5.0f + s2 * (-4.0f / 7.0f + s2 / 9.0f))));
    return 0.5f - (315.0f / 256.0f) * F;
  }
  // fraction of the Poly6 kernel's mass inside an axis-aligned box [-half, half] for a particle
  // at p (box frame): the product over axes of the kernel's 1-D marginal mass in the box's slab.
  // Exact for a single face (a plane) and smooth across edges and corners; for a box smaller
  // than the kernel it shrinks with the box instead of saturating at the plane's 1/2.
  CPS_HD float box_fraction(const Vec<D>& half, const Vec<D>& p) const {
    float f = 1.0f;
    for (int k = 0; k < D; ++k) {
      // 1 minus the marginal mass beyond the upper face and beyond the lower face
      f *= 1.0f - poly6_beyond_plane(half[k] - p[k]) - poly6_beyond_plane(half[k] + p[k]);
    }
    return f;
  }
  // viscosity-kernel Laplacian
  CPS_HD float visc_lap(float r) const { return r >= h ? 0.0f : visc_lap_c * (h - r); }
};

}  // namespace cps
