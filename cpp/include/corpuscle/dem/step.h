// The DEM module's pipeline glue: the index plug-ins (grid, LBVH, all pairs), the broad-phase
// grid's spec, and the two parts of a step every DEM pipeline enqueues the same way: the
// sort and reorder (and the index built on the sorted positions), then the contacts with the
// step's sums and the per-scene finalize. A DEM kind's Pipeline owns the buffers, the index
// (CellGrid<D, Exec> and Lbvh<D, Exec>) and its record, and calls these from its enqueue
// (scenes/wind_tunnel/pipeline.h is one; docs/architecture.md, "A new DEM kind, worked
// example"). Stage marks: 0 keys and sort, 1 reorder, 2 build, 3 contacts, 4 sums and finalize.
#pragma once
#include <cmath>
#include <type_traits>

#include "corpuscle/dem/stages.h"

namespace cps::dem {

struct GridIndex {
  static constexpr const char* name = index_name::grid;
  static constexpr bool kGrid = true;
};
// every particle against every other (O(N^2)): the reference the grid is tested against
struct AllPairsIndex {
  static constexpr const char* name = index_name::allpairs;
  static constexpr bool kGrid = false;
};
// the seed's Karras LBVH over Morton codes (spatial/lbvh.h), gather form
struct LbvhIndex {
  static constexpr const char* name = index_name::lbvh;
  static constexpr bool kGrid = false;
};
template <class Index>
constexpr bool kIsTree = std::is_same_v<Index, LbvhIndex>;

// cells of at least one contact diameter (larger cells: fewer of them, more candidates each)
template <int D>
inline CellGridSpec<D> grid_spec(const SoftSpheres<D>& m) {
  return make_cell_grid<D>(m.lo, m.hi, std::fmax(2.0f * m.radius, m.cell));
}
// the tree's query reach: a contact diameter and a rounding margin
template <int D>
inline float tree_reach(const SoftSpheres<D>& m) {
  return 2.0f * m.radius * (1.0f + 1e-6f);
}

// combines two sums items (the kind's Sums::combine)
template <class Sums>
struct CombineSums {
  CPS_HD Sums operator()(const Sums& a, const Sums& b) const { return Sums::combine(a, b); }
};

// Step part 1: key and sort the current positions (a.position), gather the kind's arrays
// (A: dem::Arrays<D> or the kind's, derived from it) into the index's order in the other
// buffers (a.position_alt ...: every field of its table that moves with the sphere), build the
// index on them (cell ranges, or the tree's nodes and boxes). A collisionless gas needs no
// index and the all-pairs reference no order: the arrays are copied as they are.
template <class Index, int D, class Exec, class A>
void sort_and_reorder(Exec& ex, const SoftSpheres<D>& m, CellGrid<D, Exec>& grid, Lbvh<D, Exec>& tree, const A& a) {
  const int n = m.n;
  if (m.collide && kIsTree<Index>) {
    tree.sort(ex, a.position, n);
    ex.mark(0);
    ex.for_each(n, ReorderStage<A>{tree.order(), a});
    ex.mark(1);
    tree.build(ex, a.position_alt);
  } else if (m.collide && Index::kGrid) {
    grid.sort(ex, a.position, nullptr, n);
    ex.mark(0);
    ex.for_each(n, ReorderStage<A>{grid.order(), a});
    ex.mark(1);
    grid.mark(ex);
  } else {
    ex.mark(0);
    ex.for_each(n, ReorderStage<A>{nullptr, a});
    ex.mark(1);
  }
  ex.mark(2);
}

// Step parts 2 and 3, on the sorted arrays s: the contacts by gather (or, reflexive, each pair
// once with atomics, then the rest), the kind's walls and bodies (`boundary`, the force hook),
// and the step's sums reduced into the record's pending (integrate) or sums (an evaluation)
// with the per-scene finalize (`finalize`, the finalize hook; integrate only): fused into the
// contact pass (Exec::for_each_reduce_then) but for the tree, whose walks need shared memory
// (the items are stored in `items` and reduced after). m: the host's model, md: the backend's.
// the fused contact pass's blocks of 256 threads per multiprocessor on CUDA (launch bounds):
// left to itself the compiler keeps the wind tunnel's pass at 64 registers and spills 128 bytes
// a thread; 3 blocks leave it 80 registers and no spills (sm_90, nvcc 13)
constexpr int kContactBlocksPerSM = 3;

template <class Index, int D, class Exec, class Record, class Sums, class Boundary, class Finalize>
void contacts_and_sums(Exec& ex, const SoftSpheres<D>& m, const SoftSpheres<D>* md, Record* g, const Arrays<D>& s,
                       Sums* items, CellGrid<D, Exec>& grid, Lbvh<D, Exec>& tree, const Boundary& boundary,
                       const Finalize& finalize, bool integrate) {
  const int n = m.n;
  constexpr bool kTree = kIsTree<Index>;
  auto contacts = [&](const auto& view) {
    using V = std::decay_t<decltype(view)>;
    // the tree's walks keep their stacks in shared memory on the device (spatial/lbvh.h)
    auto walking = [&](const auto& f) {
      if constexpr (kTree) ex.for_each_shared(n, f, lbvh_stack_bytes(m.lbvh_stack));
      else ex.for_each(n, f);
    };
    if (m.collide && m.reflexive) {
      ex.for_each(n, ZeroContactsStage<D>{s});
      walking(PairStage<D, V, Record>{md, g, s, view});
    }
    using Force = ForceStage<D, V, Record, Sums, Boundary>;
    const Force force{md, g, s, items, view, grid.spec(), boundary};
    const FinalizeStage<D, Record, Finalize> fin{md, g, finalize};
    if constexpr (kTree) {
      walking(force);
      ex.mark(3);
      if (integrate) ex.reduce_then(items, n, &g->pending, CombineSums<Sums>{}, Sums::identity(), fin);
      else ex.reduce(items, n, &g->sums, CombineSums<Sums>{}, Sums::identity());
    } else {
      // the forces and the step's sums in one pass: the sums items are never stored
      if (integrate)
        ex.template for_each_reduce_then<kContactBlocksPerSM>(n, EvalOf<Force>{force}, &g->pending,
                                                              CombineSums<Sums>{}, Sums::identity(), fin);
      else
        ex.template for_each_reduce_then<kContactBlocksPerSM>(n, EvalOf<Force>{force}, &g->sums,
                                                              CombineSums<Sums>{}, Sums::identity(), NoFinalize{});
      ex.mark(3);
    }
    ex.mark(4);
  };
  if constexpr (Index::kGrid) {
    contacts(grid.view(s.position).with_radius(2.0f * m.radius));  // the contact reach, whatever the cell
  } else if constexpr (kTree) {
    contacts(tree.view(s.position, &g->clock.bad, kBadTraversal, m.lbvh_stack));
  } else {
    const float reach = 2.0f * m.radius;
    contacts(AllPairsView<D>{s.position, n, reach * reach * (1.0f + 4e-6f)});
  }
}

}  // namespace cps::dem
