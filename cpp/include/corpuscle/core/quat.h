// Unit quaternions (w, x, y, z) for rigid-body orientation.
#pragma once
#include "corpuscle/core/vec.h"

namespace cps {

struct Quat {
  float w, x, y, z;
  CPS_HD static Quat identity() { return Quat{1.0f, 0.0f, 0.0f, 0.0f}; }
};

// Hamilton product a*b
CPS_HD CPS_INLINE Quat qmul(const Quat& a, const Quat& b) {
  return Quat{a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z, a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y,
              a.w * b.y - a.x * b.z + a.y * b.w + a.z * b.x, a.w * b.z + a.x * b.y - a.y * b.x + a.z * b.w};
}

CPS_HD CPS_INLINE Quat qnormalize(Quat q) {
  float n = fsqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
  float s = n > 0.0f ? 1.0f / n : 0.0f;
  return Quat{q.w * s, q.x * s, q.y * s, q.z * s};
}

// rotate v by q (body -> world)
CPS_HD CPS_INLINE Vec3 qrotate(const Quat& q, const Vec3& v) {
  Vec3 u{{q.x, q.y, q.z}};
  Vec3 t = 2.0f * cross(u, v);
  return v + q.w * t + cross(u, t);
}

// rotate v by the inverse of q (world -> body)
CPS_HD CPS_INLINE Vec3 qrotate_inv(const Quat& q, const Vec3& v) {
  return qrotate(Quat{q.w, -q.x, -q.y, -q.z}, v);
}

// first-order update q <- q + dt/2 * q * (0, w_body), renormalised
CPS_HD CPS_INLINE Quat qintegrate_body(const Quat& q, const Vec3& w_body, float dt) {
  Quat dq = qmul(q, Quat{0.0f, w_body[0], w_body[1], w_body[2]});
  float h = 0.5f * dt;
  return qnormalize(Quat{q.w + h * dq.w, q.x + h * dq.x, q.y + h * dq.y, q.z + h * dq.z});
}

}  // namespace cps
