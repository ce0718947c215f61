// Soft-sphere (DEM) contacts: the seed's linear spring-dashpot normal law (seed 000,
// WingSimulator's SpringDamper: a Hooke spring along the contact normal proportional to the
// overlap plus a damper on the normal relative velocity), the per-particle "pressure" (the
// seed's sum of contact-force magnitudes), the conversions between the damping c and the
// coefficient of restitution e, the contact duration, and the particle-wall / particle-
// polygon contact with the same law.
//
// The linear spring-dashpot (Cundall & Strack 1979): for overlap delta = r_i + r_j - |x_j - x_i|
// > 0 and approach speed u = (v_i - v_j) . n, n = (x_j - x_i) / |x_j - x_i|, the normal force
// F = k delta + c u pushes i along -n and j along +n. The relative motion of a head-on pair
// is then a damped oscillator m_eff delta'' + c delta' + k delta = 0, m_eff = m1 m2 / (m1 + m2),
// with the closed forms (Schwager & Poeschel, Phys. Rev. E 75, 051304 (2007), eqs. 3-6;
// Antypov & Elliott, EPL 94, 50004 (2011); Poeschel & Schwager, "Computational Granular
// Dynamics" 2005, ch. 3.1):
//   omega0^2 = k / m_eff,   beta = c / (2 m_eff),   zeta = beta / omega0 = c / (2 sqrt(k m_eff))
//   t_c = pi / sqrt(omega0^2 - beta^2)                      (contact duration, zeta < 1)
//   e   = exp(-beta t_c) = exp(-pi zeta / sqrt(1 - zeta^2))
//   zeta = -ln e / sqrt(pi^2 + ln^2 e),   c = 2 zeta sqrt(k m_eff)   (the inverse)
// These hold for a contact that ends when the overlap returns to zero, the seed's (and our)
// criterion: the force is not clipped at zero, so near the end of a damped contact it is
// briefly attractive (Schwager & Poeschel 2007 discuss the alternative, contact ending when
// F = 0, which gives a different e). With zeta >= 1 (overdamped) the pair never separates
// with a positive speed: e = 0, t_c infinite.
//
// The law is dimension-generic (template <int D>); the polygon contact is 2-D (the 3-D wind
// tunnel's airfoil is the polygon extruded along z: its contact is the 2-D one in x-y).
#pragma once
#include <cmath>

#include "corpuscle/core/real.h"
#include "corpuscle/core/vec.h"
#include "corpuscle/physics/polygon.h"

namespace cps {

struct SpringDashpot {
  float k;  // spring stiffness (force per unit overlap)
  float c;  // damping (force per unit normal approach speed)
};


// reduced mass of a pair; a wall (or the airfoil) is infinitely heavy: pass m2 <= 0
CPS_HD CPS_INLINE float effective_mass(float m1, float m2) { return m2 > 0.0f ? m1 * m2 / (m1 + m2) : m1; }

// damping ratio zeta = c / (2 sqrt(k m_eff))
template <class T>
CPS_HD CPS_INLINE T damping_ratio(T k, T c, T m_eff) {
  return c / (T(2) * tsqrt(k * m_eff));
}
CPS_HD CPS_INLINE float damping_ratio(const SpringDashpot& law, float m_eff) {
  return damping_ratio(law.k, law.c, m_eff);
}

// coefficient of normal restitution e = exp(-pi zeta / sqrt(1 - zeta^2)) implied by k, c and
// the masses (0 when overdamped). T: float in the core, double for Python (core/real.h;
// corpuscle._core.dem_restitution_for_damping)
template <class T>
CPS_HD CPS_INLINE T restitution_from_damping(T k, T c, T m_eff) {
  T z = damping_ratio(k, c, m_eff);
  if (!(z < T(1))) return T(0);
  return texp(-pi_of<T>() * z / tsqrt(T(1) - z * z));
}
CPS_HD CPS_INLINE float restitution_from_damping(const SpringDashpot& law, float m_eff) {
  return restitution_from_damping(law.k, law.c, m_eff);
}

// the damping c that gives restitution e (0 < e <= 1) with stiffness k and these masses:
// zeta = -ln e / sqrt(pi^2 + ln^2 e), c = 2 zeta sqrt(k m_eff) (_core.dem_damping_for_restitution)
template <class T>
CPS_HD CPS_INLINE T damping_from_restitution(T k, T e, T m_eff) {
  T le = tlog(e);
  T z = -le / tsqrt(pi_of<T>() * pi_of<T>() + le * le);
  return T(2) * z * tsqrt(k * m_eff);
}

// contact duration t_c = pi / sqrt(k / m_eff - (c / (2 m_eff))^2); infinite when overdamped
CPS_HD CPS_INLINE float contact_time(const SpringDashpot& law, float m_eff) {
  float b = law.c / (2.0f * m_eff);
  float w2 = law.k / m_eff - b * b;
  return w2 > 0.0f ? kPi / fsqrt(w2) : 1e30f;
}

// the scalar normal force: spring on the overlap plus damper on the approach speed
CPS_HD CPS_INLINE float normal_force(const SpringDashpot& law, float overlap, float approach) {
  return law.k * overlap + law.c * approach;
}

// The force on particle i from particle j (j gets its negative: Newton's third law), from the
// displacement d = x_j - x_i (a periodic image's displacement, computed as (x_j - x_i) minus the
// image shift, so the pair's two displacements are exact negatives of each other).
// Returns false (force zero) when they do not overlap, or when the centres coincide to
// within 1e-6 of the contact distance, where the normal is undefined (the seed skipped
// |x_j - x_i|^2 < 1e-8, an absolute length; this one is relative to the radii).
// `magnitude` is |F|, the pair's contribution to each particle's "pressure".
template <int D>
CPS_HD CPS_INLINE bool pair_contact_force_d(const SpringDashpot& law, const Vec<D>& d, const Vec<D>& vi, float ri,
                                            const Vec<D>& vj, float rj, Vec<D>& f_on_i, float& magnitude) {
  float reach = ri + rj;
  float r2 = norm2(d);
  f_on_i = Vec<D>::zero();
  magnitude = 0.0f;
  if (!(r2 < reach * reach)) return false;
  float r = fsqrt(r2);
  if (!(r > 1e-6f * reach)) return false;
  Vec<D> n = d * (1.0f / r);
  float F = normal_force(law, reach - r, dot(vi - vj, n));
  f_on_i = n * (-F);
  magnitude = F < 0.0f ? -F : F;
  return true;
}
// the same from the two positions (d = x_j - x_i)
template <int D>
CPS_HD CPS_INLINE bool pair_contact_force(const SpringDashpot& law, const Vec<D>& xi, const Vec<D>& vi, float ri,
                                          const Vec<D>& xj, const Vec<D>& vj, float rj, Vec<D>& f_on_i,
                                          float& magnitude) {
  return pair_contact_force_d<D>(law, xj - xi, vi, ri, vj, rj, f_on_i, magnitude);
}

// A particle against a wall or body: signed distance `sd` of the particle's centre from the
// surface (negative inside the body), the surface's outward unit normal n there, the wall's
// velocity at the contact. Contact when sd < r; the force on the particle is F n (the body
// gets -F n), with the overlap r - sd, which keeps pushing a centre that got inside out
// through the nearer surface.
template <int D>
CPS_HD CPS_INLINE bool wall_contact_force(const SpringDashpot& law, float sd, const Vec<D>& n, const Vec<D>& v,
                                          float r, const Vec<D>& v_wall, Vec<D>& f_on_particle, float& magnitude) {
  f_on_particle = Vec<D>::zero();
  magnitude = 0.0f;
  if (!(sd < r)) return false;
  float F = normal_force(law, r - sd, -dot(v - v_wall, n));
  f_on_particle = n * F;
  magnitude = F < 0.0f ? -F : F;
  return true;
}

// A particle (centre x, velocity v, radius r) against a resting polygon (the airfoil), with
// the polygon's law (the seed's wing k). `hit` returns the closest feature for diagnostics.
// The bounding-box early-out: callers with many particles should first test
// box_distance2(polygon_bbox(P), x) < r^2 (the bbox computed once).
template <class Poly>
CPS_HD CPS_INLINE bool polygon_contact_force(const SpringDashpot& law, const Poly& P, const Vec2& x, const Vec2& v,
                                             float r, Vec2& f_on_particle, float& magnitude, PolygonHit& hit) {
  hit = polygon_sdf(P, x);
  return wall_contact_force<2>(law, hit.distance, hit.normal, v, r, Vec2::zero(), f_on_particle, magnitude);
}

}  // namespace cps
