// The DEM module's contact search helpers over the index views (CellGridView, LbvhView,
// AllPairsView): the views widened around a periodic image, the number density (the particles
// in the 3^D cells around a particle's cell), the tree's one walk for contacts and density, and
// the reaction of the reflexive form (atomics, warp-aggregated on the device).
#pragma once
#include "corpuscle/core/atomics.h"
#include "corpuscle/dem/model.h"
#include "corpuscle/spatial/allpairs.h"
#include "corpuscle/spatial/cell_grid.h"
#include "corpuscle/spatial/lbvh.h"

namespace cps::dem {

// the index view searched around an image point: its reach widened by a rounding margin (the
// pair law decides on the exact displacement, image_displacement, so the search must not miss
// a pair that the law sees touching)
template <int D>
CPS_HD CPS_INLINE CellGridView<D> widened(const CellGridView<D>& v, float reach) {
  return v.with_radius(reach);
}
template <int D>
CPS_HD CPS_INLINE AllPairsView<D> widened(const AllPairsView<D>& v, float reach) {
  return v.with_radius(reach);
}
template <int D>
CPS_HD CPS_INLINE LbvhView<D> widened(const LbvhView<D>& v, float reach) {
  LbvhView<D> w = v;
  w.radius = reach > v.radius ? reach : v.radius;
  return w;
}

// the number density around x: the particles in the 3^D cells of `spec` around x's cell,
// itself excluded, over the block's area (D = 3: volume; cells inside the grid: at the ends
// of a periodic span the block is cut there, an unbiased estimate all the same); from the
// cell ranges on the grid, by testing every particle's cell with the all-pairs index (the
// same count)
template <int D>
CPS_HD CPS_INLINE float block_measure(const CellGridSpec<D>& spec, int cells) {
  float a = float(cells) * spec.cell * spec.cell;
  if constexpr (D == 3) a *= spec.cell;
  return a;
}
// is cell cj one of the 3^D around c?
template <int D>
CPS_HD CPS_INLINE bool in_block(const int* c, const int* cj) {
  bool in = true;
  for (int k = 0; k < D; ++k) in = in && cj[k] - c[k] >= -1 && cj[k] - c[k] <= 1;
  return in;
}
// how many of the 3^D cells around c lie inside the grid
template <int D>
CPS_HD CPS_INLINE int block_cells(const CellGridSpec<D>& spec, const int* c) {
  int cells = 1;
  for (int k = 0; k < D; ++k) {
    int along = 0;
    for (int q = c[k] - 1; q <= c[k] + 1; ++q) along += (q >= 0 && q < spec.dims[k]) ? 1 : 0;
    cells *= along;
  }
  return cells;
}
template <int D>
CPS_HD CPS_INLINE float block_density(const CellGridView<D>& grid, const CellGridSpec<D>&, const Vec<D>& x) {
  int count, cells;
  grid.block_count(x, count, cells);
  return float(count - 1) / block_measure(grid.spec, cells);
}
template <int D>
CPS_HD CPS_INLINE float block_density(const AllPairsView<D>& all, const CellGridSpec<D>& spec, const Vec<D>& x) {
  int c[D], cj[D];
  spec.cell_of(x, c);
  int count = 0;
  for (int j = 0; j < all.n; ++j) {
    spec.cell_of(all.pos[j], cj);
    count += in_block<D>(c, cj) ? 1 : 0;
  }
  return float(count - 1) / block_measure(spec, block_cells(spec, c));
}

// the tree: one box query of the 3^D cells (a little wider), each slot found counted when its
// cell is in the block. With a visitor (the contact gather), the same walk also visits every
// slot of the contact reach: the query box is the union of the block's and the reach's (the
// block holds the reach unless x lies outside the grid), a slot is a contact candidate when
// it lies in the reach's box (as in gather), and the walk meets those slots in the order
// gather would (the tree's order does not depend on the box): one walk instead of two, the
// same contacts summed in the same order
template <int D, class Visit>
CPS_HD CPS_INLINE float tree_block_density(const LbvhView<D>& tree, const CellGridSpec<D>& spec, const Vec<D>& x,
                                           Visit* contact) {
  int c[D], cj[D];
  spec.cell_of(x, c);
  float qlo[D], qhi[D], rlo[D], rhi[D];
  for (int k = 0; k < D; ++k) {
    qlo[k] = spec.origin[k] + float(c[k] - 1) * spec.cell - 1e-3f * spec.cell;
    qhi[k] = spec.origin[k] + float(c[k] + 2) * spec.cell + 1e-3f * spec.cell;
    rlo[k] = x[k] - tree.radius;
    rhi[k] = x[k] + tree.radius;
    if (contact) {
      qlo[k] = fmin2(qlo[k], rlo[k]);
      qhi[k] = fmax2(qhi[k], rhi[k]);
    }
  }
  const float r2 = tree.radius * tree.radius;
  int count = 0;
  tree.query_box(qlo, qhi, [&](int j) {
    const Vec<D> pj = tree.pos[j];
    if (contact) {
      bool in = true;
      for (int k = 0; k < D; ++k) in = in && pj[k] >= rlo[k] && pj[k] <= rhi[k];
      if (in) {
        const Vec<D> d = x - pj;
        const float rr = norm2(d);
        if (rr < r2) (*contact)(j, d, rr);
      }
    }
    spec.cell_of(pj, cj);
    count += in_block<D>(c, cj) ? 1 : 0;
  });
  return float(count - 1) / block_measure(spec, block_cells(spec, c));
}
template <int D>
struct NoContactVisit {
  CPS_HD void operator()(int, const Vec<D>&, float) const {}
};
template <int D>
CPS_HD CPS_INLINE float block_density(const LbvhView<D>& tree, const CellGridSpec<D>& spec, const Vec<D>& x) {
  return tree_block_density(tree, spec, x, static_cast<NoContactVisit<D>*>(nullptr));
}

// the contacts by gather (visit(j, x - x_j, r2) for every slot of the contact reach, i
// included) and the number density around x: the index's gather, then its block count; the
// tree does both in one walk (tree_block_density)
template <int D, class View, class Visit>
CPS_HD CPS_INLINE float gather_and_density(const View& view, const CellGridSpec<D>& spec, int i, const Vec<D>& x,
                                           Visit& visit) {
  view.gather(i, x, visit);
  return block_density(view, spec, x);
}
template <int D, class Visit>
CPS_HD CPS_INLINE float gather_and_density(const LbvhView<D>& tree, const CellGridSpec<D>& spec, int, const Vec<D>& x,
                                           Visit& visit) {
  return tree_block_density(tree, spec, x, &visit);
}

// the reaction f, its magnitude and one contact added to particle j. Warp-aggregated
// (the seed's option, on the device): the lanes of a warp adding to the same j at this moment
// (__match_any_sync over j) sum their values by shuffles and one of them adds the sum, so a
// particle hit by several lanes takes one atomic per component instead of one per lane. On the
// CPU, and with aggregate off, one atomic each.
template <int D>
CPS_HD CPS_INLINE void add_reaction(const Arrays<D>& s, int j, const Vec<D>& f, float mag, bool aggregate) {
#ifdef __CUDA_ARCH__
  if (aggregate) {
    const unsigned active = __activemask();
    const unsigned peers = __match_any_sync(active, j);
    const int lane = int(threadIdx.x & 31u);
    float sf[D], sm = 0.0f;
    for (int k = 0; k < D; ++k) sf[k] = 0.0f;
    unsigned rest = peers;
    while (rest) {  // every peer runs the same loop: the shuffles see the whole group
      const int src = __ffs(int(rest)) - 1;
      rest &= rest - 1u;
      for (int k = 0; k < D; ++k) sf[k] += __shfl_sync(peers, f[k], src);
      sm += __shfl_sync(peers, mag, src);
    }
    if (lane == __ffs(int(peers)) - 1) {
      for (int k = 0; k < D; ++k) atomicAdd(&s.force[j][k], sf[k]);
      atomicAdd(&s.pressure[j], sm);
      atomicAdd(&s.contacts[j], __popc(peers));
    }
    return;
  }
#endif
  (void)aggregate;
  for (int k = 0; k < D; ++k) atomic_add(&s.force[j][k], f[k]);
  atomic_add(&s.pressure[j], mag);
  atomic_add(&s.contacts[j], 1);
}

}  // namespace cps::dem
