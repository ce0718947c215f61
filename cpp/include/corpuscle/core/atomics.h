// Atomic read-modify-write operations for CPS_HD functors: CUDA's atomics on the device,
// GCC's __atomic builtins on the host (OpenMP threads). Every operation returns the value
// held before it (as CUDA's do) and is relaxed: it orders nothing but its own location, so
// use them for sums, counters and claims, never as locks around other memory.
//
// Float sums through atomic_add depend on the order threads arrive in: results are
// reproducible only where the data make that order irrelevant (integers, or gather-style
// stages that need no atomics at all).
#pragma once
#include <cstring>

#include "corpuscle/core/hd.h"

namespace cps {

CPS_HD CPS_INLINE int atomic_add(int* p, int v) {
#ifdef __CUDA_ARCH__
  return atomicAdd(p, v);
#else
  return __atomic_fetch_add(p, v, __ATOMIC_RELAXED);
#endif
}

CPS_HD CPS_INLINE unsigned atomic_add(unsigned* p, unsigned v) {
#ifdef __CUDA_ARCH__
  return atomicAdd(p, v);
#else
  return __atomic_fetch_add(p, v, __ATOMIC_RELAXED);
#endif
}

CPS_HD CPS_INLINE float atomic_add(float* p, float v) {
#ifdef __CUDA_ARCH__
  return atomicAdd(p, v);
#else
  // compare-and-swap loop on the float's bits
  float expected;
  __atomic_load(p, &expected, __ATOMIC_RELAXED);
  float desired = expected + v;
  while (!__atomic_compare_exchange(p, &expected, &desired, true, __ATOMIC_RELAXED, __ATOMIC_RELAXED))
    desired = expected + v;
  return expected;
#endif
}

// *p = max(*p, v)
CPS_HD CPS_INLINE int atomic_max(int* p, int v) {
#ifdef __CUDA_ARCH__
  return atomicMax(p, v);
#else
  int expected = __atomic_load_n(p, __ATOMIC_RELAXED);
  while (expected < v && !__atomic_compare_exchange_n(p, &expected, v, true, __ATOMIC_RELAXED, __ATOMIC_RELAXED)) {
  }
  return expected;
#endif
}

// the bits of a float as an int and back: non-negative floats (not NaN) order as their bits,
// so atomic_max of the bits is the max of the values
CPS_HD CPS_INLINE int float_bits(float x) {
#ifdef __CUDA_ARCH__
  return __float_as_int(x);
#else
  int b;
  std::memcpy(&b, &x, sizeof b);
  return b;
#endif
}
CPS_HD CPS_INLINE float bits_float(int b) {
#ifdef __CUDA_ARCH__
  return __int_as_float(b);
#else
  float x;
  std::memcpy(&x, &b, sizeof x);
  return x;
#endif
}

// *p = max(*p, v) for a running maximum that many threads raise and few raise further. On
// the device (sm_80 and later) the lanes of a warp that raise the same p combine first and
// one of them raises it (a scene's particles are contiguous, so mostly one atomic a warp,
// fire-and-forget: no load of *p waits in the thread's path); before sm_80 each lane skips
// the atomic where *p, as last seen, is already at least its value
CPS_HD CPS_INLINE void atomic_max_above(int* p, int v) {
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 800
  const unsigned peers = __match_any_sync(__activemask(), reinterpret_cast<unsigned long long>(p));
  const int m = __reduce_max_sync(peers, v);
  if (int(threadIdx.x & 31u) == __ffs(int(peers)) - 1) atomicMax(p, m);
#elif defined(__CUDA_ARCH__)
  if (v > *static_cast<volatile int*>(p)) atomicMax(p, v);
#else
  atomic_max(p, v);  // loads first and stops there when *p >= v
#endif
}

// *p = min(*p, v)
CPS_HD CPS_INLINE int atomic_min(int* p, int v) {
#ifdef __CUDA_ARCH__
  return atomicMin(p, v);
#else
  int expected = __atomic_load_n(p, __ATOMIC_RELAXED);
  while (expected > v && !__atomic_compare_exchange_n(p, &expected, v, true, __ATOMIC_RELAXED, __ATOMIC_RELAXED)) {
  }
  return expected;
#endif
}

// if *p == compare then *p = value; returns the old *p (the swap happened when it equals compare)
CPS_HD CPS_INLINE int atomic_cas(int* p, int compare, int value) {
#ifdef __CUDA_ARCH__
  return atomicCAS(p, compare, value);
#else
  __atomic_compare_exchange_n(p, &compare, value, false, __ATOMIC_RELAXED, __ATOMIC_RELAXED);
  return compare;  // on failure the builtin stored the current value here; on success it is unchanged
#endif
}

}  // namespace cps
