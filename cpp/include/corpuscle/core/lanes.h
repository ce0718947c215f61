// Lanes: several threads cooperating on one item (a particle's neighbour loop). The CPU
// runs one lane per item; CUDA runs a warp per item so neighbour loads are coalesced and
// small particle counts still fill the GPU. A functor written against `Lanes` works for both.
// Here only what lanes are: their sums, ballots and shuffles; the walks of an index by lanes
// are in the spatial layer (spatial/lane_walks.h).
#pragma once
#include <cstring>

#include "corpuscle/core/vec.h"

namespace cps {

// one lane: the plain serial loop
struct SingleLane {
  CPS_HD float sum(float x) const { return x; }
  template <int D>
  CPS_HD Vec<D> sum(const Vec<D>& v) const { return v; }
  CPS_HD bool leader() const { return true; }
};

#ifdef __CUDACC__
// W cooperating lanes of a warp (W = 1, 2, 4, ..., 32) per item: a stage chooses its width
// (warp-per-particle suits SPH's 100+ neighbours; DEM's ~6 contacts want a few lanes). Every
// loop strides by W; sums reduce by shuffles within the group, ballots are masked to it, so
// groups of one warp run different items independently. WarpLanes is the tuned W = 32 form.
template <int W>
struct SubWarpLanes {
  static_assert(W >= 1 && W <= 32 && (W & (W - 1)) == 0, "lane width must be a power of two up to 32");
  __device__ int lane() const { return int(threadIdx.x) & (W - 1); }
  __device__ int base() const { return int(threadIdx.x) & 31 & ~(W - 1); }
  __device__ unsigned mask() const {
    if constexpr (W == 32) return 0xffffffffu;
    else return ((1u << W) - 1u) << base();
  }
  // the group's bits of a ballot, lane 0 of the group in bit 0
  __device__ unsigned group_ballot(bool p) const {
    const unsigned b = __ballot_sync(mask(), p);
    if constexpr (W == 32) return b;
    else return (b >> base()) & ((1u << W) - 1u);
  }
  __device__ float sum(float x) const {
    for (int o = W / 2; o > 0; o >>= 1) x += __shfl_xor_sync(mask(), x, o, W);
    return x;
  }
  template <int D>
  __device__ Vec<D> sum(Vec<D> v) const {
    for (int k = 0; k < D; ++k) v[k] = sum(v[k]);
    return v;
  }
  __device__ bool leader() const { return lane() == 0; }
  // the value of v held by lane lane() ^ o of the group (any trivially copyable T of whole
  // 32-bit words, moved word by word: a visitor's partial sums)
  template <class T>
  __device__ T shfl_xor(const T& v, int o) const {
    static_assert(sizeof(T) % 4 == 0, "shfl_xor moves whole 32-bit words");
    constexpr int kWords = int(sizeof(T) / 4);
    unsigned w[kWords];
    memcpy(w, &v, sizeof(T));
    for (int k = 0; k < kWords; ++k) w[k] = __shfl_xor_sync(mask(), w[k], o, W);
    T r;
    memcpy(&r, w, sizeof(T));
    return r;
  }

};

// a full warp: lanes stride the neighbour candidates, sums reduce by butterfly shuffles
// (the same tree on every run, so results are reproducible)
struct WarpLanes : SubWarpLanes<32> {};

#endif

}  // namespace cps
