// Selectable SPH smoothing kernels, generic in the dimension D (2 or 3), each with W(r), its
// gradient with respect to x_i for d = x_i - x_j, and the normalisation of its dimension.
//
// Convention (one for every kernel here): h is the SUPPORT
// RADIUS, W(r) = 0 for r >= h, and q = r / h. Papers written with a smoothing length s and
// support 2s (Monaghan 1992's cubic spline; DualSPHysics's "h" for both cubic and Wendland)
// map onto this with h = 2 s; Dehnen & Aly (2012, Table 1) already use the support radius
// (their H), so their constants appear here unchanged.
//
//   Poly6       W = c (h^2 - r^2)^3                 c3 = 315 / (64 pi h^9), c2 = 4 / (pi h^8)
//               (Mueller, Charypar & Gross 2003, eq. 20; the 2-D constant by normalising over
//               the disc: int_0^h (h^2 - r^2)^3 2 pi r dr = pi h^8 / 4. The seed's original
//               had a typo in this constant; this file uses the correct one.)
//   Spiky       W = c (h - r)^3                     c3 = 15 / (pi h^6),      c2 = 10 / (pi h^5)
//               (Mueller 2003, eq. 21; 2-D: int_0^h (h - r)^3 2 pi r dr = pi h^5 / 10)
//   Viscosity   3-D: W = c (-r^3 / 2h^3 + r^2 / h^2 + h / 2r - 1) = c (1 - q)^3 (1 + q) / 2q, c = 15 / (2 pi h^3),
//               lap W = 45 / (pi h^6) (h - r) (Mueller 2003, eq. 22).
//               2-D: the radial kernel whose 2-D Laplacian is k (h - r) with W(h) = W'(h) = 0,
//               normalised over the disc: W = k (h r^2 / 4 - r^3 / 9 - 5 h^3 / 36 - h^3 / 6 ln(r/h)),
//               k = 40 / (pi h^5), lap W = k (h - r).
//               Both are singular (integrably) at r = 0; W(0) returns 0 there by convention.
//   CubicSpline W = sigma / h^D f(q), f = 1 - 6 q^2 + 6 q^3 (q < 1/2), 2 (1 - q)^3 (1/2 <= q < 1),
//               sigma3 = 8 / pi, sigma2 = 40 / (7 pi)
//               (Monaghan & Lattanzio 1985; Monaghan 1992, the M4 spline with s = h / 2: 1/pi and
//               10/(7 pi) times 2^D; = Dehnen & Aly 2012, Table 1, 16/pi and 80/(7 pi) times their
//               (1 - q)^3 - 4 (1/2 - q)^3 = f / 2)
//   WendlandC2  W = C / h^D (1 - q)^4 (1 + 4 q),   C3 = 21 / (2 pi), C2 = 7 / pi
//               (Wendland 1995, psi_{3,1}; Dehnen & Aly 2012, Table 1: the same polynomial is
//               C2 for D = 2 and 3)
//
// Gradients are written without dividing by r where the kernel allows it (Poly6, CubicSpline
// for q < 1/2, WendlandC2), so grad W(0) = 0 exactly and nothing blows up near r = 0; Spiky and
// Viscosity return zero at r = 0 (the self pair).
//
// The gradients' divisions are fdiv_fast (core/hd.h): exact on the host, the hardware's
// approximate division on the device (the pair loop's cost).
//
// Compile-time selection: Kernel<D, SphKernelKind::WendlandC2>::make(h). Run-time selection
// (a kind code in a POD, usable in device code): SphKernel<D>::make(kind, h), whose switch calls
// the same static functions. Each typed kernel stores only {h, h2, c, gc}, with c the
// normalisation of W and gc that of grad W.
#pragma once
#include "corpuscle/core/vec.h"

namespace cps {

enum class SphKernelKind : int { Poly6 = 0, Spiky = 1, Viscosity = 2, CubicSpline = 3, WendlandC2 = 4 };
constexpr int kSphKernelKinds = 5;


// the constants every kernel carries: support h, h^2, W's normalisation c, grad W's gc
struct SphKernelConsts {
  float h, h2, c, gc;
  float inv_h;  // 1 / h (a product where the gradients would divide)
};

template <int D, SphKernelKind K>
struct KernelFormula;

// ---- Poly6 ----
template <int D>
struct KernelFormula<D, SphKernelKind::Poly6> {
  CPS_HD static SphKernelConsts make(float h) {
    SphKernelConsts k;
    k.h = h;
    k.inv_h = 1.0f / h;
    k.h2 = h * h;
    float h4 = k.h2 * k.h2;
    if constexpr (D == 3) k.c = 315.0f / (64.0f * kPi * h4 * h4 * h);
    else k.c = 4.0f / (kPi * h4 * h4);
    k.gc = -6.0f * k.c;
    return k;
  }
  CPS_HD static float w_r2(const SphKernelConsts& k, float r2) {
    if (r2 >= k.h2) return 0.0f;
    float t = k.h2 - r2;
    return k.c * t * t * t;
  }
  CPS_HD static float w(const SphKernelConsts& k, float r) { return w_r2(k, r * r); }
  // grad W = -6 c (h^2 - r^2)^2 d
  CPS_HD static Vec<D> grad(const SphKernelConsts& k, const Vec<D>& d, float r) {
    if (r >= k.h) return Vec<D>::zero();
    float t = k.h2 - r * r;
    return d * (k.gc * t * t);
  }
  // fraction of the kernel's mass beyond a plane at signed distance d from the particle
  // (d > 0: plane outside the particle), 3-D: Gamma(s) = 1/2 - 315/256 F(s), s = d/h, with
  // F(s) = s - 4 s^3/3 + 6 s^5/5 - 4 s^7/7 + s^9/9 the antiderivative of (1 - s^2)^4
  CPS_HD static float beyond_plane(const SphKernelConsts& k, float d) {
    static_assert(D == 3, "the half-space fraction is derived for 3-D Poly6");
    float s = fclamp(d / k.h, -1.0f, 1.0f);
    float s2 = s * s;
    float F = s * (1.0f + s2 * (-4.0f / 3.0f + s2 * (6.0f / 5.0f + s2 * (-4.0f / 7.0f + s2 / 9.0f))));
    return 0.5f - (315.0f / 256.0f) * F;
  }
  // fraction of the kernel's mass inside an axis-aligned box [-half, half] for a particle at p
  // (box frame): the product over axes of the kernel's 1-D marginal mass in the box's slab.
  // Exact for a single face (a plane) and smooth across edges and corners; for a box smaller
  // than the kernel it shrinks with the box instead of saturating at the plane's 1/2.
  CPS_HD static float box_fraction(const SphKernelConsts& k, const Vec<D>& half, const Vec<D>& p) {
    float f = 1.0f;
    for (int a = 0; a < D; ++a) {
      // 1 minus the marginal mass beyond the upper face and beyond the lower face
      f *= 1.0f - beyond_plane(k, half[a] - p[a]) - beyond_plane(k, half[a] + p[a]);
    }
    return f;
  }
};

// ---- Spiky ----
template <int D>
struct KernelFormula<D, SphKernelKind::Spiky> {
  CPS_HD static SphKernelConsts make(float h) {
    SphKernelConsts k;
    k.h = h;
    k.inv_h = 1.0f / h;
    k.h2 = h * h;
    float h4 = k.h2 * k.h2;
    if constexpr (D == 3) {
      k.c = 15.0f / (kPi * h4 * k.h2);
      k.gc = 45.0f / (kPi * h4 * k.h2);  // 3 c
    } else {
      k.c = 10.0f / (kPi * h4 * h);
      k.gc = 30.0f / (kPi * h4 * h);  // 3 c
    }
    return k;
  }
  CPS_HD static float w(const SphKernelConsts& k, float r) {
    if (r >= k.h) return 0.0f;
    float t = k.h - r;
    return k.c * t * t * t;
  }
  // grad W = -3 c (h - r)^2 d / r
  CPS_HD static Vec<D> grad(const SphKernelConsts& k, const Vec<D>& d, float r) {
    if (r >= k.h || r <= 0.0f) return Vec<D>::zero();
    float t = k.h - r;
    return d * fdiv_fast(-k.gc * t * t, r);
  }
  // the same with 1 / r given (a product, no division: the pair loop has 1 / r from one
  // reciprocal square root)
  CPS_HD static Vec<D> grad_rinv(const SphKernelConsts& k, const Vec<D>& d, float r, float rinv) {
    if (r >= k.h || r <= 0.0f) return Vec<D>::zero();
    float t = k.h - r;
    return d * (-k.gc * t * t * rinv);
  }
};

// ---- Mueller's viscosity kernel (3-D) and its 2-D analogue (see the header comment) ----
template <int D>
struct KernelFormula<D, SphKernelKind::Viscosity> {
  CPS_HD static SphKernelConsts make(float h) {
    SphKernelConsts k;
    k.h = h;
    k.inv_h = 1.0f / h;
    k.h2 = h * h;
    float h4 = k.h2 * k.h2;
    if constexpr (D == 3) {
      k.c = 15.0f / (2.0f * kPi * k.h2 * h);
      k.gc = 45.0f / (kPi * h4 * k.h2);  // the Laplacian's constant
    } else {
      k.c = 40.0f / (kPi * h4 * h);  // k: W and lap W share it in 2-D
      k.gc = k.c;
    }
    return k;
  }
  // both written without the cancellation of their published sums near r = h
  CPS_HD static float w(const SphKernelConsts& k, float r) {
    if (r >= k.h || r <= 0.0f) return 0.0f;
    float q = r / k.h, e = 1.0f - q;
    if constexpr (D == 3) {
      // -q^3/2 + q^2 + 1/(2q) - 1 = (1 - q)^3 (1 + q) / (2 q)
      return k.c * e * e * e * (1.0f + q) / (2.0f * q);
    } else {
      // h^3 f(q), f = q^2/4 - q^3/9 - 5/36 - ln(q)/6 = (e^3 + sum_{n>=4} e^n / n) / 6, e = 1 - q:
      // the series for e < 0.4 (terms to n = 20: relative truncation < 1e-7), the sum beyond
      float h3 = k.h2 * k.h;
      if (e < 0.4f) {
        float s = 1.0f / 20.0f;
        for (int n = 19; n >= 4; --n) s = s * e + 1.0f / float(n);
        float e3 = e * e * e;
        return k.c * h3 * (e3 * (1.0f + e * s)) * (1.0f / 6.0f);
      }
      return k.c * h3 * (q * q * (0.25f - q * (1.0f / 9.0f)) - 5.0f / 36.0f - flog(q) * (1.0f / 6.0f));
    }
  }
  // 3-D: grad W = -c (h - r)^2 (h^2 + 2 h r + 3 r^2) / (2 h^3 r^3) d
  // 2-D: grad W = -k (h - r)^2 (h + 2 r) / (6 r^2) d
  CPS_HD static Vec<D> grad(const SphKernelConsts& k, const Vec<D>& d, float r) {
    if (r >= k.h || r <= 0.0f) return Vec<D>::zero();
    float h = k.h, t = h - r;
    if constexpr (D == 3) {
      return d * fdiv_fast(-k.c * t * t * (k.h2 + 2.0f * h * r + 3.0f * r * r), 2.0f * k.h2 * h * r * r * r);
    } else {
      return d * fdiv_fast(-k.c * t * t * (h + 2.0f * r), 6.0f * r * r);
    }
  }
  // lap W = gc (h - r)
  CPS_HD static float lap(const SphKernelConsts& k, float r) { return r >= k.h ? 0.0f : k.gc * (k.h - r); }
};

// ---- cubic B-spline (M4), support h ----
template <int D>
struct KernelFormula<D, SphKernelKind::CubicSpline> {
  CPS_HD static SphKernelConsts make(float h) {
    SphKernelConsts k;
    k.h = h;
    k.inv_h = 1.0f / h;
    k.h2 = h * h;
    float hd = D == 3 ? k.h2 * h : k.h2;
    k.c = (D == 3 ? 8.0f / kPi : 40.0f / (7.0f * kPi)) / hd;
    k.gc = k.c / k.h2;
    return k;
  }
  CPS_HD static float w(const SphKernelConsts& k, float r) {
    float q = r / k.h;
    if (q >= 1.0f) return 0.0f;
    if (q < 0.5f) return k.c * (1.0f + q * q * (6.0f * q - 6.0f));
    float t = 1.0f - q;
    return k.c * 2.0f * t * t * t;
  }
  // grad W = c / h^2 (f'(q) / q) d: f'/q = 18 q - 12 (q < 1/2), -6 (1 - q)^2 / q (q >= 1/2)
  CPS_HD static Vec<D> grad(const SphKernelConsts& k, const Vec<D>& d, float r) {
    float q = r * k.inv_h;
    if (q >= 1.0f) return Vec<D>::zero();
    if (q < 0.5f) return d * (k.gc * (18.0f * q - 12.0f));
    float t = 1.0f - q;
    return d * fdiv_fast(-6.0f * k.gc * t * t, q);
  }
};

// ---- Wendland C2, support h ----
template <int D>
struct KernelFormula<D, SphKernelKind::WendlandC2> {
  CPS_HD static SphKernelConsts make(float h) {
    SphKernelConsts k;
    k.h = h;
    k.inv_h = 1.0f / h;
    k.h2 = h * h;
    float hd = D == 3 ? k.h2 * h : k.h2;
    k.c = (D == 3 ? 21.0f / (2.0f * kPi) : 7.0f / kPi) / hd;
    k.gc = -20.0f * k.c / k.h2;
    return k;
  }
  CPS_HD static float w(const SphKernelConsts& k, float r) {
    float q = r / k.h;
    if (q >= 1.0f) return 0.0f;
    float t = 1.0f - q, t2 = t * t;
    return k.c * t2 * t2 * (1.0f + 4.0f * q);
  }
  // dW/dr = -20 c q (1 - q)^3 / h, so grad W = -20 c / h^2 (1 - q)^3 d
  CPS_HD static Vec<D> grad(const SphKernelConsts& k, const Vec<D>& d, float r) {
    float q = r * k.inv_h;
    if (q >= 1.0f) return Vec<D>::zero();
    float t = 1.0f - q;
    return d * (k.gc * t * t * t);
  }
};

// a kernel chosen at compile time
template <int D, SphKernelKind K>
struct Kernel {
  using F = KernelFormula<D, K>;
  static constexpr SphKernelKind kind = K;
  SphKernelConsts k;
  CPS_HD static Kernel make(float h) { return Kernel{F::make(h)}; }
  CPS_HD float support() const { return k.h; }
  CPS_HD float w(float r) const { return F::w(k, r); }
  // W from the squared distance (Poly6 needs no square root)
  CPS_HD float w_r2(float r2) const {
    if constexpr (K == SphKernelKind::Poly6) return F::w_r2(k, r2);
    else return F::w(k, fsqrt(r2));
  }
  CPS_HD Vec<D> grad(const Vec<D>& d, float r) const { return F::grad(k, d, r); }
  // the forms one kernel has: Spiky's gradient with 1 / r given, the viscosity kernel's
  // Laplacian, Poly6's mass inside a box
  CPS_HD Vec<D> grad_rinv(const Vec<D>& d, float r, float rinv) const { return F::grad_rinv(k, d, r, rinv); }
  CPS_HD float lap(float r) const { return F::lap(k, r); }
  CPS_HD float box_fraction(const Vec<D>& half, const Vec<D>& p) const { return F::box_fraction(k, half, p); }
};

// Mueller, Charypar & Gross (2003)'s three kernels of one support h: Poly6 for the density
// (and XSPH), Spiky's gradient for the pressure, the viscosity kernel's Laplacian for the
// viscosity (the Magic 8-Ball's set)
template <int D>
struct MuellerKernels {
  Kernel<D, SphKernelKind::Poly6> poly6;
  Kernel<D, SphKernelKind::Spiky> spiky;
  Kernel<D, SphKernelKind::Viscosity> visc;
  CPS_HD static MuellerKernels make(float h) {
    MuellerKernels s;
    s.poly6 = Kernel<D, SphKernelKind::Poly6>::make(h);
    s.spiky = Kernel<D, SphKernelKind::Spiky>::make(h);
    s.visc = Kernel<D, SphKernelKind::Viscosity>::make(h);
    return s;
  }
  CPS_HD float support() const { return poly6.k.h; }
  CPS_HD float support2() const { return poly6.k.h2; }
};

// a kernel chosen at run time: a kind code and the constants (a POD for device code)
template <int D>
struct SphKernel {
  SphKernelKind kind;
  SphKernelConsts k;

  CPS_HD static SphKernel make(SphKernelKind kind, float h) {
    SphKernel s;
    s.kind = kind;
    switch (kind) {
      case SphKernelKind::Poly6: s.k = KernelFormula<D, SphKernelKind::Poly6>::make(h); break;
      case SphKernelKind::Spiky: s.k = KernelFormula<D, SphKernelKind::Spiky>::make(h); break;
      case SphKernelKind::Viscosity: s.k = KernelFormula<D, SphKernelKind::Viscosity>::make(h); break;
      case SphKernelKind::CubicSpline: s.k = KernelFormula<D, SphKernelKind::CubicSpline>::make(h); break;
      default: s.k = KernelFormula<D, SphKernelKind::WendlandC2>::make(h); break;
    }
    return s;
  }
  CPS_HD float support() const { return k.h; }
  CPS_HD float w(float r) const {
    switch (kind) {
      case SphKernelKind::Poly6: return KernelFormula<D, SphKernelKind::Poly6>::w(k, r);
      case SphKernelKind::Spiky: return KernelFormula<D, SphKernelKind::Spiky>::w(k, r);
      case SphKernelKind::Viscosity: return KernelFormula<D, SphKernelKind::Viscosity>::w(k, r);
      case SphKernelKind::CubicSpline: return KernelFormula<D, SphKernelKind::CubicSpline>::w(k, r);
      default: return KernelFormula<D, SphKernelKind::WendlandC2>::w(k, r);
    }
  }
  // W from the squared distance (Poly6 needs no square root)
  CPS_HD float w_r2(float r2) const {
    if (kind == SphKernelKind::Poly6) return KernelFormula<D, SphKernelKind::Poly6>::w_r2(k, r2);
    return w(fsqrt(r2));
  }
  CPS_HD Vec<D> grad(const Vec<D>& d, float r) const {
    switch (kind) {
      case SphKernelKind::Poly6: return KernelFormula<D, SphKernelKind::Poly6>::grad(k, d, r);
      case SphKernelKind::Spiky: return KernelFormula<D, SphKernelKind::Spiky>::grad(k, d, r);
      case SphKernelKind::Viscosity: return KernelFormula<D, SphKernelKind::Viscosity>::grad(k, d, r);
      case SphKernelKind::CubicSpline: return KernelFormula<D, SphKernelKind::CubicSpline>::grad(k, d, r);
      default: return KernelFormula<D, SphKernelKind::WendlandC2>::grad(k, d, r);
    }
  }
};

// the kernels one SPH model uses: one for density (and interpolation), one for gradients.
// The seed's set is {Poly6, Spiky} (with the viscosity kernel's Laplacian: MuellerKernels<D>);
// the cubic spline and Wendland models use one kernel for both.
template <int D>
struct SphKernelSet {
  SphKernel<D> density, gradient;
  CPS_HD static SphKernelSet make(SphKernelKind kind, float h) {
    SphKernelSet s;
    if (kind == SphKernelKind::Poly6 || kind == SphKernelKind::Spiky) {
      s.density = SphKernel<D>::make(SphKernelKind::Poly6, h);
      s.gradient = SphKernel<D>::make(SphKernelKind::Spiky, h);
    } else {
      s.density = SphKernel<D>::make(kind, h);
      s.gradient = s.density;
    }
    return s;
  }
};

}  // namespace cps
