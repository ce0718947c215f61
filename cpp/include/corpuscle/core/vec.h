// Small fixed-size float vectors; the dimension D is a template parameter (2 or 3).
#pragma once
#include "corpuscle/core/hd.h"

namespace cps {

template <int D>
struct Vec {
  float v[D];
  CPS_HD float& operator[](int i) { return v[i]; }
  CPS_HD const float& operator[](int i) const { return v[i]; }
  CPS_HD static Vec zero() {
    Vec r;
    for (int k = 0; k < D; ++k) r.v[k] = 0.0f;
    return r;
  }
};

using Vec2 = Vec<2>;
using Vec3 = Vec<3>;

// a Vec<D> padded to 8 (2-D) or 16 (3-D: the fourth float unused) bytes and aligned to that, so
// a device thread loads it with one vector instruction (a gather of neighbours' positions)
template <int D>
struct alignas(D == 3 ? 16 : 8) VecA {
  float v[D == 3 ? 4 : 2];
  CPS_HD static VecA of(const Vec<D>& x) {
    VecA a;
    for (int k = 0; k < D; ++k) a.v[k] = x.v[k];
    if constexpr (D == 3) a.v[3] = 0.0f;
    return a;
  }
  CPS_HD Vec<D> vec() const {
    Vec<D> x;
    for (int k = 0; k < D; ++k) x.v[k] = v[k];
    return x;
  }
  // *p as a Vec<D>, read with one vector load on the device (a plain read of three floats
  // would be split into three)
  CPS_HD static Vec<D> load(const VecA* p) {
#ifdef __CUDA_ARCH__
    if constexpr (D == 3) {
      const float4 q = *reinterpret_cast<const float4*>(p);
      return Vec<D>{{q.x, q.y, q.z}};
    } else {
      const float2 q = *reinterpret_cast<const float2*>(p);
      return Vec<D>{{q.x, q.y}};
    }
#else
    return p->vec();
#endif
  }
};

// element-wise arithmetic
template <int D> CPS_HD CPS_INLINE Vec<D> operator+(Vec<D> a, const Vec<D>& b) {
  for (int k = 0; k < D; ++k) a.v[k] += b.v[k];
  return a;
}
template <int D> CPS_HD CPS_INLINE Vec<D> operator-(Vec<D> a, const Vec<D>& b) {
  for (int k = 0; k < D; ++k) a.v[k] -= b.v[k];
  return a;
}
template <int D> CPS_HD CPS_INLINE Vec<D> operator-(Vec<D> a) {
  for (int k = 0; k < D; ++k) a.v[k] = -a.v[k];
  return a;
}
template <int D> CPS_HD CPS_INLINE Vec<D> operator*(Vec<D> a, float s) {
  for (int k = 0; k < D; ++k) a.v[k] *= s;
  return a;
}
template <int D> CPS_HD CPS_INLINE Vec<D> operator*(float s, Vec<D> a) { return a * s; }
template <int D> CPS_HD CPS_INLINE Vec<D>& operator+=(Vec<D>& a, const Vec<D>& b) {
  for (int k = 0; k < D; ++k) a.v[k] += b.v[k];
  return a;
}
template <int D> CPS_HD CPS_INLINE Vec<D>& operator-=(Vec<D>& a, const Vec<D>& b) {
  for (int k = 0; k < D; ++k) a.v[k] -= b.v[k];
  return a;
}
template <int D> CPS_HD CPS_INLINE float dot(const Vec<D>& a, const Vec<D>& b) {
  float s = 0.0f;
  for (int k = 0; k < D; ++k) s += a.v[k] * b.v[k];
  return s;
}
template <int D> CPS_HD CPS_INLINE float norm2(const Vec<D>& a) { return dot(a, a); }
template <int D> CPS_HD CPS_INLINE float norm(const Vec<D>& a) { return fsqrt(dot(a, a)); }

// the 3-D cross product
CPS_HD CPS_INLINE Vec3 cross(const Vec3& a, const Vec3& b) {
  return Vec3{{a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]}};
}

}  // namespace cps
