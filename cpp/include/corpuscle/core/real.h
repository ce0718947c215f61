// sqrt, pow, log, exp and pi for float and double, so that a closed form written once as a
// template over its number type runs in the core's float (the same calls as fsqrt, fpow,
// flog, fexp: bit for bit) and in double, where Python asks for the value its float64 scene
// keys give (the bindings of physics_bindings.cpp). Not overloads of fsqrt & co.: those take
// float on purpose, and a double overload would silently move existing calls to double.
#pragma once

#include "corpuscle/core/hd.h"

namespace cps {


CPS_HD CPS_INLINE float tsqrt(float x) { return fsqrt(x); }
CPS_HD CPS_INLINE float tpow(float x, float y) { return fpow(x, y); }
CPS_HD CPS_INLINE float tlog(float x) { return flog(x); }
CPS_HD CPS_INLINE float texp(float x) { return fexp(x); }
#ifdef __CUDA_ARCH__
CPS_HD CPS_INLINE double tsqrt(double x) { return ::sqrt(x); }
CPS_HD CPS_INLINE double tpow(double x, double y) { return ::pow(x, y); }
CPS_HD CPS_INLINE double tlog(double x) { return ::log(x); }
CPS_HD CPS_INLINE double texp(double x) { return ::exp(x); }
#else
CPS_HD CPS_INLINE double tsqrt(double x) { return std::sqrt(x); }
CPS_HD CPS_INLINE double tpow(double x, double y) { return std::pow(x, y); }
CPS_HD CPS_INLINE double tlog(double x) { return std::log(x); }
CPS_HD CPS_INLINE double texp(double x) { return std::exp(x); }
#endif

// pi in T: float(pi) is kPi (the float literal), double(pi) is Python's math.pi
template <class T>
CPS_HD CPS_INLINE constexpr T pi_of() { return T(3.14159265358979323846); }
static_assert(pi_of<float>() == kPi, "pi in float is kPi");

}  // namespace cps
