// All pairs: every particle against every other, O(N^2). The reference index (no build, no
// limit on the radius) and the right one for small N, where a grid costs more than it saves.
//
// gather visits j = 0, 1, ..., n-1 in order; pairs visits j = i+1, ..., n-1. On CUDA the
// tiled form (gather_stage_tiled) runs a begin / visit / end stage with blocks of kTile
// threads that load tiles of kTile positions into shared memory, every thread of the block
// then scanning the tile: the same visits in the same order as gather, so the same results.
// gather_range and list_range walk a part of the slots by cooperating lanes (a particle's
// scene of a batch, or its ghosts: the Magic 8-Ball's all pairs and its lists' scan).
#pragma once
#include "corpuscle/spatial/index.h"
#include "corpuscle/spatial/lane_walks.h"
#include "corpuscle/spatial/periodic.h"

namespace cps {

template <int D>
struct AllPairsView {
  static constexpr int kDim = D;
  const Vec<D>* pos = nullptr;
  int n = 0;
  float r2 = 0.0f;  // squared query radius
  Periodic<D> per;  // periodic axes: the minimum-image displacement (gather, pairs, the tiled
                    // gather; not gather_range / list_range)

  CPS_HD int size() const { return n; }
  CPS_HD bool active(int) const { return true; }
  CPS_HD const Vec<D>& position(int i) const { return pos[i]; }
  CPS_HD float max_radius() const { return kNoRadiusLimit; }
  CPS_HD AllPairsView with_radius(float r) const {
    AllPairsView v = *this;
    v.r2 = r * r;
    return v;
  }

  template <class Visit>
  CPS_HD void gather(int /*i*/, const Vec<D>& xi, Visit&& visit) const {
    for (int j = 0; j < n; ++j) {
      Vec<D> d = per.displacement(xi - pos[j]);
      float rr = norm2(d);
      if (rr < r2) visit(j, d, rr);
    }
  }
  template <class Visit>
  CPS_HD void pairs(int i, const Vec<D>& xi, Visit&& visit) const {
    for (int j = i + 1; j < n; ++j) {
      Vec<D> d = per.displacement(xi - pos[j]);
      float rr = norm2(d);
      if (rr < r2) visit(j, d, rr);
    }
  }
  // gather's visits restricted to slots [begin, end), by lanes (core/lanes.h: the CPU's one
  // lane, or W lanes of a warp striding the slots); returns how many there were (every lane)
  template <class Lanes, class Visit>
  CPS_HD int gather_range(const Lanes& L, int begin, int end, const Vec<D>& xi, Visit& visit) const {
    return for_each_in_range(L, pos, begin, end, xi, r2, visit);
  }
  // list the slots of [begin, end) that gather_range visits after the `count` already listed
  // (up to cap), in index order; returns the new count (the true one, past cap)
  template <class Lanes>
  CPS_HD int list_range(const Lanes& L, int begin, int end, const Vec<D>& xi, int* list, int cap, int count) const {
    return list_in_range(L, pos, begin, end, xi, r2, list, cap, count);
  }
};

// the host side: nothing to build, it only remembers the positions
template <int D>
struct AllPairs {
  const Vec<D>* pos = nullptr;
  int n = 0;
  float radius = 0.0f;

  template <class Exec>
  void build(Exec& /*ex*/, const Vec<D>* positions, int count, float r) {
    pos = positions;
    n = count;
    radius = r;
  }
  AllPairsView<D> view() const { return AllPairsView<D>{pos, n, radius * radius}; }
};

// the tiled gather: tile t covers particles [t*K, t*K + K); each lane owns one of them and
// the tile walks the positions in tiles of K staged through shared memory (phases between
// syncs, see CpuTile in cpu/exec_cpu.h)
template <int D, class Stage>
struct AllPairsTiledGatherFn {
  AllPairsView<D> view;
  Stage stage;

  template <class Tile>
  CPS_HD void operator()(int tile, Tile& t) const {
    constexpr int K = Tile::kSize;
    const int n = view.n;
    Vec<D>* sh = t.template shared<Vec<D>>(K);
    typename Tile::template PerLane<typename Stage::Acc> acc;
    typename Tile::template PerLane<Vec<D>> xi;
    t.lanes([&](int l) {
      const int i = tile * K + l;
      if (i < n) {
        xi[l] = view.pos[i];
        acc[l] = stage.begin(i);
      }
    });
    for (int base = 0; base < n; base += K) {
      const int m = n - base < K ? n - base : K;
      t.lanes([&](int l) {
        if (l < m) sh[l] = view.pos[base + l];
      });
      t.sync();
      t.lanes([&](int l) {
        const int i = tile * K + l;
        if (i >= n) return;
        for (int k = 0; k < m; ++k) {
          Vec<D> d = view.per.displacement(xi[l] - sh[k]);
          float rr = norm2(d);
          if (rr < view.r2) stage.visit(acc[l], i, base + k, d, rr);
        }
      });
      t.sync();
    }
    t.lanes([&](int l) {
      const int i = tile * K + l;
      if (i < n) stage.end(i, acc[l]);
    });
  }
};

// run a begin / visit / end stage over all pairs in tiles of kTile (a CUDA block each)
template <int kTile, class Exec, int D, class Stage>
void gather_stage_tiled(Exec& ex, const AllPairsView<D>& view, const Stage& stage) {
  const int ntiles = (view.n + kTile - 1) / kTile;
  ex.template for_each_tile<kTile>(ntiles, AllPairsTiledGatherFn<D, Stage>{view, stage}, sizeof(Vec<D>) * kTile);
}

}  // namespace cps
