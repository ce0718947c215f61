// Pair terms of weakly compressible SPH (the DualSPHysics set): Monaghan's artificial
// viscosity, the laminar viscosity of Morris et al. / Lo & Shao, and delta-SPH density
// diffusion (Molteni & Colagrossi 2009; Fourtakas et al. 2019). Each function gives the
// contribution of neighbour j to particle i, for
//   d  = x_i - x_j (r_ij),  r2 = |d|^2,  dv = v_i - v_j (v_ij),  gradW = grad_i W(d) (the
//   gradient kernel of sph_kernel_families.h, or any other, evaluated at d),
// so the pair (j, i) is the same call with d, dv and gradW negated and i, j swapped.
//
// Smoothing length: these formulas were published with a smoothing length hs (Monaghan's h,
// DualSPHysics's h) in mu_ij, eta^2 = 0.01 hs^2 and the diffusion's delta hs c0. That is NOT the
// support radius h of the kernels here: pass hs explicitly (for the cubic spline and Wendland
// with support 2 hs, hs = h / 2; DualSPHysics's dam break uses hs = 1.732 dp, support 2 hs).
//
// Conservation (tests/physics/test_sph_pair_terms.py checks each):
//   - the viscosities give m_i a_ij = -m_j a_ji exactly in exact arithmetic (momentum): their
//     scalar factors are symmetric in (i, j) and multiply an antisymmetric vector;
//   - the density diffusion gives V_i D_ij = -V_j D_ji (V = m / rho), so sum_i V_i drho_i/dt
//     = 0: the hydrostatic correction is taken as an odd function of z_ij (see below).
//
// Divisions and powers here are fdiv_fast / fpow_fast (core/hd.h): the host evaluates them
// exactly as written, the device with its approximate instructions (the pair loop's cost).
#pragma once
#include "corpuscle/core/vec.h"

namespace cps {

// mu_ij = hs v_ij . r_ij / (r_ij^2 + eta^2) (Monaghan 1992, section 4); |mu_ij| is also the
// pair's speed in the DualSPHysics CFL limit dt_cv (physics/timestep.h, choose_dt_cfl)
// (inv_den = 1 / (r^2 + eta^2) and vr = v_ij . r_ij given: what a pair loop computes once for
// every term, one reciprocal where each term would divide)
CPS_HD CPS_INLINE float sph_inv_den(float r2, float eta2) { return fdiv_fast(1.0f, r2 + eta2); }
CPS_HD CPS_INLINE float sph_mu_inv(float hs, float vr, float inv_den) { return hs * vr * inv_den; }
template <int D>
CPS_HD CPS_INLINE float sph_mu(float hs, float eta2, const Vec<D>& d, const Vec<D>& dv, float r2) {
  return sph_mu_inv(hs, dot(dv, d), sph_inv_den(r2, eta2));
}

// ---- Monaghan artificial viscosity (Monaghan 1992, section 4; Monaghan & Gingold 1983) ----
//   Pi_ij = (-alpha cbar_ij mu_ij + beta mu_ij^2) / rhobar_ij  if v_ij . r_ij < 0, else 0
//   cbar = (c_i + c_j) / 2, rhobar = (rho_i + rho_j) / 2, eta^2 = 0.01 hs^2
//   a_i += -m_j Pi_ij grad_i W_ij
// Pi_ij >= 0 for approaching pairs, so the pair force is repulsive along r_ij and its power
// -m_i m_j Pi_ij v_ij . grad_i W_ij is <= 0 (dissipative). DualSPHysics: beta = 0.
struct ArtificialViscosity {
  float alpha, beta, hs, eta2;
  CPS_HD static ArtificialViscosity make(float alpha, float beta, float hs) {
    return ArtificialViscosity{alpha, beta, hs, 0.01f * hs * hs};
  }
};

// with vr = v_ij . r_ij and mu = mu_ij given (sph_mu_inv with p.hs and 1 / (r^2 + p.eta2))
CPS_HD CPS_INLINE float monaghan_pi_mu(const ArtificialViscosity& p, float vr, float mu, float c_bar, float rho_bar) {
  if (vr >= 0.0f) return 0.0f;  // receding (or sliding past): no viscosity
  return fdiv_fast(-p.alpha * c_bar * mu + p.beta * mu * mu, rho_bar);
}
template <int D>
CPS_HD CPS_INLINE float monaghan_pi(const ArtificialViscosity& p, const Vec<D>& d, const Vec<D>& dv, float r2,
                                    float c_bar, float rho_bar) {
  float vr = dot(dv, d);
  if (vr >= 0.0f) return 0.0f;
  return monaghan_pi_mu(p, vr, sph_mu_inv(p.hs, vr, sph_inv_den(r2, p.eta2)), c_bar, rho_bar);
}

template <int D>
CPS_HD CPS_INLINE Vec<D> artificial_viscosity_acc_mu(const ArtificialViscosity& p, float vr, float mu, float c_i,
                                                     float c_j, float rho_i, float rho_j, float m_j,
                                                     const Vec<D>& gradW) {
  float pi = monaghan_pi_mu(p, vr, mu, 0.5f * (c_i + c_j), 0.5f * (rho_i + rho_j));
  return gradW * (-m_j * pi);
}
template <int D>
CPS_HD CPS_INLINE Vec<D> artificial_viscosity_acc(const ArtificialViscosity& p, const Vec<D>& d, const Vec<D>& dv,
                                                  float r2, float c_i, float c_j, float rho_i, float rho_j,
                                                  float m_j, const Vec<D>& gradW) {
  float pi = monaghan_pi(p, d, dv, r2, 0.5f * (c_i + c_j), 0.5f * (rho_i + rho_j));
  return gradW * (-m_j * pi);
}

// ---- laminar viscosity (Morris, Fox & Zhu 1997, in the form of Lo & Shao 2002 that
// DualSPHysics calls "laminar": Dominguez et al. 2022, Comput. Part. Mech.) ----
//   a_i += m_j 4 nu0 (r_ij . grad_i W_ij) / ((rho_i + rho_j)(r_ij^2 + eta^2)) v_ij
// nu0: kinematic viscosity (m^2/s); eta^2 = 0.01 hs^2. Morris's (mu_i + mu_j) / (rho_i rho_j)
// becomes 4 nu0 / (rho_i + rho_j) for a uniform nu0 (equal at rho_i = rho_j).
// r_ij . grad W <= 0, so i is pulled towards j's velocity (dissipative).
struct LaminarViscosity {
  float nu0, eta2;
  CPS_HD static LaminarViscosity make(float nu0, float hs) { return LaminarViscosity{nu0, 0.01f * hs * hs}; }
};

// with den = r^2 + p.eta2 given
template <int D>
CPS_HD CPS_INLINE Vec<D> laminar_viscosity_acc_den(const LaminarViscosity& p, const Vec<D>& d, const Vec<D>& dv,
                                                   float den, float rho_i, float rho_j, float m_j,
                                                   const Vec<D>& gradW) {
  float s = fdiv_fast(m_j * 4.0f * p.nu0 * dot(d, gradW), (rho_i + rho_j) * den);
  return dv * s;
}
template <int D>
CPS_HD CPS_INLINE Vec<D> laminar_viscosity_acc(const LaminarViscosity& p, const Vec<D>& d, const Vec<D>& dv,
                                               float r2, float rho_i, float rho_j, float m_j, const Vec<D>& gradW) {
  return laminar_viscosity_acc_den<D>(p, d, dv, r2 + p.eta2, rho_i, rho_j, m_j, gradW);
}

// ---- density diffusion (delta-SPH) ----
//   drho_i/dt += 2 delta hs c0 ((rho_j - rho_i) - rho^H_ji) (r_ji . grad_i W_ij) / (r_ij^2 + eta^2) V_j
//   V_j = m_j / rho_j, r_ji = -d, eta^2 = 0.01 hs^2.
// Molteni & Colagrossi 2009 (with r_ij^2 regularised by eta^2 as DualSPHysics does):
//   rho^H_ji = 0.
// Fourtakas et al. 2019 (Comput. Fluids 190; DualSPHysics's "DDT2"): rho^H_ji is the
// hydrostatic density difference of the pair, from the Tait equation with B = c0^2 rho0 / gamma,
//   rho^H_ji = rho0 ((1 + kz z_ij)^(1/gamma) - 1),  kz = rho0 g / B = gamma g / c0^2,
// with z_ij = z_i - z_j (z the last axis, gravity g > 0 along -z): positive when j is below i.
// That published form is not odd in z_ij, so the (i, j) and (j, i) terms would not cancel
// (mass would drift at O((kz z)^2)); here rho^H_ji is its odd part,
//   rho^H_ji = rho0 / 2 ((1 + kz z_ij)^(1/gamma) - (1 - kz z_ij)^(1/gamma)),
// which agrees with the published form to first order in kz z (and with it, the exact Tait
// hydrostatic difference is cancelled to O((kz z)^2); kz z ~ 1e-3 at the dam break's spacing).
// fourtakas_rho_h_published() gives the published form for comparison.
enum class DensityDiffusionKind : int { None = 0, Molteni = 1, Fourtakas = 2 };

// The odd part is a pair's cost that the other terms do not have: two powers (four MUFU
// operations on a GPU, whose special-function units are an eighth of its FMA lanes). For
// |kz z| <= kFourtakasSeriesMax it is summed from its series instead,
//   rho0 / 2 ((1 + x)^a - (1 - x)^a) = rho0 (C(a,1) x + C(a,3) x^3 + C(a,5) x^5 + C(a,7) x^7) + ...,
// x = kz z, a = 1 / gamma, C the binomial coefficients (even powers cancel). For gamma >= 1 the
// next term is below |C(a,9) / C(a,1)| x^8 <= 0.1 x^8 of the sum, < 1e-8 at x = 0.1 (float32
// rounding is 6e-8); a pair's |kz z| is ~1e-3 (2 h g gamma / c0^2). Past 0.1: the powers.
constexpr float kFourtakasSeriesMax = 0.1f;

struct DensityDiffusion {
  DensityDiffusionKind kind;
  float coeff;      // 2 delta hs c0
  float eta2;       // 0.01 hs^2
  float rho0;       // rest density (Fourtakas)
  float gamma_inv;  // 1 / gamma (Fourtakas)
  float kz;         // rho0 g / B = gamma g / c0^2 (Fourtakas)
  float c1 = 0.0f, c3 = 0.0f, c5 = 0.0f, c7 = 0.0f;  // rho0 C(1/gamma, k): the odd part's series (Fourtakas)

  CPS_HD static DensityDiffusion none() { return DensityDiffusion{DensityDiffusionKind::None, 0.0f, 0.0f, 0.0f, 1.0f, 0.0f}; }
  CPS_HD static DensityDiffusion molteni(float delta, float hs, float c0) {
    return DensityDiffusion{DensityDiffusionKind::Molteni, 2.0f * delta * hs * c0, 0.01f * hs * hs, 0.0f, 1.0f, 0.0f};
  }
  CPS_HD static DensityDiffusion fourtakas(float delta, float hs, float c0, float rho0, float gamma, float g) {
    // C(a, k) = C(a, k - 2) (a - k + 2)(a - k + 1) / (k (k - 1)), in double
    const double a = 1.0 / double(gamma);
    const double b1 = a, b3 = b1 * (a - 1.0) * (a - 2.0) / 6.0, b5 = b3 * (a - 3.0) * (a - 4.0) / 20.0,
                 b7 = b5 * (a - 5.0) * (a - 6.0) / 42.0;
    return DensityDiffusion{DensityDiffusionKind::Fourtakas, 2.0f * delta * hs * c0, 0.01f * hs * hs, rho0,
                            1.0f / gamma, gamma * g / (c0 * c0), float(rho0 * b1), float(rho0 * b3),
                            float(rho0 * b5), float(rho0 * b7)};
  }
};

// the published hydrostatic difference rho^H_ji = rho0 ((1 + kz z_ij)^(1/gamma) - 1)
CPS_HD CPS_INLINE float fourtakas_rho_h_published(const DensityDiffusion& p, float z_ij) {
  return p.rho0 * (fpow(fmax2(1.0f + p.kz * z_ij, 0.0f), p.gamma_inv) - 1.0f);
}
// its odd part, the one used: rho0 / 2 ((1 + kz z)^(1/gamma) - (1 - kz z)^(1/gamma)) (the series
// above for |kz z| <= kFourtakasSeriesMax)
CPS_HD CPS_INLINE float fourtakas_rho_h(const DensityDiffusion& p, float z_ij) {
  const float x = p.kz * z_ij;
  if ((x < 0.0f ? -x : x) <= kFourtakasSeriesMax) {
    const float x2 = x * x;
    return x * (p.c1 + x2 * (p.c3 + x2 * (p.c5 + x2 * p.c7)));
  }
  float up = fpow_fast(fmax2(1.0f + x, 0.0f), p.gamma_inv);
  float dn = fpow_fast(fmax2(1.0f - x, 0.0f), p.gamma_inv);
  return 0.5f * p.rho0 * (up - dn);
}

// with inv_den = 1 / (r^2 + p.eta2) and V_j = m_j / rho_j given (what a pair loop has at hand),
// the kind K fixed at compile time (p.kind is not read) ...
template <int D, DensityDiffusionKind K>
CPS_HD CPS_INLINE float density_diffusion_rate_k(const DensityDiffusion& p, const Vec<D>& d, float inv_den,
                                                 float rho_i, float rho_j, float vol_j, const Vec<D>& gradW) {
  if constexpr (K == DensityDiffusionKind::None) {
    return 0.0f;
  } else {
    float drho = rho_j - rho_i;
    if constexpr (K == DensityDiffusionKind::Fourtakas) drho -= fourtakas_rho_h(p, d[D - 1]);
    // r_ji . grad_i W_ij = -d . gradW >= 0
    return p.coeff * drho * (-dot(d, gradW)) * inv_den * vol_j;
  }
}
// ... or p.kind's
template <int D>
CPS_HD CPS_INLINE float density_diffusion_rate_v(const DensityDiffusion& p, const Vec<D>& d, float inv_den,
                                                 float rho_i, float rho_j, float vol_j, const Vec<D>& gradW) {
  switch (p.kind) {
    case DensityDiffusionKind::None: return 0.0f;
    case DensityDiffusionKind::Fourtakas:
      return density_diffusion_rate_k<D, DensityDiffusionKind::Fourtakas>(p, d, inv_den, rho_i, rho_j, vol_j, gradW);
    default:
      return density_diffusion_rate_k<D, DensityDiffusionKind::Molteni>(p, d, inv_den, rho_i, rho_j, vol_j, gradW);
  }
}

template <int D>
CPS_HD CPS_INLINE float density_diffusion_rate(const DensityDiffusion& p, const Vec<D>& d, float r2, float rho_i,
                                               float rho_j, float m_j, const Vec<D>& gradW) {
  if (p.kind == DensityDiffusionKind::None) return 0.0f;
  return density_diffusion_rate_v<D>(p, d, sph_inv_den(r2, p.eta2), rho_i, rho_j, m_j / rho_j, gradW);
}

// ---- the transport-velocity formulation (Adami, Hu & Adams 2013, J. Comput. Phys. 241) ----
// The particles move with a transport velocity v~ = v + dv~ that differs from the momentum
// velocity v by the push of a constant background pressure p_b, which drives them towards a
// uniform spacing (no clumping, no gaps where the flow stretches the lattice) without acting
// on the momentum:
//   a~_i = -(p_b / m_i) sum_j (V_i^2 + V_j^2) grad_i W_ij             (the background push)
// integrated over a step into the advection (v~ - v = dt / 2 a~ of the kick-drift scheme), and
// the momentum equation gains the divergence of the extra stress A = rho v (v~ - v)^T that
// the difference carries,
//   a_i += (1 / m_i) sum_j (V_i^2 + V_j^2) 1/2 (A_i + A_j) . grad_i W_ij,
//   (A . g)_k = rho v_k ((v~ - v) . g)
// (the paper's eqs. 8 and 13-15), V = m / rho. Both are m_i a_ij = -m_j a_ji (their factors are
// symmetric in (i, j), grad W antisymmetric): momentum and the sum of the pushes are conserved.
// With m_i the particle's mass; for a uniform lattice sum_j grad W = 0 and the push vanishes.
template <int D>
CPS_HD CPS_INLINE Vec<D> tvf_background_acc(float p_b, float vol_i, float vol_j, float m_i, const Vec<D>& gradW) {
  return gradW * (-fdiv_fast(p_b * (vol_i * vol_i + vol_j * vol_j), m_i));
}
// dvt_i = v~_i - v_i (the last step's push), v_i the momentum velocity
template <int D>
CPS_HD CPS_INLINE Vec<D> tvf_stress_acc(float rho_i, const Vec<D>& v_i, const Vec<D>& dvt_i, float rho_j,
                                        const Vec<D>& v_j, const Vec<D>& dvt_j, float vol_i, float vol_j, float m_i,
                                        const Vec<D>& gradW) {
  const float s = 0.5f * fdiv_fast(vol_i * vol_i + vol_j * vol_j, m_i);
  return (v_i * (rho_i * dot(dvt_i, gradW)) + v_j * (rho_j * dot(dvt_j, gradW))) * s;
}

}  // namespace cps
