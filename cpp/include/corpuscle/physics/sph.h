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
  // one pair's term of the sum
  CPS_HD static float term(const MuellerKernels<D>& k, float r2) { return k.poly6.w_r2(r2); }
  CPS_HD void operator()(int, const Vec<D>&, float r2) { sum += term(k, r2); }
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

// one particle's sums (plain data: an index's per-lane accumulator can hold it)
template <int D>
struct ForceSum {
  int i;
  Vec<D> vi;
  float rho_i, pterm_i;
  Vec<D> acc_p, acc_v, dv_xsph;
};
// the pair terms over the fluid's arrays
template <int D>
struct ForcePairs {
  const MuellerKernels<D>& k;
  const Vec<D>* vel;
  const float* rho;
  const ForceTerms* terms;
  int n_fluid;  // indices below are fluid, the rest ghosts (XSPH ignores ghosts)

  CPS_HD ForceSum<D> begin(int i) const {
    ForceSum<D> s;
    s.i = i;
    s.vi = vel[i];
    s.rho_i = rho[i];
    s.pterm_i = terms[i].pterm;
    s.acc_p = s.acc_v = s.dv_xsph = Vec<D>::zero();
    return s;
  }
  CPS_HD void add(ForceSum<D>& s, int j, const Vec<D>& d, float r2) const {
    if (j == s.i) return;
    const float rinv = r2 > 0.0f ? frsqrt(r2) : 0.0f;
    const float r = r2 * rinv;
    const float rho_j = rho[j];
    const ForceTerms tj = terms[j];
    Vec<D> dv = vel[j] - s.vi;
    // symmetric pressure term
    float pterm = s.pterm_i + tj.pterm;
    s.acc_p -= k.spiky.grad_rinv(d, r, rinv) * pterm;
    // viscosity (the 1/rho_i factor is applied in acceleration())
    s.acc_v += dv * (k.visc.lap(r) * tj.inv_rho);
    // XSPH velocity smoothing over fluid neighbours only
    if (j < n_fluid) s.dv_xsph += dv * (k.poly6.w_r2(r2) * 2.0f / (s.rho_i + rho_j));
  }
  // (the particle mass, common to every pair, is applied once here)
  CPS_HD static Vec<D> acceleration(const SphParams& p, const ForceSum<D>& s) {
    return (s.acc_p + s.acc_v * (p.viscosity / s.rho_i)) * p.mass;
  }
  CPS_HD static Vec<D> xsph_correction(const SphParams& p, const ForceSum<D>& s) { return s.dv_xsph * (p.xsph * p.mass); }
};
// the visitor of a walk: ForcePairs over one particle's ForceSum
template <int D>
struct ForceVisitor {
  ForcePairs<D> pairs;
  const SphParams& p;
  ForceSum<D> s;
  CPS_HD ForceVisitor(const MuellerKernels<D>& k_, const SphParams& p_, const Vec<D>* vel_, const float* rho_,
                      const ForceTerms* terms_, int i_, int n_fluid_)
      : pairs{k_, vel_, rho_, terms_, n_fluid_}, p(p_), s(pairs.begin(i_)) {}
  CPS_HD void operator()(int j, const Vec<D>& d, float r2) { pairs.add(s, j, d, r2); }
  // combine the partial sums of cooperating lanes
  template <class Lanes>
  CPS_HD void reduce(const Lanes& L) {
    s.acc_p = L.sum(s.acc_p);
    s.acc_v = L.sum(s.acc_v);
    s.dv_xsph = L.sum(s.dv_xsph);
  }
  CPS_HD Vec<D> acceleration() const { return ForcePairs<D>::acceleration(p, s); }
  CPS_HD Vec<D> xsph_correction() const { return ForcePairs<D>::xsph_correction(p, s); }
};

}  // namespace cps
