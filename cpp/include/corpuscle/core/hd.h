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
// 1 / sqrt(x): the device's reciprocal square root (within 2 ulp), the host's 1 / sqrt
CPS_HD CPS_INLINE float frsqrt(float x) {
#ifdef __CUDA_ARCH__
  return ::rsqrtf(x);
#else
  return 1.0f / __builtin_sqrtf(x);
#endif
}
CPS_HD CPS_INLINE float fpow(float x, float y) {
#ifdef __CUDA_ARCH__
  return ::powf(x, y);
#else
  return std::pow(x, y);
#endif
}
// Pair-loop arithmetic (the SPH box's pair terms): the host evaluates exactly the IEEE
// operation written (so CPU results are those of a / b, sqrt(x), pow(x, y)); the device uses
// the hardware approximations, one or two instructions instead of a call of ten to fifty:
// __fdividef (2 ulp; 0 for |b| > 2^126), sqrt.approx (about 1 ulp; 0 -> 0, inf -> inf) and
// __powf (exp2(y log2 x): an absolute error of a few 1e-7 near x = 1). The CUDA results stay
// within the float tolerance the CUDA-vs-CPU tests allow; use them only where that holds.
CPS_HD CPS_INLINE float fdiv_fast(float a, float b) {
#ifdef __CUDA_ARCH__
  return __fdividef(a, b);
#else
  return a / b;
#endif
}
CPS_HD CPS_INLINE float fsqrt_fast(float x) {
#ifdef __CUDA_ARCH__
  float r;
  asm("sqrt.approx.f32 %0, %1;" : "=f"(r) : "f"(x));
  return r;
#else
  return __builtin_sqrtf(x);
#endif
}
CPS_HD CPS_INLINE float fpow_fast(float x, float y) {
#ifdef __CUDA_ARCH__
  return __powf(x, y);
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
