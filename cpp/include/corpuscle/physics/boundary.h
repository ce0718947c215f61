// Spherical (3-D) or circular (2-D) container centred at the origin: mirrored ghost
// particles for the SPH sums near the wall, and wall reflection with restitution and friction.
#pragma once
#include "corpuscle/core/vec.h"

namespace cps {

struct SphereWall {
  float radius;
  float restitution;  // fraction of normal velocity kept (reversed) on contact
  float friction;     // fraction of tangential velocity removed on contact
};

// fluid within the support radius of the wall gets a ghost
template <int D>
CPS_HD CPS_INLINE bool needs_ghost(const SphereWall& w, const Vec<D>& x, float h) {
  float r2 = norm2(x);
  float inner = w.radius - h;
  return r2 > (inner > 0.0f ? inner * inner : 0.0f) && r2 > 1e-12f;
}

// mirror image of x across the wall: radius r -> 2R - r along the same ray
template <int D>
CPS_HD CPS_INLINE Vec<D> mirror_position(const SphereWall& w, const Vec<D>& x) {
  float r = norm(x);
  return x * ((2.0f * w.radius - r) / r);
}

// mirrored velocity: normal component reversed, tangential kept (the wall is at rest)
template <int D>
CPS_HD CPS_INLINE Vec<D> mirror_velocity(const Vec<D>& x, const Vec<D>& v) {
  float r = norm(x);
  Vec<D> n = x * (1.0f / r);
  return v - n * (2.0f * dot(v, n));
}

// keep x inside the wall; an outward-moving particle is reflected with restitution and friction
template <int D>
CPS_HD CPS_INLINE void reflect_at_wall(const SphereWall& w, Vec<D>& x, Vec<D>& v) {
  float r = norm(x);
  float lim = w.radius * (1.0f - 1e-5f);
  if (!(r > lim)) return;
  Vec<D> n = x * (1.0f / r);
  x = n * lim;
  float vn = dot(v, n);
  if (vn > 0.0f) {
    Vec<D> vt = v - n * vn;
    v = vt * (1.0f - w.friction) - n * (w.restitution * vn);
  }
}

}  // namespace cps
