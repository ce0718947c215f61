// Morton (Z-order) codes for cell coordinates: cells close in space are close in memory.
#pragma once
#include "corpuscle/core/hd.h"

namespace cps {

// spread the low 10 bits of x so that two zero bits separate each (3-D interleave)
CPS_HD CPS_INLINE uint32_t morton_spread3(uint32_t x) {
  x &= 0x3ffu;
  x = (x | (x << 16)) & 0x030000ffu;
  x = (x | (x << 8)) & 0x0300f00fu;
  x = (x | (x << 4)) & 0x030c30c3u;
  x = (x | (x << 2)) & 0x09249249u;
  return x;
}

// spread the low 16 bits of x so that one zero bit separates each (2-D interleave)
CPS_HD CPS_INLINE uint32_t morton_spread2(uint32_t x) {
  x &= 0xffffu;
  x = (x | (x << 8)) & 0x00ff00ffu;
  x = (x | (x << 4)) & 0x0f0f0f0fu;
  x = (x | (x << 2)) & 0x33333333u;
  x = (x | (x << 1)) & 0x55555555u;
  return x;
}

template <int D>
CPS_HD CPS_INLINE uint32_t morton_encode(const int* c) {
  if constexpr (D == 3) {
    return morton_spread3(uint32_t(c[0])) | (morton_spread3(uint32_t(c[1])) << 1) |
           (morton_spread3(uint32_t(c[2])) << 2);
  } else {
    return morton_spread2(uint32_t(c[0])) | (morton_spread2(uint32_t(c[1])) << 1);
  }
}

// largest number of bits per axis a 32-bit key can hold (two bits stay free for tags)
template <int D>
constexpr int morton_max_bits() {
  return D == 3 ? 10 : 15;
}


// ---- decoding (the inverse of morton_encode) ----

// gather every third bit of x (bits 0, 3, 6, ...) into the low 10 bits
CPS_HD CPS_INLINE uint32_t morton_compact3(uint32_t x) {
  x &= 0x09249249u;
  x = (x ^ (x >> 2)) & 0x030c30c3u;
  x = (x ^ (x >> 4)) & 0x0300f00fu;
  x = (x ^ (x >> 8)) & 0x030000ffu;
  x = (x ^ (x >> 16)) & 0x000003ffu;
  return x;
}

// gather every second bit of x (bits 0, 2, 4, ...) into the low 16 bits
CPS_HD CPS_INLINE uint32_t morton_compact2(uint32_t x) {
  x &= 0x55555555u;
  x = (x ^ (x >> 1)) & 0x33333333u;
  x = (x ^ (x >> 2)) & 0x0f0f0f0fu;
  x = (x ^ (x >> 4)) & 0x00ff00ffu;
  x = (x ^ (x >> 8)) & 0x0000ffffu;
  return x;
}

template <int D>
CPS_HD CPS_INLINE void morton_decode(uint32_t code, int* c) {
  for (int k = 0; k < D; ++k) c[k] = int(D == 3 ? morton_compact3(code >> k) : morton_compact2(code >> k));
}

// ---- 64-bit codes: 21 bits per axis in 3-D, 32 in 2-D ----

// spread the low 21 bits of x so that two zero bits separate each
CPS_HD CPS_INLINE uint64_t morton_spread3_64(uint64_t x) {
  x &= 0x1fffffull;
  x = (x | (x << 32)) & 0x001f00000000ffffull;
  x = (x | (x << 16)) & 0x001f0000ff0000ffull;
  x = (x | (x << 8)) & 0x100f00f00f00f00full;
  x = (x | (x << 4)) & 0x10c30c30c30c30c3ull;
  x = (x | (x << 2)) & 0x1249249249249249ull;
  return x;
}

CPS_HD CPS_INLINE uint64_t morton_compact3_64(uint64_t x) {
  x &= 0x1249249249249249ull;
  x = (x ^ (x >> 2)) & 0x10c30c30c30c30c3ull;
  x = (x ^ (x >> 4)) & 0x100f00f00f00f00full;
  x = (x ^ (x >> 8)) & 0x001f0000ff0000ffull;
  x = (x ^ (x >> 16)) & 0x001f00000000ffffull;
  x = (x ^ (x >> 32)) & 0x00000000001fffffull;
  return x;
}

// spread the low 32 bits of x so that one zero bit separates each
CPS_HD CPS_INLINE uint64_t morton_spread2_64(uint64_t x) {
  x &= 0xffffffffull;
  x = (x | (x << 16)) & 0x0000ffff0000ffffull;
  x = (x | (x << 8)) & 0x00ff00ff00ff00ffull;
  x = (x | (x << 4)) & 0x0f0f0f0f0f0f0f0full;
  x = (x | (x << 2)) & 0x3333333333333333ull;
  x = (x | (x << 1)) & 0x5555555555555555ull;
  return x;
}

CPS_HD CPS_INLINE uint64_t morton_compact2_64(uint64_t x) {
  x &= 0x5555555555555555ull;
  x = (x ^ (x >> 1)) & 0x3333333333333333ull;
  x = (x ^ (x >> 2)) & 0x0f0f0f0f0f0f0f0full;
  x = (x ^ (x >> 4)) & 0x00ff00ff00ff00ffull;
  x = (x ^ (x >> 8)) & 0x0000ffff0000ffffull;
  x = (x ^ (x >> 16)) & 0x00000000ffffffffull;
  return x;
}

// cell coordinates c[0..D) (each below 2^morton_max_bits64<D>()) to a 64-bit code, x lowest
template <int D>
CPS_HD CPS_INLINE uint64_t morton_encode64(const int* c) {
  if constexpr (D == 3) {
    return morton_spread3_64(uint32_t(c[0])) | (morton_spread3_64(uint32_t(c[1])) << 1) |
           (morton_spread3_64(uint32_t(c[2])) << 2);
  } else {
    return morton_spread2_64(uint32_t(c[0])) | (morton_spread2_64(uint32_t(c[1])) << 1);
  }
}

template <int D>
CPS_HD CPS_INLINE void morton_decode64(uint64_t code, int* c) {
  for (int k = 0; k < D; ++k) c[k] = int(uint32_t(D == 3 ? morton_compact3_64(code >> k) : morton_compact2_64(code >> k)));
}

// bits per axis a 64-bit code holds
template <int D>
constexpr int morton_max_bits64() {
  return D == 3 ? 21 : 32;
}

}  // namespace cps
