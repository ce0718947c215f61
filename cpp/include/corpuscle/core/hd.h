// CPS_HD marks functions compiled for both host and device: physics is written once.
#pragma once

#ifdef __CUDACC__
#define CPS_HD __host__ __device__
#define CPS_INLINE __forceinline__
#else
#define CPS_HD
#define CPS_INLINE inline
#endif

#include <cmath>
#include <cstdint>

namespace cps {

// sqrt/min/max that work in both compilation modes
CPS_HD CPS_INLINE float fsqrt(float x) {
#ifdef __CUDA_ARCH__
  return ::sqrtf(x);
#else
  return __builtin_sqrtf(x);
#endif
}
CPS_HD CPS_INLINE float fpow(float x, float y) {
#ifdef __CUDA_ARCH__
  return ::powf(x, y);
#else
  return std::pow(x, y);
#endif
}
// log, exp, cos, sin: the CUDA intrinsic on the device, the C++ library on the host
#ifdef __CUDA_ARCH__
#define CPS_UNARY_MATH(name, device_fn, host_fn) \
  CPS_HD CPS_INLINE float name(float x) { return ::device_fn(x); }
#else
#define CPS_UNARY_MATH(name, device_fn, host_fn) \
  CPS_HD CPS_INLINE float name(float x) { return host_fn(x); }
#endif
CPS_UNARY_MATH(flog, logf, std::log)
CPS_UNARY_MATH(fexp, expf, std::exp)
CPS_UNARY_MATH(fcos, cosf, std::cos)
CPS_UNARY_MATH(fsin, sinf, std::sin)
CPS_UNARY_MATH(ferf, erff, std::erf)
CPS_UNARY_MATH(ffloor, floorf, std::floor)
#undef CPS_UNARY_MATH
CPS_HD CPS_INLINE float fmin2(float a, float b) { return a < b ? a : b; }
CPS_HD CPS_INLINE float fmax2(float a, float b) { return a > b ? a : b; }
CPS_HD CPS_INLINE float fclamp(float x, float lo, float hi) { return fmin2(fmax2(x, lo), hi); }
CPS_HD CPS_INLINE int iclamp(int x, int lo, int hi) { return x < lo ? lo : (x > hi ? hi : x); }
CPS_HD CPS_INLINE bool finite(float x) { return x == x && x - x == 0.0f; }

constexpr float kPi = 3.14159265358979323846f;

}  // namespace cps
