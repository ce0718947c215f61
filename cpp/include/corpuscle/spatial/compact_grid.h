// The compact grid (seed 002's "compact z-index grid"): the cells of a CellGrid split into
// chunks of at most K particles (K = 32: a warp), so one CUDA block of K threads works on one
// chunk. The chunk's particles share a cell, hence its neighbour cells: the block walks those
// cells once, loading their particles into shared memory in batches of K (one per thread) that
// every thread of the block then scans. On the CPU the same chunks run as blocked loops
// (CpuTile: the lanes of a chunk one after another).
//
// Build (after the grid's sort and mark): flag every sorted slot that starts a chunk (the first
// slot of its cell, or K slots after the previous chunk start), then compact the flags
// (Exec::select_flagged) into the ascending list of chunk starts; the count stays in device
// memory. The tiled gather is launched over an upper bound of the chunks (cells that can be
// non-empty + n / K), so nothing is read back and the step can be captured in a graph; a tile
// past the count leaves at once.
//
// Each particle visits the same cells, tags and slots in the same order as CellGridView's
// gather (tags, then z, y, x from low to high, then slots), so a begin / visit / end stage
// gives bit-identical results through either index.
#pragma once
#include "corpuscle/spatial/cell_grid.h"

namespace cps {

// flag sorted slot j when it starts a chunk of at most K slots of one cell
template <int D, int K>
struct ChunkFlagFn {
  CellGridView<D> grid;
  int* flags;
  CPS_HD void operator()(int j) const {
    if (!grid.active(j)) {
      flags[j] = 0;
      return;
    }
    const uint32_t s = grid.cell_start[grid.spec.slot_of_key(grid.key(j))];
    flags[j] = (uint32_t(j) - s) % uint32_t(K) == 0u ? 1 : 0;
  }
};

template <int D, int K>
struct CompactGridView {
  static constexpr int kDim = D;
  static constexpr int kChunk = K;
  CellGridView<D> grid;
  const int* chunk_start = nullptr;  // ascending sorted slots
  const int* nchunks = nullptr;      // the count (device memory on CUDA)
  int max_chunks = 0;                // the launch's upper bound
  // chunks of a tag >= split gather from tags [tag_begin, split) only (-1: every chunk from
  // every tag): the SPH walls need the fluid's particles, not each other's
  int split = -1;

  // the chunk's slots [s, e) (c < *nchunks)
  CPS_HD void chunk(int c, int& s, int& e) const {
    s = chunk_start[c];
    const uint32_t ce = grid.cell_end[grid.spec.slot_of_key(grid.key(s))];
    e = int(ce) < s + K ? int(ce) : s + K;
  }
};

// the tiled gather over chunks: lane l of chunk c owns slot s + l
template <int D, int K, class Stage>
struct CompactTiledGatherFn {
  CompactGridView<D, K> view;
  Stage stage;

  template <class Tile>
  CPS_HD void operator()(int c, Tile& t) const {
    static_assert(Tile::kSize == K, "one lane per slot of a chunk");
    if (c >= *view.nchunks) return;  // uniform over the tile
    const CellGridView<D>& g = view.grid;
    int s0, e0;
    view.chunk(c, s0, e0);
    const int m0 = e0 - s0;
    Vec<D>* sh = t.template shared<Vec<D>>(K);
    typename Tile::template PerLane<typename Stage::Acc> acc;
    typename Tile::template PerLane<Vec<D>> xi;
    t.lanes([&](int l) {
      if (l < m0) {
        xi[l] = g.pos[s0 + l];
        acc[l] = stage.begin(s0 + l);
      }
    });
    // the cells around the chunk's cell (that of each of its particles; the grid's block, in
    // its order, wrapping across periodic faces)
    int t1 = g.tag_end;
    if (view.split >= 0 && g.spec.tag_of_key(g.key(s0)) >= view.split) t1 = view.split < t1 ? view.split : t1;
    g.template block_rows<false>(g.pos[s0], g.tag_begin, t1, [&](uint64_t row, int x0, int x1, int) {
      for (int x = x0; x <= x1; ++x) {
        const uint64_t slot = row + uint64_t(x);
        const int s = int(g.cell_start[slot]), e = int(g.cell_end[slot]);
        // the cell's particles in batches of K through shared memory
        for (int base = s; base < e; base += K) {
          const int m = e - base < K ? e - base : K;
          t.lanes([&](int l) {
            if (l < m) sh[l] = g.pos[base + l];
          });
          t.sync();
          t.lanes([&](int l) {
            if (l >= m0) return;
            for (int k = 0; k < m; ++k) {
              Vec<D> d = g.spec.per.displacement(xi[l] - sh[k]);
              float rr = norm2(d);
              if (rr < g.r2) stage.visit(acc[l], s0 + l, base + k, d, rr);
            }
          });
          t.sync();
        }
      }
    });
    t.lanes([&](int l) {
      if (l < m0) stage.end(s0 + l, acc[l]);
    });
  }
};

// the host side: the chunk starts of a grid's sorted slots
template <int D, class Exec, int K = 32>
class CompactGrid {
 public:
  template <class T>
  using Buffer = typename Exec::template Buffer<T>;

  // chunk the cells of `grid` (its sort and mark done); table_cells bounds the non-empty cells
  void build(Exec& ex, const CellGridView<D>& grid) {
    const int n = grid.n;
    if (flags_.size() < size_t(n) || flags_.size() == 0) {
      ex.resize(flags_, size_t(n > 0 ? n : 1));
      ex.resize(starts_, size_t(n > 0 ? n : 1));
    }
    if (count_.size() == 0) ex.resize(count_, 1);
    ex.for_each(n, ChunkFlagFn<D, K>{grid, flags_.data()});
    ex.select_flagged(flags_.data(), n, starts_.data(), count_.data());
    const double cells = double(grid.spec.table_size());
    const double bound = (cells < double(n) ? cells : double(n)) + double(n) / K + 1.0;
    max_chunks_ = int(bound < double(n) ? bound : double(n > 0 ? n : 1));
    grid_ = grid;
  }
  CompactGridView<D, K> view(const CellGridView<D>& grid, int split = -1) const {
    CompactGridView<D, K> v;
    v.split = split;
    v.grid = grid;
    v.chunk_start = starts_.data();
    v.nchunks = count_.data();
    v.max_chunks = max_chunks_;
    return v;
  }
  int max_chunks() const { return max_chunks_; }
  const int* chunk_starts() const { return starts_.data(); }
  const int* count() const { return count_.data(); }

 private:
  Buffer<int> flags_, starts_, count_;
  int max_chunks_ = 0;
  CellGridView<D> grid_{};
};

// run a begin / visit / end stage over the chunks (a CUDA block of K threads each)
template <class Exec, int D, int K, class Stage>
void gather_stage_compact(Exec& ex, const CompactGridView<D, K>& view, const Stage& stage) {
  ex.template for_each_tile<K>(view.max_chunks, CompactTiledGatherFn<D, K, Stage>{view, stage}, sizeof(Vec<D>) * K);
}

}  // namespace cps
