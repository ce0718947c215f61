// Lanes: several threads cooperating on one item (a particle's neighbour loop). The CPU
// runs one lane per item; CUDA runs a warp per item so neighbour loads are coalesced and
// small particle counts still fill the GPU. A functor written against `Lanes` works for both.
#pragma once
#include <cstring>

#include "corpuscle/spatial/grid.h"

namespace cps {

// one lane: the plain serial loop
struct SingleLane {
  CPS_HD float sum(float x) const { return x; }
  template <int D>
  CPS_HD Vec<D> sum(const Vec<D>& v) const { return v; }
  CPS_HD bool leader() const { return true; }
  // the plain cell-by-cell neighbour loop, listing the neighbours (up to cap; returns how
  // many there were)
  template <int D, class Visitor>
  CPS_HD int for_each_neighbor_listing(const GridView<D>& g, const Vec<D>& xi, bool ghosts, Visitor& visit,
                                       int* list, int cap) const {
    int count = 0;
    auto listing = [&](int j, const Vec<D>& d, float r2) {
      if (count < cap) list[count] = j;
      ++count;
      visit(j, d, r2);
    };
    cps::for_each_neighbor(g, xi, ghosts, listing);
    return count;
  }
  // visit every j in [begin, end) closer than sqrt(r2max) to xi (the all-pairs walk);
  // returns how many there were
  template <int D, class Visitor>
  CPS_HD int for_each_in_range(const Vec<D>* pos, int begin, int end, const Vec<D>& xi, float r2max,
                               Visitor& visit) const {
    int count = 0;
    for (int j = begin; j < end; ++j) {
      Vec<D> d = xi - pos[j];
      float r2 = norm2(d);
      if (r2 < r2max) {
        visit(j, d, r2);
        ++count;
      }
    }
    return count;
  }
  // list every j in [begin, end) closer than sqrt(r2max) to xi after the `count` already
  // listed (up to cap), in index order; returns the new count (the true one, past cap)
  template <int D>
  CPS_HD int list_in_range(const Vec<D>* pos, int begin, int end, const Vec<D>& xi, float r2max, int* list, int cap,
                           int count) const {
    for (int j = begin; j < end; ++j) {
      Vec<D> d = xi - pos[j];
      if (norm2(d) < r2max) {
        if (count < cap) list[count] = j;
        ++count;
      }
    }
    return count;
  }
  // visit the listed neighbours of xi
  template <int D, class Visitor>
  CPS_HD void for_each_listed(const int* list, int count, const Vec<D>* pos, const Vec<D>& xi, Visitor& visit) const {
    for (int e = 0; e < count; ++e) {
      const int j = list[e];
      Vec<D> d = xi - pos[j];
      visit(j, d, norm2(d));
    }
  }
  // visit the listed neighbours of xi and copy those closer than sqrt(r2max) to `out`, in
  // order (up to cap); returns how many there were
  template <int D, class Visitor>
  CPS_HD int for_each_listed_compacting(const int* list, int count, const Vec<D>* pos, const Vec<D>& xi,
                                        Visitor& visit, float r2max, int* out, int cap) const {
    int kept = 0;
    for (int e = 0; e < count; ++e) {
      const int j = list[e];
      Vec<D> d = xi - pos[j];
      float r2 = norm2(d);
      visit(j, d, r2);
      if (r2 < r2max) {
        if (kept < cap) out[kept] = j;
        ++kept;
      }
    }
    return kept;
  }
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

  template <int D, class Visitor>
  __device__ int for_each_in_range(const Vec<D>* pos, int begin, int end, const Vec<D>& xi, float r2max,
                                   Visitor& visit) const {
    int count = 0;
    for (int b = begin; b < end; b += W) {
      const int j = b + lane();
      bool hit = false;
      if (j < end) {
        Vec<D> d = xi - pos[j];
        float r2 = norm2(d);
        hit = r2 < r2max;
        if (hit) visit(j, d, r2);
      }
      count += __popc(group_ballot(hit));
    }
    return count;
  }

  // SingleLane::list_in_range: W candidates a round, hits listed in index order by a ballot
  template <int D>
  __device__ int list_in_range(const Vec<D>* pos, int begin, int end, const Vec<D>& xi, float r2max, int* list,
                               int cap, int count) const {
    const unsigned below = (1u << lane()) - 1u;
    for (int b = begin; b < end; b += W) {
      const int j = b + lane();
      bool hit = false;
      if (j < end) {
        Vec<D> d = xi - pos[j];
        hit = norm2(d) < r2max;
      }
      const unsigned m = group_ballot(hit);
      if (hit) {
        const int at = count + __popc(m & below);
        if (at < cap) list[at] = j;
      }
      count += __popc(m);
    }
    return count;
  }

  template <int D, class Visitor>
  __device__ void for_each_listed(const int* list, int count, const Vec<D>* pos, const Vec<D>& xi,
                                  Visitor& visit) const {
    for (int e = lane(); e < count; e += W) {
      const int j = list[e];
      Vec<D> d = xi - pos[j];
      visit(j, d, norm2(d));
    }
  }

  template <int D, class Visitor>
  __device__ int for_each_listed_compacting(const int* list, int count, const Vec<D>* pos, const Vec<D>& xi,
                                            Visitor& visit, float r2max, int* out, int cap) const {
    const unsigned below = (1u << lane()) - 1u;
    int kept = 0;
    for (int b = 0; b < count; b += W) {
      const int e = b + lane();
      bool near = false;
      if (e < count) {
        const int j = list[e];
        Vec<D> d = xi - pos[j];
        float r2 = norm2(d);
        visit(j, d, r2);
        near = r2 < r2max;
      }
      const unsigned m = group_ballot(near);
      if (near) {
        const int at = kept + __popc(m & below);
        if (at < cap) out[at] = list[e];
      }
      kept += __popc(m);
    }
    return kept;
  }

  // cell range of stencil slot k (layer k / stencil, offset k % stencil), empty outside the grid
  template <int D>
  __device__ static void load_range(const GridView<D>& g, const int* c, int k, int nslots, uint32_t& s, uint32_t& e) {
    uint32_t slot;
    if (k >= nslots || !stencil_slot(g.spec, c, k % kStencil<D>, k / kStencil<D>, slot)) return;
    s = g.cell_start[slot];
    e = g.cell_end[slot];
  }

  // the cell walk (WarpLanes': W = 32): the lanes load the ranges of W stencil cells at once
  // (lane l: cell k0 + l), then walk those cells with the ranges broadcast by shuffles, each
  // lane taking every W-th candidate of a cell. Neighbours are listed in the serial loop's
  // order (the stencil's cells of the fluid layer, then of the ghost layer; ascending index in
  // each: a ballot keeps lane order), up to cap; returns how many there were (on every lane)
  template <int D, class Visitor>
  __device__ int for_each_neighbor_listing(const GridView<D>& g, const Vec<D>& xi, bool ghosts, Visitor& visit,
                                           int* list, int cap) const {
    const int nslots = kStencil<D> * (ghosts ? 2 : 1);
    int c[D];
    g.spec.cell_of(xi, c);
    const unsigned below = (1u << lane()) - 1u;
    int count = 0;
    for (int k0 = 0; k0 < nslots; k0 += W) {
      uint32_t sl = 0, el = 0;  // the range of stencil cell k0 + lane
      load_range(g, c, k0 + lane(), nslots, sl, el);
      const int kn = nslots - k0 < W ? nslots - k0 : W;
      for (int q = 0; q < kn; ++q) {
        const uint32_t s = __shfl_sync(mask(), sl, q, W), e = __shfl_sync(mask(), el, q, W);
        for (uint32_t b = s; b < e; b += uint32_t(W)) {
          const uint32_t j = b + uint32_t(lane());
          Vec<D> d = Vec<D>::zero();
          float r2 = 0.0f;
          bool hit = false;
          if (j < e) {
            d = xi - g.pos[j];
            r2 = norm2(d);
            hit = r2 < g.spec.h2;
          }
          const unsigned m = group_ballot(hit);
          if (hit) {
            const int at = count + __popc(m & below);
            if (at < cap) list[at] = int(j);
            visit(int(j), d, r2);
          }
          count += __popc(m);
        }
      }
    }
    return count;
  }
};

// a full warp: lanes stride the neighbour candidates, sums reduce by butterfly shuffles
// (the same tree on every run, so results are reproducible)
struct WarpLanes : SubWarpLanes<32> {};

#endif

}  // namespace cps
