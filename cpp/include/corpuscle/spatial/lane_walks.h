// Walks of a range of slots, of a cell grid's block or of a neighbour list by cooperating
// lanes (core/lanes.h): the all-pairs walk of a slot range, the listing of a range, the walk
// of the cells around a point (CellGridView's order), the walk of a list and its compaction
// to the entries within a smaller radius. One overload per kind of lanes: the
// CPU's SingleLane (the plain serial loop) and CUDA's SubWarpLanes<W> (W lanes of a warp
// stride the candidates; hits are listed in index order by a ballot, so a list comes out
// the same on every backend). Each visit is visit(j, xi - x_j, r2).
#pragma once
#include "corpuscle/core/lanes.h"
#include "corpuscle/spatial/cell_grid.h"

namespace cps {

// visit every j in [begin, end) closer than sqrt(r2max) to xi (the all-pairs walk);
// returns how many there were
template <int D, class Visitor>
CPS_HD int for_each_in_range(const SingleLane&, const Vec<D>* pos, int begin, int end, const Vec<D>& xi, float r2max,
                             Visitor& visit) {
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
CPS_HD int list_in_range(const SingleLane&, const Vec<D>* pos, int begin, int end, const Vec<D>& xi, float r2max, int* list, int cap,
                         int count) {
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
CPS_HD void for_each_listed(const SingleLane&, const int* list, int count, const Vec<D>* pos, const Vec<D>& xi, Visitor& visit) {
  for (int e = 0; e < count; ++e) {
    const int j = list[e];
    Vec<D> d = xi - pos[j];
    visit(j, d, norm2(d));
  }
}
// visit the listed neighbours of xi and copy those closer than sqrt(r2max) to `out`, in
// order (up to cap); returns how many there were
template <int D, class Visitor>
CPS_HD int for_each_listed_compacting(const SingleLane&, const int* list, int count, const Vec<D>* pos, const Vec<D>& xi,
                                      Visitor& visit, float r2max, int* out, int cap) {
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

// visit every slot of g's tags within sqrt(g.r2) of xi, cell by cell in CellGridView's walk
// order (tags, then z, y, x, then slots), and list them (up to cap); returns how many there
// were
template <int D, class Visitor>
CPS_HD int for_each_in_cells(const SingleLane&, const CellGridView<D>& g, const Vec<D>& xi, Visitor& visit, int* list,
                             int cap) {
  int count = 0;
  g.for_each_cell_range(0, xi, [&](uint32_t s, uint32_t e) {
    for (uint32_t j = s; j < e; ++j) {
      Vec<D> d = xi - g.pos[j];
      float r2 = norm2(d);
      if (r2 < g.r2) {
        if (count < cap) list[count] = int(j);
        ++count;
        visit(int(j), d, r2);
      }
    }
  });
  return count;
}

#ifdef __CUDACC__
template <int W, int D, class Visitor>
__device__ int for_each_in_range(const SubWarpLanes<W>& L, const Vec<D>* pos, int begin, int end, const Vec<D>& xi, float r2max,
                                 Visitor& visit) {
  int count = 0;
  for (int b = begin; b < end; b += W) {
    const int j = b + L.lane();
    bool hit = false;
    if (j < end) {
      Vec<D> d = xi - pos[j];
      float r2 = norm2(d);
      hit = r2 < r2max;
      if (hit) visit(j, d, r2);
    }
    count += __popc(L.group_ballot(hit));
  }
  return count;
}

// list_in_range's lanes: W candidates a round, hits listed in index order by a ballot
template <int W, int D>
__device__ int list_in_range(const SubWarpLanes<W>& L, const Vec<D>* pos, int begin, int end, const Vec<D>& xi, float r2max, int* list,
                             int cap, int count) {
  const unsigned below = (1u << L.lane()) - 1u;
  for (int b = begin; b < end; b += W) {
    const int j = b + L.lane();
    bool hit = false;
    if (j < end) {
      Vec<D> d = xi - pos[j];
      hit = norm2(d) < r2max;
    }
    const unsigned m = L.group_ballot(hit);
    if (hit) {
      const int at = count + __popc(m & below);
      if (at < cap) list[at] = j;
    }
    count += __popc(m);
  }
  return count;
}

template <int W, int D, class Visitor>
__device__ void for_each_listed(const SubWarpLanes<W>& L, const int* list, int count, const Vec<D>* pos, const Vec<D>& xi,
                                Visitor& visit) {
  for (int e = L.lane(); e < count; e += W) {
    const int j = list[e];
    Vec<D> d = xi - pos[j];
    visit(j, d, norm2(d));
  }
}

template <int W, int D, class Visitor>
__device__ int for_each_listed_compacting(const SubWarpLanes<W>& L, const int* list, int count, const Vec<D>* pos, const Vec<D>& xi,
                                          Visitor& visit, float r2max, int* out, int cap) {
  const unsigned below = (1u << L.lane()) - 1u;
  int kept = 0;
  for (int b = 0; b < count; b += W) {
    const int e = b + L.lane();
    bool near = false;
    if (e < count) {
      const int j = list[e];
      Vec<D> d = xi - pos[j];
      float r2 = norm2(d);
      visit(j, d, r2);
      near = r2 < r2max;
    }
    const unsigned m = L.group_ballot(near);
    if (near) {
      const int at = kept + __popc(m & below);
      if (at < cap) out[at] = list[e];
    }
    kept += __popc(m);
  }
  return kept;
}
// the cell range of block slot k of g's walk (tag k / 3^D, then cell k % 3^D: x fastest
// around xi's cell c); empty outside the grid or past nslots
template <int D>
__device__ void block_range(const CellGridView<D>& g, const int* c, int k, int nslots, uint32_t& s, uint32_t& e) {
  constexpr int kBlock = D == 3 ? 27 : 9;
  if (k >= nslots) return;
  int o = k % kBlock, cc[D];
  for (int a = 0; a < D; ++a) {
    cc[a] = c[a] + o % 3 - 1;
    o /= 3;
    if (cc[a] < 0 || cc[a] >= g.spec.dims[a]) return;
  }
  const uint64_t slot = uint64_t(g.tag_begin + k / kBlock) * g.spec.ncells + g.spec.linear(cc);
  s = g.cell_start[slot];
  e = g.cell_end[slot];
}

// for_each_in_cells's lanes: the lanes load the ranges of W block cells at once (lane l: cell
// k0 + l), then walk those cells with the ranges broadcast by shuffles, each lane taking every
// W-th candidate of a cell; hits are listed in the serial walk's order by a ballot (the cells
// the serial walk culls hold no slot within reach: the same hits, in the same order)
template <int W, int D, class Visitor>
__device__ int for_each_in_cells(const SubWarpLanes<W>& L, const CellGridView<D>& g, const Vec<D>& xi, Visitor& visit,
                                 int* list, int cap) {
  constexpr int kBlock = D == 3 ? 27 : 9;
  const int nslots = kBlock * (g.tag_end - g.tag_begin);
  int c[D];
  g.spec.cell_of(xi, c);
  const unsigned below = (1u << L.lane()) - 1u;
  int count = 0;
  for (int k0 = 0; k0 < nslots; k0 += W) {
    uint32_t sl = 0, el = 0;  // the range of block cell k0 + lane
    block_range(g, c, k0 + L.lane(), nslots, sl, el);
    const int kn = nslots - k0 < W ? nslots - k0 : W;
    for (int q = 0; q < kn; ++q) {
      const uint32_t s = __shfl_sync(L.mask(), sl, q, W), e = __shfl_sync(L.mask(), el, q, W);
      for (uint32_t b = s; b < e; b += uint32_t(W)) {
        const uint32_t j = b + uint32_t(L.lane());
        Vec<D> d = Vec<D>::zero();
        float r2 = 0.0f;
        bool hit = false;
        if (j < e) {
          d = xi - g.pos[j];
          r2 = norm2(d);
          hit = r2 < g.r2;
        }
        const unsigned m = L.group_ballot(hit);
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
#endif

}  // namespace cps
