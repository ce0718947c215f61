// A uniform cell grid with per-axis extents, keyed in 64-bit Morton order or in rows.
//
// Cells have an edge of at least the query radius; each axis has as many cells as the
// domain needs (a 4 x 1 x 1 m tank at 1 cm cells: 400 x 100 x 100 cells), so memory follows
// the domain. Particles are sorted by a 64-bit key
//
//     key = (tag << (D * bits)) | morton(cell),     bits = Morton bits for the longest axis
//
// or, in rows (CellOrder::Rows), key = (tag << cell_bits) | linear(cell) with x fastest and
// cell_bits the bits of the largest linear index: the three cells x - 1, x, x + 1 of a row
// then hold consecutive sorted slots, so a walk reads a row of the 3^D block as one range (9
// ranges in 3-D instead of 27 cells, 3 in 2-D instead of 9; the same slots in the same order).
// Every tag (a layer: fluid / ghosts, or a scene of a batch) stays contiguous and sorted
// by cell inside; unused slots (tag outside [0, ntags)) get kSentinel and sort last. The
// cell table is indexed by tag * ncells + linear cell index (x fastest), not by the Morton
// code, so it holds exactly ntags * dims[0] * ... * dims[D-1] ranges. Positions outside the
// domain (and NaN) clamp into the border cells: they are still found, the distance check
// decides. Cell counts and table offsets are 64-bit; particle slots are int.
//
// Two particles closer than the radius must never land two cells apart, whatever their
// coordinates: the cell of a position is computed in double (exact difference, one
// rounding, so the error does not grow with the coordinate), and the cell edge is the
// radius plus 1e-6 of it, which covers the float rounding of the distance check itself.
//
// Keys of at most 32 bits (a grid of up to 2^32 / 2^tag_bits cells: 2M cells of one tag need
// 23) are sorted as 32-bit words: the radix sort moves a third less memory per pass than with
// 64-bit keys (the wind tunnel's sort at 2M particles is a third of its step). The view reads
// either width through key(); the 32-bit sentinel is all ones, as the 64-bit one.
//
// Periodic axes (make_cell_grid's `periodic` mask, spatial/periodic.h): the domain's extent
// along such an axis is the period; it holds floor(extent / cell) >= 3 cells (the last one
// takes the remainder, so it may be up to twice as wide: a neighbour within the radius is
// still at most one cell away), the block around a cell wraps across the periodic faces (3
// distinct cells, so nothing is visited twice), a row that wraps is read as two ranges, and
// the walk's displacement is the minimum image. Positions must lie inside the period (the
// stage that moves them wraps them: Periodic::wrap).
//
// Build: sort (keys, stable sort; order() maps sorted slot -> input slot), reorder (the
// caller's arrays, or the grid's own copy of the positions), mark (cell ranges from the
// sorted keys). The view (CellGridView) follows the protocol of spatial/index.h; its slot
// numbers are sorted slots.
#pragma once
#include <cmath>
#include <cstddef>
#include <cstdio>
#include <string>
#include <vector>

#include "corpuscle/core/error.h"
#include "corpuscle/spatial/index.h"
#include "corpuscle/spatial/morton.h"
#include "corpuscle/spatial/periodic.h"

namespace cps {

// the default limit on a grid's cell table (ntags * cells): 2^31 ranges, 16 GiB of table
constexpr uint64_t kCellGridMaxCells = uint64_t(1) << 31;

// a count for messages (exact below 2^53, which is all a message needs)
inline std::string cell_count_text(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, v < 1e15 ? "%.0f" : "%.3g", v);
  return buf;
}

// the order of the cells in the sort: Morton (z-order), or rows (the linear index, x fastest)
enum class CellOrder { Morton, Rows };

template <int D>
struct CellGridSpec {
  static constexpr uint64_t kSentinel = ~uint64_t(0);

  Vec<D> origin;      // lower corner of cell (0, ..., 0) = the domain's lower corner
  float cell = 0.0f;      // cell edge: the radius plus a rounding margin
  double inv_cell = 0.0;  // 1 / cell
  float radius = 0.0f;   // the largest query radius the grid answers
  int dims[D] = {};      // cells per axis
  uint64_t ncells = 0;   // dims[0] * ... * dims[D-1]: the cells of one tag
  int bits = 0;          // Morton bits per axis
  bool rows = false;     // CellOrder::Rows: the key's cell part is the linear index
  int cell_bits = 0;     // the key's bits below the tag (Morton: D * bits)
  int ntags = 1;         // tags 0 .. ntags-1
  int key_bits = 0;      // key bits the sort looks at
  Periodic<D> per;       // the periodic axes (mask 0: none)

  CPS_HD int tag_shift() const { return cell_bits; }
  // the keys fit a 32-bit word (and the 32-bit sentinel, all ones, stays above every real key)
  CPS_HD bool narrow() const { return key_bits <= 32; }
  CPS_HD uint64_t table_size() const { return uint64_t(ntags) * ncells; }

  // integer cell of a position, clamped into the grid (NaN: cell 0)
  CPS_HD void cell_of(const Vec<D>& x, int* c) const {
    for (int k = 0; k < D; ++k) {
      const double f = (double(x[k]) - double(origin[k])) * inv_cell;
      // compare before converting: no overflow for far-away (or infinite) positions, NaN fails both
      c[k] = f >= 0.0 ? (f < double(dims[k]) ? int(f) : dims[k] - 1) : 0;
    }
  }
  CPS_HD uint64_t linear(const int* c) const {
    uint64_t s = uint64_t(c[D - 1]);
    for (int k = D - 2; k >= 0; --k) s = s * uint64_t(dims[k]) + uint64_t(c[k]);
    return s;
  }
  CPS_HD uint64_t key(const Vec<D>& x, int tag) const {
    if (tag < 0 || tag >= ntags) return kSentinel;
    int c[D];
    cell_of(x, c);
    return (uint64_t(tag) << tag_shift()) | (rows ? linear(c) : morton_encode64<D>(c));
  }
  CPS_HD int tag_of_key(uint64_t k) const { return int(k >> tag_shift()); }
  // the cell table slot of a (non-sentinel) key
  CPS_HD uint64_t slot_of_key(uint64_t k) const {
    const int s = tag_shift();
    const uint64_t cell = s >= 64 ? k : (k & ((uint64_t(1) << s) - 1u));
    if (rows) return uint64_t(tag_of_key(k)) * ncells + cell;
    int c[D];
    morton_decode64<D>(cell, c);
    return uint64_t(tag_of_key(k)) * ncells + linear(c);
  }
};

// a grid over the domain [lo, hi] answering radii up to `radius`, for tags 0 .. ntags-1, its
// cells sorted in `order`; throws cps::Error for bad arguments or when the table would exceed
// max_cells ranges
template <int D>
inline CellGridSpec<D> make_cell_grid(const Vec<D>& lo, const Vec<D>& hi, float radius, int ntags = 1,
                                      uint64_t max_cells = kCellGridMaxCells, CellOrder order = CellOrder::Morton,
                                      unsigned periodic = 0u) {
  if (!(radius > 0.0f) || !finite(radius))
    throw Error("cell grid: the radius must be positive and finite, got " + std::to_string(radius));
  if (ntags < 1) throw Error("cell grid: needs at least one tag, got " + std::to_string(ntags));
  double extent[D];
  double longest = 1.0;
  for (int k = 0; k < D; ++k) {
    if (!finite(lo[k]) || !finite(hi[k]) || !(hi[k] >= lo[k]))
      throw Error("cell grid: the domain's upper corner must not lie below the lower one (axis " +
                  std::to_string(k) + ": " + std::to_string(lo[k]) + " .. " + std::to_string(hi[k]) + ")");
    extent[k] = double(hi[k]) - double(lo[k]);
    longest = std::fmax(longest, extent[k] / double(radius));
  }
  if (longest > double(int(1) << 30))
    throw Error("cell grid: an axis would need " + cell_count_text(longest) + " cells of " + std::to_string(radius) +
                " (more than 2^30)");
  CellGridSpec<D> g;
  g.radius = radius;
  g.ntags = ntags;
  // cell edge = radius * (1 + 1e-6), rounded up to a float (see the top of this file)
  const double want = double(radius) * (1.0 + 1e-6);
  float cell = float(want);
  while (double(cell) < want) cell = std::nextafter(cell, 2.0f * cell);
  g.cell = cell;
  g.inv_cell = 1.0 / double(cell);
  int widest = 1;
  uint64_t ncells = 1;
  for (int k = 0; k < D; ++k) {
    const double n = std::ceil(extent[k] / double(cell));
    g.dims[k] = n < 1.0 ? 1 : int(n);
    if ((periodic >> k) & 1u) {  // whole cells of at least `cell` tile the period
      const double whole = std::floor(extent[k] / double(cell));
      if (whole < 3.0)
        throw Error("cell grid: the periodic axis " + std::to_string(k) + " is " + std::to_string(extent[k]) +
                    " long, less than 3 cells of " + std::to_string(cell) + " (the period must hold three query radii)");
      g.dims[k] = int(whole);
    }
    widest = g.dims[k] > widest ? g.dims[k] : widest;
    g.origin[k] = lo[k];
  }
  std::string shape;
  double cells = 1.0;
  for (int k = 0; k < D; ++k) {
    cells *= double(g.dims[k]);
    shape += (k ? " x " : "") + std::to_string(g.dims[k]);
  }
  if (cells * double(ntags) > double(max_cells))
    throw Error("cell grid: " + shape + " cells of " + std::to_string(cell) + (ntags > 1 ? " for " + std::to_string(ntags) + " tags" : std::string()) +
                " would need " + cell_count_text(cells * double(ntags)) + " cell ranges, more than the limit of " +
                cell_count_text(double(max_cells)) + ": use a larger radius, a smaller domain or fewer tags");
  for (int k = 0; k < D; ++k) ncells *= uint64_t(g.dims[k]);
  g.ncells = ncells;
  g.bits = 0;
  while ((int64_t(1) << g.bits) < int64_t(widest)) ++g.bits;
  int tag_bits = 0;  // 2^tag_bits > ntags: every real key stays below the sentinel's low key_bits bits
  while ((int64_t(1) << tag_bits) <= int64_t(ntags)) ++tag_bits;
  g.per = Periodic<D>::make(periodic, lo, hi);
  g.rows = order == CellOrder::Rows;
  g.cell_bits = D * g.bits;
  if (g.rows) {
    g.cell_bits = 0;
    while ((uint64_t(1) << g.cell_bits) < ncells) ++g.cell_bits;
  }
  g.key_bits = g.cell_bits + tag_bits;
  if ((!g.rows && g.bits > morton_max_bits64<D>()) || g.key_bits > 64)
    throw Error("cell grid: " + shape + " cells with " + std::to_string(ntags) + " tags need " +
                std::to_string(g.key_bits) + " key bits, more than a 64-bit key holds: use a larger radius or fewer tags");
  return g;
}

// the sorted particles and the cell table, passed by value to functors
template <int D>
struct CellGridView {
  static constexpr int kDim = D;
  CellGridSpec<D> spec;
  const Vec<D>* pos = nullptr;           // positions in sorted order
  const uint64_t* keys = nullptr;        // sorted keys (kSentinel: unused slot), 64-bit ...
  const uint32_t* keys32 = nullptr;      // ... or 32-bit (spec.narrow(); all ones: unused)
  const uint32_t* cell_start = nullptr;  // spec.table_size() entries each
  const uint32_t* cell_end = nullptr;
  int n = 0;                             // slots
  float r2 = 0.0f;                       // squared query radius
  int tag_begin = 0, tag_end = 1;        // the tags gathered from ...
  bool own_tag = false;                  // ... or only the tag of slot i (scenes of a batch)

  CPS_HD int size() const { return n; }
  // the sorted key of slot i, whatever width it is stored in
  CPS_HD uint64_t key(int i) const {
    if (keys32) {
      const uint32_t k = keys32[i];
      return k == ~uint32_t(0) ? CellGridSpec<D>::kSentinel : uint64_t(k);
    }
    return keys[i];
  }
  // slot i holds a particle: its key's tag is one of the grid's (an unused slot's key is the
  // sentinel, or any key past the last tag)
  CPS_HD bool active(int i) const { return (key(i) >> spec.tag_shift()) < uint64_t(spec.ntags); }
  CPS_HD const Vec<D>& position(int i) const { return pos[i]; }
  CPS_HD float max_radius() const { return spec.radius; }
  CPS_HD CellGridView with_radius(float r) const {
    CellGridView v = *this;
    v.r2 = r * r;
    return v;
  }
  // gather from tags [a, b) only
  CPS_HD CellGridView tags(int a, int b) const {
    CellGridView v = *this;
    v.tag_begin = a < 0 ? 0 : a;
    v.tag_end = b > spec.ntags ? spec.ntags : b;
    v.own_tag = false;
    return v;
  }
  // gather for slot i from slot i's tag only (i must be an active slot)
  CPS_HD CellGridView own_tags() const {
    CellGridView v = *this;
    v.own_tag = true;
    return v;
  }

  template <class Visit>
  CPS_HD void gather(int i, const Vec<D>& xi, Visit&& visit) const {
    walk<false>(i, xi, visit);
  }
  template <class Visit>
  CPS_HD void pairs(int i, const Vec<D>& xi, Visit&& visit) const {
    walk<true>(i, xi, visit);
  }

  // the cell table slots of the 3^D cells around xi's cell for tags [t0, t1): tags in order,
  // then the cells (z, y, x, each from low to high; cells outside the grid skipped, so a grid
  // narrower than three cells visits no cell twice); f(slot, tag) for each
  template <class F>
  CPS_HD void for_each_block_slot(const Vec<D>& xi, int t0, int t1, F&& f) const {
    block_slots<false>(xi, t0, t1, f);
  }

  // the slots in the 3^D cells around xi's cell (in the grid) of tags [tag_begin, tag_end),
  // and how many cells that block has inside the grid: a particle's local number density
  // is (count - 1) / (cells * cell^D) (itself not counted: unbiased for a uniform gas)
  CPS_HD void block_count(const Vec<D>& xi, int& count, int& cells) const {
    count = 0;
    cells = 0;
    for_each_block_slot(xi, tag_begin, tag_end, [&](uint64_t slot, int t) {
      count += int(cell_end[slot] - cell_start[slot]);
      cells += t == tag_begin ? 1 : 0;
    });
  }

  // for_each_block_slot's cells less those that lie wholly beyond the query radius of xi: a
  // cell is left out when the distance from xi to its box (the gaps to the faces between them,
  // in double) exceeds sqrt(r2) by a margin (1e-5 of r2, far above the float rounding of the
  // distance check), so no slot it holds could pass that check; the walks visit the same
  // neighbours in the same order. (Cells of the radius: a 3-D walk reads about 20.6 of the 27
  // cells on average, 2-D 8.1 of 9.) A border cell also holds the positions beyond the domain
  // clamped into it, all on its far side from the face the gap is measured to; NaN culls nothing.
  template <class F>
  CPS_HD void for_each_near_slot(const Vec<D>& xi, int t0, int t1, F&& f) const {
    block_slots<true>(xi, t0, t1, f);
  }

  // the 3^D block's slots in for_each_block_slot's order, less (kCull) those beyond reach
  template <bool kCull, class F>
  CPS_HD void block_slots(const Vec<D>& xi, int t0, int t1, F& f) const {
    block_rows<kCull>(xi, t0, t1, [&](uint64_t row, int x0, int x1, int t) {
      for (int x = x0; x <= x1; ++x) f(row + uint64_t(x), t);
    });
  }

  // the block's rows in for_each_block_slot's order: f(row, x0, x1, t) for each row (z, y) of
  // tag t that keeps a cell, with the table slot of its cell x at row + x and the kept cells
  // x0 .. x1 (kCull: those within reach; the culled ones of a row are at its ends, since its
  // middle cell lies nearest xi)
  template <bool kCull, class F>
  CPS_HD void block_rows(const Vec<D>& xi, int t0, int t1, F&& f) const {
    int c[D];
    spec.cell_of(xi, c);
    // the block's cells per axis as offsets -1, 0, 1 from xi's cell: lo..hi (an offset past a
    // non-periodic border is left out; past a periodic one it wraps to the other end)
    int lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0}, at[3] = {0, 0, 0}, dim[3] = {1, 1, 1};
    bool wraps[3] = {false, false, false};
    float g2[3][3] = {{0.0f, 0.0f, 0.0f}, {0.0f, 0.0f, 0.0f}, {0.0f, 0.0f, 0.0f}};  // [axis][offset + 1]
    for (int k = 0; k < D; ++k) {
      wraps[k] = spec.per.on(k);
      dim[k] = spec.dims[k];
      lo[k] = wraps[k] || c[k] > 0 ? -1 : 0;
      hi[k] = wraps[k] || c[k] + 1 < spec.dims[k] ? 1 : 0;
      at[k] = c[k];
      if constexpr (kCull) {
        const double face = double(spec.origin[k]) + double(c[k]) * double(spec.cell);
        const double below = double(xi[k]) - face, above = face + double(spec.cell) - double(xi[k]);
        g2[k][0] = below > 0.0 ? float(below * below) : 0.0f;
        g2[k][2] = above > 0.0 ? float(above * above) : 0.0f;
      }
    }
    const float lim = r2 * (1.0f + 1e-5f);
    const uint64_t dx = uint64_t(spec.dims[0]);
    const uint64_t dxy = D == 3 ? dx * uint64_t(spec.dims[1]) : 0;
    for (int t = t0; t < t1; ++t) {
      const uint64_t tbase = uint64_t(t) * spec.ncells;
      for (int oz = lo[2]; oz <= hi[2]; ++oz) {
        const float gz = g2[2][oz + 1];
        int z = at[2] + oz;
        z = z < 0 ? z + dim[2] : (z >= dim[2] ? z - dim[2] : z);
        for (int oy = lo[1]; oy <= hi[1]; ++oy) {
          const float gzy = gz + g2[1][oy + 1];
          if (kCull && gzy > lim) continue;
          int y = at[1] + oy;
          y = y < 0 ? y + dim[1] : (y >= dim[1] ? y - dim[1] : y);
          int x0 = lo[0], x1 = hi[0];
          if (kCull && x0 < 0 && gzy + g2[0][0] > lim) x0 = 0;
          if (kCull && x1 > 0 && gzy + g2[0][2] > lim) x1 = 0;
          const uint64_t row = tbase + uint64_t(z) * dxy + uint64_t(y) * dx;
          const int a = at[0] + x0, b = at[0] + x1;
          if (wraps[0] && a < 0) {  // the row wraps below: the last cell, then from the first
            f(row, dim[0] - 1, dim[0] - 1, t);
            f(row, 0, b, t);
          } else if (wraps[0] && b >= dim[0]) {  // ... above: to the last cell, then the first
            f(row, a, dim[0] - 1, t);
            f(row, 0, 0, t);
          } else {
            f(row, a, b, t);
          }
        }
      }
    }
  }

  // the cell ranges [s, e) of sorted slots around xi's cell that may hold a slot within the
  // query radius (for_each_near_slot's cells, in for_each_block_slot's order), for tags
  // [tag_begin, tag_end) (own_tag: slot i's tag); f(s, e) for each: a cell's range, or (rows)
  // the range of a row's kept cells, which are consecutive in the sort (an empty cell's table
  // entry is 0, 0: the row ends at its cells' largest end and spans their sizes)
  template <class F>
  CPS_HD void for_each_cell_range(int i, const Vec<D>& xi, F&& f) const {
    int t0 = tag_begin, t1 = tag_end;
    if (own_tag) {
      t0 = spec.tag_of_key(key(i));
      t1 = t0 + 1;
    }
    if (spec.rows) {
      block_rows<true>(xi, t0, t1, [&](uint64_t row, int x0, int x1, int) {
        uint32_t e = 0, size = 0;
        for (int x = x0; x <= x1; ++x) {
          const uint32_t ce = cell_end[row + uint64_t(x)];
          size += ce - cell_start[row + uint64_t(x)];
          e = ce > e ? ce : e;
        }
        f(e - size, e);
      });
    } else {
      for_each_near_slot(xi, t0, t1, [&](uint64_t slot, int) { f(cell_start[slot], cell_end[slot]); });
    }
  }

  // the cells' slots in for_each_cell_range's order, each cell's in sorted order
  template <bool kPairs, class Visit>
  CPS_HD void walk(int i, const Vec<D>& xi, Visit& visit) const {
    for_each_cell_range(i, xi, [&](uint32_t s, const uint32_t e) {
      if (kPairs && s <= uint32_t(i)) s = uint32_t(i) + 1u;
      for (uint32_t j = s; j < e; ++j) {
        Vec<D> d = spec.per.displacement(xi - pos[j]);
        float rr = norm2(d);
        if (rr < r2) visit(int(j), d, rr);
      }
    });
  }
};

// ---- build stages (one thread per slot) ----

// (K: uint64_t, or uint32_t for narrow keys: the 64-bit key's low word, the sentinel all ones)
template <int D, class K>
struct CellKeysFn {
  CellGridSpec<D> spec;
  const Vec<D>* pos;
  const int* tags;  // null: every slot has tag 0
  K* keys;
  int* ids;
  const int* perm = nullptr;  // the id tie-break's first pass: key k is slot perm[k]'s (null: slot k)
  CPS_HD void operator()(int k) const {
    const int i = perm ? perm[k] : k;
    keys[k] = K(spec.key(pos[i], tags ? tags[i] : 0));
    ids[k] = i;
  }
};

// the id tie-break's first pass: slots keyed by their particle's id (a slot that keeps its
// place, when *rebuild is 0: by the slot itself, so the order stands)
struct IdKeysFn {
  const int* id;
  const int* rebuild;  // null: always by id
  uint32_t* keys;
  int* slots;
  CPS_HD void operator()(int i) const {
    keys[i] = uint32_t(rebuild && *rebuild == 0 ? i : id[i]);
    slots[i] = i;
  }
};

// the keys of a sort that keeps the order unless *rebuild: a slot not rekeyed keeps the key the
// last sort gave it (those are sorted, so the stable sort leaves every slot where it is and the
// cell ranges come out as they were)
template <int D, class K>
struct CellKeysIfFn {
  CellGridSpec<D> spec;
  const Vec<D>* pos;
  const int* tags;
  const K* last;  // the last sort's sorted keys
  const int* rebuild;
  K* keys;
  int* ids;
  const int* perm = nullptr;  // as CellKeysFn's
  CPS_HD void operator()(int k) const {
    const int i = perm ? perm[k] : k;
    keys[k] = *rebuild ? K(spec.key(pos[i], tags ? tags[i] : 0)) : last[k];
    ids[k] = i;
  }
};

template <class T>
struct ReorderFn {
  const int* order;
  const T* in;
  T* out;
  CPS_HD void operator()(int j) const { out[j] = in[order[j]]; }
};

// record the cell range of sorted slot j (tables zeroed beforehand)
template <int D, class K>
struct CellMarkFn {
  CellGridSpec<D> spec;
  const K* keys;
  int n;
  uint32_t* start;
  uint32_t* end;
  CPS_HD void operator()(int j) const {
    const K k = keys[j];
    if (k == K(CellGridSpec<D>::kSentinel)) return;
    const uint64_t slot = spec.slot_of_key(uint64_t(k));
    if (j == 0 || keys[j - 1] != k) start[slot] = uint32_t(j);
    if (j == n - 1 || keys[j + 1] != k) end[slot] = uint32_t(j + 1);
  }
};

// the host side: the keys, the sort order, the cell table and (for build) a sorted copy of
// the positions, in Exec buffers that grow with the particle count
template <int D, class Exec>
class CellGrid {
 public:
  template <class T>
  using Buffer = typename Exec::template Buffer<T>;

  explicit CellGrid(const CellGridSpec<D>& spec) : spec_(spec) {}
  const CellGridSpec<D>& spec() const { return spec_; }

  // 1. key slot i from pos[i] and tags[i] (null: tag 0; a tag outside [0, ntags): an unused
  //    slot), then stable-sort the keys
  //    (ids: ties within a cell broken by ids[i], a particle's id below 2^id_bits, so the sorted
  //    order is (tag, cell, id) whatever order the slots came in: two stable sorts, by id and
  //    then by cell; null: ties keep the slots' order)
  void sort(Exec& ex, const Vec<D>* pos, const int* tags, int n, const int* ids = nullptr, int id_bits = 32) {
    n_ = n;
    grow(ex, ids_, n);
    grow(ex, order_, n);
    const int* perm = ids ? by_id(ex, ids, nullptr, n, id_bits) : nullptr;
    if (spec_.narrow()) {
      grow(ex, keys32_, n);
      grow(ex, keys32_sorted_, n);
      ex.for_each(n, CellKeysFn<D, uint32_t>{spec_, pos, tags, keys32_.data(), ids_.data(), perm});
      ex.sort_pairs(keys32_.data(), keys32_sorted_.data(), ids_.data(), order_.data(), n, spec_.key_bits);
    } else {
      grow(ex, keys_, n);
      grow(ex, keys_sorted_, n);
      ex.for_each(n, CellKeysFn<D, uint64_t>{spec_, pos, tags, keys_.data(), ids_.data(), perm});
      ex.sort_pairs(keys_.data(), keys_sorted_.data(), ids_.data(), order_.data(), n, spec_.key_bits);
    }
    sorted_ = true;
  }
  // 1'. the same when *rebuild != 0 (read on the device); otherwise every slot keeps its last
  //     sorted key and the order stands (order() is the identity). The first sort always keys.
  //     (ids, id_bits: the tie-break of sort)
  void sort_if(Exec& ex, const Vec<D>* pos, const int* tags, int n, const int* rebuild, const int* ids = nullptr,
               int id_bits = 32) {
    if (!sorted_ || n != n_) {
      sort(ex, pos, tags, n, ids, id_bits);
      return;
    }
    const int* perm = ids ? by_id(ex, ids, rebuild, n, id_bits) : nullptr;
    if (spec_.narrow()) {
      ex.for_each(n, CellKeysIfFn<D, uint32_t>{spec_, pos, tags, keys32_sorted_.data(), rebuild, keys32_.data(),
                                               ids_.data(), perm});
      ex.sort_pairs(keys32_.data(), keys32_sorted_.data(), ids_.data(), order_.data(), n, spec_.key_bits);
    } else {
      ex.for_each(n, CellKeysIfFn<D, uint64_t>{spec_, pos, tags, keys_sorted_.data(), rebuild, keys_.data(),
                                               ids_.data(), perm});
      ex.sort_pairs(keys_.data(), keys_sorted_.data(), ids_.data(), order_.data(), n, spec_.key_bits);
    }
  }
  // 2. out[j] = in[order()[j]]: an array in sorted order (in and out distinct)
  template <class T>
  void reorder(Exec& ex, const T* in, T* out) const {
    ex.for_each(n_, ReorderFn<T>{order_.data(), in, out});
  }
  // 3. the cell ranges of the sorted keys
  void mark(Exec& ex) {
    const uint64_t entries = spec_.table_size();
    if (start_.size() < entries) {
      ex.resize(start_, entries);
      ex.resize(end_, entries);
    }
    ex.zero(start_.data(), entries * sizeof(uint32_t));
    ex.zero(end_.data(), entries * sizeof(uint32_t));
    if (spec_.narrow())
      ex.for_each(n_, CellMarkFn<D, uint32_t>{spec_, keys32_sorted_.data(), n_, start_.data(), end_.data()});
    else
      ex.for_each(n_, CellMarkFn<D, uint64_t>{spec_, keys_sorted_.data(), n_, start_.data(), end_.data()});
  }
  // all three, keeping a sorted copy of the positions for view()
  void build(Exec& ex, const Vec<D>* pos, const int* tags, int n) {
    sort(ex, pos, tags, n);
    grow(ex, sorted_pos_, n);
    reorder(ex, pos, sorted_pos_.data());
    mark(ex);
  }

  // the view over positions in sorted order (the caller's reordered array), every tag
  CellGridView<D> view(const Vec<D>* sorted_pos) const {
    CellGridView<D> v;
    v.spec = spec_;
    v.pos = sorted_pos;
    if (spec_.narrow()) v.keys32 = keys32_sorted_.data();
    else v.keys = keys_sorted_.data();
    v.cell_start = start_.data();
    v.cell_end = end_.data();
    v.n = n_;
    v.r2 = spec_.radius * spec_.radius;
    v.tag_begin = 0;
    v.tag_end = spec_.ntags;
    return v;
  }
  // the view over the grid's own sorted copy (after build)
  CellGridView<D> view() const { return view(sorted_pos_.data()); }

  int size() const { return n_; }
  const int* order() const { return order_.data(); }             // sorted slot -> input slot
  // the sorted keys as 64-bit values on the host (the sentinel as kSentinel), for tests
  std::vector<uint64_t> sorted_keys_host(Exec& ex) const {
    std::vector<uint64_t> out(size_t(n_ > 0 ? n_ : 0));
    if (n_ <= 0) return out;
    if (spec_.narrow()) {
      std::vector<uint32_t> k(out.size());
      ex.to_host(k.data(), keys32_sorted_.data(), k.size() * sizeof(uint32_t));
      for (size_t i = 0; i < k.size(); ++i) out[i] = k[i] == ~uint32_t(0) ? CellGridSpec<D>::kSentinel : k[i];
    } else {
      ex.to_host(out.data(), keys_sorted_.data(), out.size() * sizeof(uint64_t));
    }
    return out;
  }
  const Vec<D>* sorted_positions() const { return sorted_pos_.data(); }
  uint64_t table_entries() const { return spec_.table_size(); }

 private:
  // the slots in the order of their ids (a slot that keeps its place when *rebuild is 0: the
  // identity), the first pass of the id tie-break
  const int* by_id(Exec& ex, const int* ids, const int* rebuild, int n, int id_bits) {
    grow(ex, id_keys_, n);
    grow(ex, id_keys_sorted_, n);
    grow(ex, id_slots_, n);
    grow(ex, id_perm_, n);
    int bits = id_bits;
    while ((int64_t(1) << bits) < int64_t(n) && bits < 32) ++bits;  // (a kept slot is keyed by its index)
    ex.for_each(n, IdKeysFn{ids, rebuild, id_keys_.data(), id_slots_.data()});
    ex.sort_pairs(id_keys_.data(), id_keys_sorted_.data(), id_slots_.data(), id_perm_.data(), n, bits > 32 ? 32 : bits);
    return id_perm_.data();
  }
  template <class T>
  static void grow(Exec& ex, Buffer<T>& b, int n) {
    if (b.size() < size_t(n) || b.size() == 0) ex.resize(b, size_t(n > 0 ? n : 1));
  }

  CellGridSpec<D> spec_;
  int n_ = 0;
  bool sorted_ = false;  // a sort has keyed every slot (sort_if may keep those keys)
  Buffer<uint64_t> keys_, keys_sorted_;      // 64-bit keys ...
  Buffer<uint32_t> keys32_, keys32_sorted_;  // ... or 32-bit ones (spec_.narrow())
  Buffer<int> ids_, order_;
  Buffer<uint32_t> id_keys_, id_keys_sorted_;  // the id tie-break's first pass
  Buffer<int> id_slots_, id_perm_;
  Buffer<Vec<D>> sorted_pos_;
  Buffer<uint32_t> start_, end_;
};

}  // namespace cps
