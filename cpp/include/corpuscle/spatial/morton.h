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

}  // namespace cps
