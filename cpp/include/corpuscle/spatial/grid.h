// Uniform cell grid keyed in Morton order, and its neighbour query.
//
// Particles are sorted by key each step and the arrays physically reordered. A key holds
// the Morton code of the particle's cell plus a layer tag above it (layer 0: fluid,
// layer 1: ghost), so each layer stays contiguous and sorted by cell; unused slots carry
// kSentinel and sort last. Cell ranges are kept per (layer, cell).
//
// The query x visitor protocol: `for_each_neighbor(grid, xi, visitor)` calls
// `visitor(j, xi - xj, r2)` for every particle j of the requested layers within the support
// radius. Other indexes (all-pairs, neighbour lists, LBVH) implement the same call so the
// physics visitors never change.
#pragma once
#include "corpuscle/core/lanes.h"
#include "corpuscle/core/vec.h"
#include "corpuscle/spatial/morton.h"

namespace cps {

template <int D>
struct GridSpec {
  Vec<D> origin;   // lower corner of cell (0, ..., 0)
  float cell;      // cell edge, >= support radius
  float inv_cell;  // 1 / cell
  int bits;        // Morton bits per axis; dims = 1 << bits per axis
  int dims;        // cells per axis (power of two)
  uint32_t ncells; // dims^D: cells of one layer
  float h2;        // squared support radius used to cull candidates

  CPS_HD uint32_t layer_bit() const { return uint32_t(1) << (D * bits); }
  CPS_HD uint32_t sentinel() const { return uint32_t(2) << (D * bits); }
  // number of key bits the sort must look at
  CPS_HD int key_bits() const { return D * bits + 2; }

  // integer cell of a position, clamped into the grid
  CPS_HD void cell_of(const Vec<D>& x, int* c) const {
    for (int k = 0; k < D; ++k) {
      float f = (x[k] - origin[k]) * inv_cell;
      int ci = finite(f) ? int(f >= 0.0f ? f : -1.0f) : 0;
      c[k] = iclamp(ci, 0, dims - 1);
    }
  }
  CPS_HD uint32_t key(const Vec<D>& x, int layer) const {
    int c[D];
    cell_of(x, c);
    return morton_encode<D>(c) | (layer ? layer_bit() : 0u);
  }
};

// build a grid covering [lo, hi] with cells of at least `support`, one spare cell each side
template <int D>
inline GridSpec<D> make_grid(const Vec<D>& lo, const Vec<D>& hi, float support) {
  GridSpec<D> g;
  g.cell = support;
  g.inv_cell = 1.0f / support;
  int need = 1;
  for (int k = 0; k < D; ++k) {
    int n = int((hi[k] - lo[k]) / support) + 3;
    need = need > n ? need : n;
  }
  g.bits = 0;
  while ((1 << g.bits) < need) ++g.bits;
  g.dims = 1 << g.bits;
  g.ncells = 1;
  for (int k = 0; k < D; ++k) g.ncells *= uint32_t(g.dims);
  for (int k = 0; k < D; ++k) g.origin[k] = lo[k] - support;
  g.h2 = support * support;
  return g;
}

// read-only view of the sorted particles and the cell table, passed by value to functors
template <int D>
struct GridView {
  GridSpec<D> spec;
  const Vec<D>* pos;          // sorted positions
  const uint32_t* cell_start; // 2 * ncells entries: layer 0 then layer 1
  const uint32_t* cell_end;
};

// cells in the 3^D stencil around a cell
template <int D>
constexpr int kStencil = D == 3 ? 27 : 9;

// the slot of stencil entry o (x fastest) around cell c in the layer's table, or false when
// that cell lies outside the grid
template <int D>
CPS_HD CPS_INLINE bool stencil_slot(const GridSpec<D>& g, const int* c, int o, int layer, uint32_t& slot) {
  int cc[D];
  bool inside = true;
  for (int k = 0; k < D; ++k) {
    cc[k] = c[k] + (o % 3) - 1;
    o /= 3;
    inside = inside && cc[k] >= 0 && cc[k] < g.dims;
  }
  slot = morton_encode<D>(cc) + uint32_t(layer) * g.ncells;
  return inside;
}

// visit every particle of the chosen layers within the support radius of xi (one thread;
// for_each_neighbor_listing below has the cooperative form a warp uses)
template <int D, class Visitor>
CPS_HD CPS_INLINE void for_each_neighbor(const GridView<D>& g, const Vec<D>& xi, bool ghosts, Visitor& visit) {
  int c[D];
  g.spec.cell_of(xi, c);
  const int nlayers = ghosts ? 2 : 1;
  for (int o = 0; o < kStencil<D>; ++o) {
    for (int layer = 0; layer < nlayers; ++layer) {
      uint32_t slot;
      if (!stencil_slot(g.spec, c, o, layer, slot)) break;
      uint32_t end = g.cell_end[slot];
      for (uint32_t j = g.cell_start[slot]; j < end; ++j) {
        Vec<D> d = xi - g.pos[j];
        float r2 = norm2(d);
        if (r2 < g.spec.h2) visit(int(j), d, r2);
      }
    }
  }
}

// record cell ranges of sorted key j (one thread per sorted slot; tables zeroed beforehand)
template <int D>
CPS_HD CPS_INLINE void mark_cell_range(const GridSpec<D>& g, const uint32_t* keys, int j, int n, uint32_t* start,
                                       uint32_t* end) {
  uint32_t k = keys[j];
  if (k >= g.sentinel()) return;
  // key without the layer tag plus layer offset = slot in the table
  uint32_t slot = (k & (g.layer_bit() - 1u)) + ((k & g.layer_bit()) ? g.ncells : 0u);
  if (j == 0 || keys[j - 1] != k) start[slot] = uint32_t(j);
  if (j == n - 1 || keys[j + 1] != k) end[slot] = uint32_t(j + 1);
}

// the cell walk by lanes (core/lanes.h): every particle of the chosen layers within the
// support radius of xi, visited and listed (up to cap; returns how many there were)
// the plain cell-by-cell neighbour loop, listing the neighbours (up to cap; returns how
// many there were)
template <int D, class Visitor>
CPS_HD int for_each_neighbor_listing(const SingleLane&, const GridView<D>& g, const Vec<D>& xi, bool ghosts, Visitor& visit,
                                     int* list, int cap) {
  int count = 0;
  auto listing = [&](int j, const Vec<D>& d, float r2) {
    if (count < cap) list[count] = j;
    ++count;
    visit(j, d, r2);
  };
  cps::for_each_neighbor(g, xi, ghosts, listing);
  return count;
}

#ifdef __CUDACC__
// cell range of stencil slot k (layer k / stencil, offset k % stencil), empty outside the grid
template <int D>
__device__ void load_range(const GridView<D>& g, const int* c, int k, int nslots, uint32_t& s, uint32_t& e) {
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
template <int W, int D, class Visitor>
__device__ int for_each_neighbor_listing(const SubWarpLanes<W>& L, const GridView<D>& g, const Vec<D>& xi, bool ghosts, Visitor& visit,
                                         int* list, int cap) {
  const int nslots = kStencil<D> * (ghosts ? 2 : 1);
  int c[D];
  g.spec.cell_of(xi, c);
  const unsigned below = (1u << L.lane()) - 1u;
  int count = 0;
  for (int k0 = 0; k0 < nslots; k0 += W) {
    uint32_t sl = 0, el = 0;  // the range of stencil cell k0 + lane
    load_range(g, c, k0 + L.lane(), nslots, sl, el);
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
          hit = r2 < g.spec.h2;
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
