// Lanes: several threads cooperating on one item (a particle's neighbour loop). The CPU
// runs one lane per item; CUDA runs a warp per item so neighbour loads are coalesced and
// small particle counts still fill the GPU. A functor written against `Lanes` works for both.
#pragma once
#include "corpuscle/core/vec.h"

namespace cps {

// one lane: the plain serial loop
struct SingleLane {
  CPS_HD int lane() const { return 0; }
  CPS_HD int count() const { return 1; }
  CPS_HD float sum(float x) const { return x; }
  template <int D>
  CPS_HD Vec<D> sum(const Vec<D>& v) const { return v; }
  CPS_HD bool leader() const { return true; }
};

#ifdef __CUDACC__
// a full warp: lanes stride the neighbour candidates, sums reduce by butterfly shuffles
// (the same tree on every run, so results are reproducible)
struct WarpLanes {
  __device__ int lane() const { return int(threadIdx.x) & 31; }
  __device__ int count() const { return 32; }
  __device__ float sum(float x) const {
    for (int o = 16; o > 0; o >>= 1) x += __shfl_xor_sync(0xffffffffu, x, o);
    return x;
  }
  template <int D>
  __device__ Vec<D> sum(Vec<D> v) const {
    for (int k = 0; k < D; ++k) v[k] = sum(v[k]);
    return v;
  }
  __device__ bool leader() const { return lane() == 0; }
};
#endif

}  // namespace cps
