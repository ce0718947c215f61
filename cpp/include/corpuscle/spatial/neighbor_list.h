// CSR neighbour lists, built from any index (spatial/index.h) in three passes:
//
//   count:  counts[i] = the neighbours the source index gathers for slot i within the list radius
//   scan:   offsets = exclusive_scan(counts) (int64, offsets[n] = the total)
//   fill:   neighbours[offsets[i] ..] = those neighbours, in the source's gather order
//
// Memory follows the pairs that exist: the host reads the total once per build and grows
// the neighbour buffer (by a quarter more than needed) when it does not fit, so a list never
// overflows and a build never stops. The list radius may exceed the radius the stages use
// (a skin): the view's gather checks the distance against its own radius with the positions
// it is given (which may have moved since the build, by less than half the skin).
//
// Slot lists (SlotNeighborList, below) are the fixed-capacity form for a pair stage run one
// thread per particle on a device: entry k of slot i is stored at nbr[k * stride + i], so the
// threads of a warp (consecutive slots) read their k-th entries in one coalesced transaction,
// and every lane of the pair loop evaluates a listed neighbour instead of a cell's candidate.
// A build is one pass (no count pass, no host read-back, so it can run inside a captured CUDA
// graph and be skipped by a device flag): a slot with more neighbours than the capacity stores
// the first `capacity`, counts them all and raises an overflow code; the host then grows the
// capacity to the largest count and repeats the step (the engine's fixed-capacity rule).
//
// Row lists (RowLists, below) are the fixed-capacity form for W lanes sharing one slot's list
// (a warp per particle): slot i's entries lie in one row, nbr[i * capacity + k], so the lanes
// read consecutive entries. They are filled by any walk that lists (the cell walk by lanes, an
// all-pairs scan of a range), in its order, the slot itself included, and a shorter row list
// can keep the entries of another within a smaller radius (walk_compacting); the same
// overflow rule holds (the counts are the true ones; the owner grows and repeats).
#pragma once
#include <algorithm>
#include <string>
#include <vector>

#include "corpuscle/core/atomics.h"
#include "corpuscle/core/error.h"
#include "corpuscle/core/lanes.h"
#include "corpuscle/spatial/index.h"
#include "corpuscle/spatial/lane_walks.h"
#include "corpuscle/spatial/periodic.h"

namespace cps {

template <int D>
struct CsrView {
  static constexpr int kDim = D;
  const int64_t* offsets = nullptr;  // n + 1 entries
  const int* nbr = nullptr;          // offsets[n] entries
  const Vec<D>* pos = nullptr;       // positions, in the numbering of the list's entries
  int n = 0;
  float r2 = 0.0f;            // squared query radius
  float list_radius = 0.0f;   // the radius the lists were built with

  CPS_HD int size() const { return n; }
  CPS_HD bool active(int) const { return true; }
  CPS_HD const Vec<D>& position(int i) const { return pos[i]; }
  CPS_HD float max_radius() const { return list_radius; }
  CPS_HD CsrView with_radius(float r) const {
    CsrView v = *this;
    v.r2 = r * r;
    return v;
  }
  CPS_HD int64_t count(int i) const { return offsets[i + 1] - offsets[i]; }

  template <class Visit>
  CPS_HD void gather(int i, const Vec<D>& xi, Visit&& visit) const {
    walk<false>(i, xi, visit);
  }
  template <class Visit>
  CPS_HD void pairs(int i, const Vec<D>& xi, Visit&& visit) const {
    walk<true>(i, xi, visit);
  }
  template <bool kPairs, class Visit>
  CPS_HD void walk(int i, const Vec<D>& xi, Visit& visit) const {
    const int64_t e = offsets[i + 1];
    for (int64_t k = offsets[i]; k < e; ++k) {
      const int j = nbr[k];
      if (kPairs && j <= i) continue;
      Vec<D> d = xi - pos[j];
      float rr = norm2(d);
      if (rr < r2) visit(j, d, rr);
    }
  }
};

// count pass: neighbours of slot i in the source index
template <class View>
struct CsrCountFn {
  View src;
  int* counts;
  CPS_HD void operator()(int i) const {
    int c = 0;
    if (src.active(i)) src.gather(i, src.position(i), [&](int, const Vec<View::kDim>&, float) { ++c; });
    counts[i] = c;
  }
};

// fill pass: the same walk, writing the neighbours at the scanned offsets
template <class View>
struct CsrFillFn {
  View src;
  const int64_t* offsets;
  int* nbr;
  CPS_HD void operator()(int i) const {
    if (!src.active(i)) return;
    int64_t at = offsets[i];
    src.gather(i, src.position(i), [&](int j, const Vec<View::kDim>&, float) { nbr[at++] = j; });
  }
};

template <int D, class Exec>
class NeighborList {
 public:
  template <class T>
  using Buffer = typename Exec::template Buffer<T>;

  // lists of every slot of the source view within list_radius (<= src.max_radius()); reads
  // the total back once and grows the neighbour buffer when it is too small
  template <class View>
  void build(Exec& ex, const View& src, float list_radius) {
    static_assert(View::kDim == D, "the source index has another dimension");
    if (!(list_radius > 0.0f) || !(list_radius <= src.max_radius()))
      throw Error("neighbour list: the list radius " + std::to_string(list_radius) +
                  " must be positive and at most the source index's radius " + std::to_string(src.max_radius()));
    const View s = src.with_radius(list_radius);
    n_ = s.size();
    list_radius_ = list_radius;
    if (counts_.size() < size_t(n_) || counts_.size() == 0) ex.resize(counts_, size_t(n_ > 0 ? n_ : 1));
    if (offsets_.size() < size_t(n_) + 1) ex.resize(offsets_, size_t(n_) + 1);
    ex.for_each(n_, CsrCountFn<View>{s, counts_.data()});
    ex.exclusive_scan(counts_.data(), offsets_.data(), n_, offsets_.data() + n_);
    int64_t total = 0;
    ex.to_host(&total, offsets_.data() + n_, sizeof(total));
    total_ = total;
    if (size_t(total) > nbr_.size() || nbr_.size() == 0) {
      const size_t cap = size_t(total) + size_t(total) / 4 + 64;
      ex.resize(nbr_, cap);
      ++grows_;
    }
    ex.for_each(n_, CsrFillFn<View>{s, offsets_.data(), nbr_.data()});
    ++builds_;
  }

  // the lists over positions `pos` (numbered like the source's slots), queried with radius
  // (at most the list radius; default: the list radius)
  CsrView<D> view(const Vec<D>* pos, float radius = -1.0f) const {
    if (radius > list_radius_)
      throw Error("neighbour list: a query radius of " + std::to_string(radius) + " exceeds the list radius " +
                  std::to_string(list_radius_));
    CsrView<D> v;
    v.offsets = offsets_.data();
    v.nbr = nbr_.data();
    v.pos = pos;
    v.n = n_;
    const float r = radius < 0.0f ? list_radius_ : radius;
    v.r2 = r * r;
    v.list_radius = list_radius_;
    return v;
  }

  int size() const { return n_; }
  int64_t total() const { return total_; }            // entries of the last build
  size_t capacity() const { return nbr_.size(); }     // entries the buffer holds
  int builds() const { return builds_; }
  int grows() const { return grows_; }                // builds that grew the buffer
  float list_radius() const { return list_radius_; }
  const int64_t* offsets() const { return offsets_.data(); }
  const int* neighbors() const { return nbr_.data(); }

 private:
  int n_ = 0;
  float list_radius_ = 0.0f;
  int64_t total_ = 0;
  int builds_ = 0, grows_ = 0;
  Buffer<int> counts_;
  Buffer<int64_t> offsets_;
  Buffer<int> nbr_;
};

// ---- slot lists: fixed capacity, entry k of slot i at nbr[k * stride + i] ----

template <int D>
struct SlotListView {
  static constexpr int kDim = D;
  const int* nbr = nullptr;     // capacity * stride entries
  const int* counts = nullptr;  // stride entries: the neighbours found (may exceed capacity: overflow)
  const VecA<D>* pos = nullptr; // positions, numbered like the list's slots (padded: one vector load)
  int pos_stride = 1;           // slot i's position at pos[i * pos_stride] (inside larger records)
  int n = 0;
  int capacity = 0;
  size_t stride = 0;
  float r2 = 0.0f;           // squared query radius
  float list_radius = 0.0f;  // the radius the lists were built with
  Periodic<D> per;           // periodic axes: the walk's displacement is the minimum image

  CPS_HD int size() const { return n; }
  CPS_HD bool active(int) const { return true; }
  CPS_HD Vec<D> position(int i) const { return VecA<D>::load(pos + size_t(i) * pos_stride); }
  CPS_HD float max_radius() const { return list_radius; }
  CPS_HD SlotListView with_radius(float r) const {
    SlotListView v = *this;
    v.r2 = r * r;
    return v;
  }
  CPS_HD int count(int i) const { return counts[i] < capacity ? counts[i] : capacity; }

  template <class Visit>
  CPS_HD void gather(int i, const Vec<D>& xi, Visit&& visit) const {
    walk<false>(i, xi, visit);
  }
  template <class Visit>
  CPS_HD void pairs(int i, const Vec<D>& xi, Visit&& visit) const {
    walk<true>(i, xi, visit);
  }
  // lane `lane` of kWidth lanes sharing slot i's list: entries lane, lane + kWidth, ... (in
  // the build's order; the kWidth lanes together visit what gather visits). Entry k of slot i
  // lies at nbr[k * stride + i], so a warp of 32 / kWidth slots reads kWidth rows of
  // 32 / kWidth consecutive entries a round: for kWidth <= 4 as many 32-byte sectors as one
  // row of 32 (kWidth = 8: twice as many)
  template <int kWidth, class Visit>
  CPS_HD void gather_lane(int i, const Vec<D>& xi, int lane, Visit&& visit) const {
    walk<false, kWidth>(i, xi, visit, lane);
  }
  // the listed entries in the order the build found them, within the query radius now. Written
  // as "find the next entry within the radius, then visit it": on a device the lanes of a warp
  // search their lists apart (a few instructions an entry) and run the visitor together, so an
  // entry past the radius costs a lane the search only, not an idle pass through the visitor.
  // kWidth > 1: every kWidth-th entry from `first` (gather_lane)
  template <bool kPairs, int kWidth = 1, class Visit>
  CPS_HD void walk(int i, const Vec<D>& xi, Visit& visit, int first = 0) const {
    static_assert(kWidth >= 1, "a walk takes at least every entry");
    const int c = count(i);
    const int* e = nbr + i + size_t(first) * stride;
    const size_t step = size_t(kWidth) * stride;
    int k = first;
    // loaded ahead (the walk waits on memory, not on arithmetic: ncu's long-scoreboard stalls,
    // docs/benchmarks.md): entry k's index j1 and position x1, entry k + kWidth's index j2; each
    // round starts the loads of the next, so a load's latency overlaps a round of work
    int j1 = k < c ? e[0] : -1;
    int j2 = k + kWidth < c ? e[step] : -1;
    Vec<D> x1 = j1 >= 0 ? position(j1) : Vec<D>::zero();
    for (;;) {
      int j = -1;
      Vec<D> d;
      float rr = 0.0f;
      while (j1 >= 0) {
        const int jj = j1;
        const Vec<D> xj = x1;
        j1 = j2;
        j2 = k + 2 * kWidth < c ? e[2 * step] : -1;
        if (j1 >= 0) x1 = position(j1);
        k += kWidth;
        e += step;
        if (kPairs && jj <= i) continue;
        d = per.displacement(xi - xj);
        rr = norm2(d);
        if (rr < r2) {
          j = jj;
          break;
        }
      }
      if (j < 0) return;
      visit(j, d, rr);
    }
  }
};

// the build of slots [begin, begin + count): the source index's neighbours of slot i within
// its radius (i itself left out), in the source's gather order; counts[i] = how many there
// were, *overflow = code (if it was 0) when that is more than the capacity
template <class View>
struct SlotListFillFn {
  View src;
  int* nbr;
  int* counts;
  size_t stride;
  int capacity;
  int begin;
  int* overflow;
  int code;
  CPS_HD void operator()(int k) const {
    const int i = begin + k;
    int c = 0;
    if (src.active(i)) {
      int* e = nbr + i;
      src.gather(i, src.position(i), [&](int j, const Vec<View::kDim>&, float) {
        if (j == i) return;
        if (c < capacity) e[size_t(c) * stride] = j;
        ++c;
      });
    }
    finish(i, c);
  }
  CPS_HD void operator()(int k, const SingleLane&) const { (*this)(k); }
#ifdef __CUDACC__
  // W lanes a slot (a cell grid's view: the lanes share its cell ranges): lane l takes the
  // candidates s + l, s + l + W, ... of each cell, and a ballot lists the hits in candidate
  // order, so the lists are those of the one-lane build, entry for entry. (One thread walking
  // a slot's 27 cells waits on every load: latency-bound, docs/benchmarks.md.)
  template <int W>
  __device__ void operator()(int k, const SubWarpLanes<W>& L) const {
    const int i = begin + k;
    int c = 0;
    if (src.active(i)) {
      const auto xi = src.position(i);
      const unsigned below = (1u << L.lane()) - 1u;
      int* e = nbr + i;
      src.for_each_cell_range(i, xi, [&](uint32_t s, uint32_t end) {
        for (uint32_t b = s; b < end; b += uint32_t(W)) {
          const uint32_t j = b + uint32_t(L.lane());
          bool hit = false;
          if (j < end && j != uint32_t(i)) hit = norm2(src.spec.per.displacement(xi - src.pos[j])) < src.r2;
          const unsigned m = L.group_ballot(hit);
          if (hit) {
            const int at = c + __popc(m & below);
            if (at < capacity) e[size_t(at) * stride] = int(j);
          }
          c += __popc(m);
        }
      });
    }
    if (L.leader()) finish(i, c);
  }
#endif
  CPS_HD void finish(int i, int c) const {
    counts[i] = c;
    if (c > capacity && overflow) atomic_cas(overflow, 0, code);
  }
};

template <int D, class Exec>
class SlotNeighborList {
 public:
  template <class T>
  using Buffer = typename Exec::template Buffer<T>;

  // room for n slots of `capacity` entries (the contents are lost)
  void reserve(Exec& ex, int n, int capacity) {
    if (n < 0 || capacity < 1)
      throw Error("neighbour list: needs n >= 0 slots and a capacity of at least 1, got " + std::to_string(n) +
                  " and " + std::to_string(capacity));
    n_ = n;
    capacity_ = capacity;
    stride_ = size_t(n > 0 ? n : 1);
    ex.resize(nbr_, stride_ * size_t(capacity));
    ex.resize(counts_, stride_);
  }
  static double bytes(int n, int capacity) { return double(n > 0 ? n : 1) * (double(capacity) + 1.0) * sizeof(int); }

  // list slots [begin, begin + count) from the source view within list_radius (at most its
  // radius); when `when` is given, only if *when != 0 (read on the device: a stage can skip the
  // build without a host round trip). Overflow: *overflow = code, the counts are the true ones.
  // W lanes a slot (W > 1: a cell grid's view; the CPU runs one lane): the same lists.
  template <int W = 1, class View>
  void fill(Exec& ex, const View& src, float list_radius, int begin, int count, int* overflow, int code,
            const int* when = nullptr) {
    static_assert(View::kDim == D, "the source index has another dimension");
    if (!(list_radius > 0.0f) || !(list_radius <= src.max_radius()))
      throw Error("neighbour list: the list radius " + std::to_string(list_radius) +
                  " must be positive and at most the source index's radius " + std::to_string(src.max_radius()));
    if (begin < 0 || count < 0 || begin + count > n_)
      throw Error("neighbour list: slots " + std::to_string(begin) + " + " + std::to_string(count) + " outside the " +
                  std::to_string(n_) + " reserved");
    list_radius_ = list_radius;
    SlotListFillFn<View> f{src.with_radius(list_radius), nbr_.data(), counts_.data(), stride_, capacity_, begin,
                           overflow, code};
    if constexpr (W == 1) {
      if (when) ex.for_each_if(when, count, f);
      else ex.for_each(count, f);
    } else {
      if (when) ex.template for_each_lanes_w_if<W>(when, count, f);
      else ex.template for_each_lanes_w<W>(count, f);
    }
  }

  // the lists over positions `pos` (numbered like the source's slots; slot i's at
  // pos[i * pos_stride]), queried with radius (at most the list radius)
  SlotListView<D> view(const VecA<D>* pos, float radius, int pos_stride = 1, const Periodic<D>& per = {}) const {
    if (radius > list_radius_)
      throw Error("neighbour list: a query radius of " + std::to_string(radius) + " exceeds the list radius " +
                  std::to_string(list_radius_));
    SlotListView<D> v;
    v.nbr = nbr_.data();
    v.counts = counts_.data();
    v.pos = pos;
    v.pos_stride = pos_stride;
    v.n = n_;
    v.capacity = capacity_;
    v.stride = stride_;
    v.r2 = radius * radius;
    v.list_radius = list_radius_;
    v.per = per;
    return v;
  }

  // the largest count of the last build (a host read-back: for growing after an overflow)
  int max_count(Exec& ex) const {
    if (n_ <= 0) return 0;
    std::vector<int> c(n_);
    ex.synchronize();
    ex.to_host(c.data(), counts_.data(), size_t(n_) * sizeof(int));
    return *std::max_element(c.begin(), c.end());
  }

  int size() const { return n_; }
  int capacity() const { return capacity_; }
  size_t stride() const { return stride_; }
  float list_radius() const { return list_radius_; }
  const int* neighbors() const { return nbr_.data(); }
  const int* counts() const { return counts_.data(); }

 private:
  int n_ = 0, capacity_ = 0;
  size_t stride_ = 1;
  float list_radius_ = 0.0f;
  Buffer<int> nbr_, counts_;
};

// ---- row lists: fixed capacity, entry k of slot i at nbr[i * capacity + k] ----

struct RowLists {
  int* nbr = nullptr;    // rows of `capacity` entries, one a slot
  int* count = nullptr;  // one a slot: the entries found (may exceed capacity: overflow)
  int capacity = 0;

  CPS_HD int* row(int i) const { return nbr + size_t(i) * size_t(capacity); }
  // the entries row i holds (its count, at most the capacity)
  CPS_HD int stored(int c) const { return c < capacity ? c : capacity; }
  CPS_HD int listed(int i) const { return stored(count[i]); }

  // visit slot i's listed entries by lanes (spatial/lane_walks.h): visit(j, xi - pos[j], r2)
  // for each, in the row's order, with no radius check (the row holds what its fill kept)
  template <class Lanes, int D, class Visit>
  CPS_HD void walk(const Lanes& L, int i, const Vec<D>* pos, const Vec<D>& xi, Visit& visit) const {
    for_each_listed(L, row(i), listed(i), pos, xi, visit);
  }
  // the same over the first c entries (c: the true count of a listing just made, not yet
  // stored), copying those closer than sqrt(r2) to row i of `out` in order; returns how many
  // there were (the true count, past out's capacity)
  template <class Lanes, int D, class Visit>
  CPS_HD int walk_compacting(const Lanes& L, int i, int c, const Vec<D>* pos, const Vec<D>& xi, Visit& visit,
                             float r2, const RowLists& out) const {
    return for_each_listed_compacting(L, row(i), stored(c), pos, xi, visit, r2, out.row(i), out.capacity);
  }
};

}  // namespace cps
