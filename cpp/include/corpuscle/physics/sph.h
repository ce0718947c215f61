// Weakly compressible SPH: Tait equation of state and the pair visitors for density and
// forces. Each visitor is called by a spatial query (for_each_neighbor) for one particle i.
#pragma once
#include "corpuscle/physics/sph_kernel_families.h"
#include "corpuscle/physics/tait.h"

namespace cps {

// fluid constants shared by the visitors
struct SphParams {
  float mass;          // particle mass (kg)
  float rest_density;  // rho_0 (kg/m^3)
  float stiffness;     // Tait B (Pa)
  float gamma;         // Tait exponent
  float viscosity;     // dynamic viscosity mu (Pa s)
  float xsph;          // XSPH epsilon
  float density_floor; // lower bound on density (kg/m^3)
};

// Tait equation (physics/tait.h; Becker & Teschner 2007, eq. 7), negative pressure clamped to 0
CPS_HD CPS_INLINE float tait_pressure(const SphParams& p, float rho) {
  float pr = tait_pressure(rho, p.rest_density, p.stiffness, p.gamma);
  return pr > 0.0f ? pr : 0.0f;
}

// speed of sound of the Tait fluid at rest density: c0^2 = gamma B / rho0
CPS_HD CPS_INLINE float tait_sound_speed(const SphParams& p) {
  return tait_sound_speed(p.stiffness, p.rest_density, p.gamma);
}

// density: rho_i = m W(0) + sum_j m W(|x_ij|^2), fluid and ghost neighbours
template <int D>
struct DensityVisitor {
  const MuellerKernels<D>& k;
  float sum = 0.0f;
  CPS_HD void operator()(int, const Vec<D>&, float r2) { sum += k.poly6.w_r2(r2); }
};

// finish the density sum (self term is part of the neighbour sum: j == i has r2 = 0)
CPS_HD CPS_INLINE float finish_density(const SphParams& p, float kernel_sum) {
  float rho = p.mass * kernel_sum;
  return rho > p.density_floor ? rho : p.density_floor;
}

// pressure, viscosity and XSPH on particle i (Mueller 2003 eqs. 10, 14; Monaghan 1989 XSPH):
//   a_p    = -sum_j m (p_i / rho_i^2 + p_j / rho_j^2) grad W_spiky      (symmetric: momentum-conserving)
//   a_visc =  mu / rho_i sum_j m (v_j - v_i) / rho_j lap W_visc
//   dv_xsph = eps sum_{j fluid} m / rho_ij (v_j - v_i) W_poly6, rho_ij = (rho_i + rho_j) / 2
//
// The per-particle terms p / rho^2 and 1 / rho come precomputed (ForceTerms, written where the
// density is), 1 / r from one reciprocal square root and the mass applied to the sums: no
// division but XSPH's per pair.
struct alignas(8) ForceTerms {
  float pterm;    // p / rho^2
  float inv_rho;  // 1 / rho
  CPS_HD static ForceTerms of(float rho, float p) { return ForceTerms{p / (rho * rho), 1.0f / rho}; }
};

template <int D>
struct ForceVisitor {
  const MuellerKernels<D>& k;
  const SphParams& p;
  const Vec<D>* vel;
  const float* rho;
  const ForceTerms* terms;
  int i;
  int n_fluid;  // indices below are fluid, the rest ghosts (XSPH ignores ghosts)
  Vec<D> vi;
  float rho_i, pterm_i;
  Vec<D> acc_p = Vec<D>::zero();
  Vec<D> acc_v = Vec<D>::zero();
  Vec<D> dv_xsph = Vec<D>::zero();

  CPS_HD ForceVisitor(const MuellerKernels<D>& k_, const SphParams& p_, const Vec<D>* vel_, const float* rho_,
                      const ForceTerms* terms_, int i_, int n_fluid_)
      : k(k_), p(p_), vel(vel_), rho(rho_), terms(terms_), i(i_), n_fluid(n_fluid_) {
    vi = vel[i];
    rho_i = rho[i];
    pterm_i = terms[i].pterm;
  }

  CPS_HD void operator()(int j, const Vec<D>& d, float r2) {
    if (j == i) return;
    const float rinv = r2 > 0.0f ? frsqrt(r2) : 0.0f;
    const float r = r2 * rinv;
    const float rho_j = rho[j];
    const ForceTerms tj = terms[j];
    Vec<D> dv = vel[j] - vi;
    // symmetric pressure term
    float pterm = pterm_i + tj.pterm;
    acc_p -= k.spiky.grad_rinv(d, r, rinv) * pterm;
    // viscosity (the 1/rho_i factor is applied in acceleration())
    acc_v += dv * (k.visc.lap(r) * tj.inv_rho);
    // XSPH velocity smoothing over fluid neighbours only
    if (j < n_fluid) dv_xsph += dv * (k.poly6.w_r2(r2) * 2.0f / (rho_i + rho_j));
  }

  // combine the partial sums of cooperating lanes
  template <class Lanes>
  CPS_HD void reduce(const Lanes& L) {
    acc_p = L.sum(acc_p);
    acc_v = L.sum(acc_v);
    dv_xsph = L.sum(dv_xsph);
  }
  // (the particle mass, common to every pair, is applied once here)
  CPS_HD Vec<D> acceleration() const { return (acc_p + acc_v * (p.viscosity / rho_i)) * p.mass; }
  CPS_HD Vec<D> xsph_correction() const { return dv_xsph * (p.xsph * p.mass); }
};

}  // namespace cps
