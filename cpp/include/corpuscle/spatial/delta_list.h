// Delta-coded slot lists: the slot lists of spatial/neighbor_list.h (fixed capacity, byte k of
// slot i at nbr[k * stride + i], so the threads of a warp read their k-th bytes in one
// transaction; one build pass that a device flag can skip; overflow: the counts are the true
// ones and the owner grows the capacity and repeats the step) with each entry stored as the
// difference to the entry before it in one byte: a cell walk lists a slot's neighbours range
// by range, each range of consecutive sorted slots, so within a range the differences are
// small (about the candidates per neighbour: 6 in a 3-D walk of 27 cells of the list radius).
// A difference outside 1 .. 254 (the first entry, the jump to the next range, a periodic wrap
// read as a second range, anything) is stored as an escape byte (255) and the slot number in
// the next four bytes (little-endian), so any list can be stored. The entries decode to the
// slot lists' entries in the same order: a pair pass over them sums the same terms in the
// same order (bitwise the same on the CPU).
//
// Cost: one byte an entry plus four an escape (about one escape per cell range with
// neighbours: 9 in 3-D, 3 in 2-D), against four bytes an entry. A walk decodes the entries in
// turn (a slot's k-th neighbour needs the k - 1 before it): with kWidth lanes sharing a list,
// every lane decodes the whole list and visits every kWidth-th entry, as the slot lists do.
#pragma once
#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

#include "corpuscle/core/atomics.h"
#include "corpuscle/core/error.h"
#include "corpuscle/core/lanes.h"
#include "corpuscle/spatial/index.h"
#include "corpuscle/spatial/periodic.h"

namespace cps {

constexpr uint8_t kDeltaEscape = 255;

template <int D>
struct DeltaSlotListView {
  static constexpr int kDim = D;
  const uint8_t* nbr = nullptr;  // capacity * stride bytes
  const int* counts = nullptr;   // stride entries: the bytes the list needed (may exceed capacity)
  const VecA<D>* pos = nullptr;  // positions, numbered like the list's slots (padded)
  int pos_stride = 1;            // slot i's position at pos[i * pos_stride]
  int n = 0;
  int capacity = 0;              // bytes a slot
  size_t stride = 0;
  float r2 = 0.0f;
  float list_radius = 0.0f;
  Periodic<D> per;

  CPS_HD int size() const { return n; }
  CPS_HD bool active(int) const { return true; }
  CPS_HD Vec<D> position(int i) const { return VecA<D>::load(pos + size_t(i) * pos_stride); }
  CPS_HD float max_radius() const { return list_radius; }
  CPS_HD DeltaSlotListView with_radius(float r) const {
    DeltaSlotListView v = *this;
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
  // lane `lane` of kWidth lanes sharing slot i's list: its entries lane, lane + kWidth, ... (as
  // SlotListView::gather_lane)
  template <int kWidth, class Visit>
  CPS_HD void gather_lane(int i, const Vec<D>& xi, int lane, Visit&& visit) const {
    walk<false, kWidth>(i, xi, visit, lane);
  }
  // the listed entries in the build's order, within the query radius now
  template <bool kPairs, int kWidth = 1, class Visit>
  CPS_HD void walk(int i, const Vec<D>& xi, Visit& visit, int first = 0) const {
    static_assert(kWidth >= 1, "a walk takes at least every entry");
    const int c = count(i);
    const uint8_t* e = nbr + i;
    int k = 0, entry = 0, j = -1;
    while (k < c) {
      const uint8_t b = e[size_t(k) * stride];
      if (b == kDeltaEscape) {
        j = int(uint32_t(e[size_t(k + 1) * stride]) | (uint32_t(e[size_t(k + 2) * stride]) << 8) |
                (uint32_t(e[size_t(k + 3) * stride]) << 16) | (uint32_t(e[size_t(k + 4) * stride]) << 24));
        k += 5;
      } else {
        j += int(b);
        k += 1;
      }
      const int mine = entry++;
      if (kWidth > 1 && (mine & (kWidth - 1)) != first) continue;
      if (kPairs && j <= i) continue;
      const Vec<D> d = per.displacement(xi - position(j));
      const float rr = norm2(d);
      if (rr < r2) visit(j, d, rr);
    }
  }
};

// the build of slots [begin, begin + count): as SlotListFillFn (neighbor_list.h), the entries
// delta-coded; counts[i] = the bytes slot i's list needed
template <class View>
struct DeltaSlotListFillFn {
  View src;
  uint8_t* nbr;
  int* counts;
  size_t stride;
  int capacity;
  int begin;
  int* overflow;
  int code;

  // slot j after slot `prev` at byte c of list e: the bytes after it
  CPS_HD int put(uint8_t* e, int c, int prev, int j) const {
    const int d = j - prev;
    if (d >= 1 && d < int(kDeltaEscape)) {
      if (c < capacity) e[size_t(c) * stride] = uint8_t(d);
      return c + 1;
    }
    if (c + 5 <= capacity) put_escape(e, c, j);
    return c + 5;
  }
  CPS_HD void put_escape(uint8_t* e, int c, int j) const {
    const uint32_t u = uint32_t(j);
    e[size_t(c) * stride] = kDeltaEscape;
    e[size_t(c + 1) * stride] = uint8_t(u & 0xffu);
    e[size_t(c + 2) * stride] = uint8_t((u >> 8) & 0xffu);
    e[size_t(c + 3) * stride] = uint8_t((u >> 16) & 0xffu);
    e[size_t(c + 4) * stride] = uint8_t((u >> 24) & 0xffu);
  }
  CPS_HD void operator()(int k) const {
    const int i = begin + k;
    int c = 0, prev = -1;
    if (src.active(i)) {
      uint8_t* e = nbr + i;
      src.gather(i, src.position(i), [&](int j, const Vec<View::kDim>&, float) {
        if (j == i) return;
        c = put(e, c, prev, j);
        prev = j;
      });
    }
    finish(i, c);
  }
  CPS_HD void operator()(int k, const SingleLane&) const { (*this)(k); }
#ifdef __CUDACC__
  // W lanes a slot (a cell grid's view): lane l takes the candidates s + l, s + l + W, ... of
  // each cell range and a ballot orders the hits, as SlotListFillFn's; the hits of one batch
  // are at most W - 1 apart, so only a batch's first hit can need an escape, and every lane
  // knows from the ballot where its byte goes: the lists are the one-lane build's, byte for byte
  template <int W>
  __device__ void operator()(int k, const SubWarpLanes<W>& L) const {
    const int i = begin + k;
    int c = 0, prev = -1;
    if (src.active(i)) {
      const auto xi = src.position(i);
      const int lane = L.lane();
      const unsigned below = (1u << lane) - 1u;
      uint8_t* e = nbr + i;
      src.for_each_cell_range(i, xi, [&](uint32_t s, uint32_t end) {
        for (uint32_t b = s; b < end; b += uint32_t(W)) {
          const uint32_t j = b + uint32_t(lane);
          bool hit = false;
          if (j < end && j != uint32_t(i)) hit = norm2(src.spec.per.displacement(xi - src.pos[j])) < src.r2;
          const unsigned m = L.group_ballot(hit);
          if (m == 0u) continue;
          const int first = __ffs(int(m)) - 1;
          const int df = int(b) + first - prev;
          const bool esc = !(df >= 1 && df < int(kDeltaEscape));
          if (hit) {
            if (lane == first) {
              if (esc) {
                if (c + 5 <= capacity) put_escape(e, c, int(j));
              } else if (c < capacity) {
                e[size_t(c) * stride] = uint8_t(df);
              }
            } else {
              const unsigned lower = m & below;  // (holds `first`)
              const int at = c + (esc ? 4 : 0) + __popc(lower);
              const int d = lane - (31 - __clz(int(lower)));
              if (at < capacity) e[size_t(at) * stride] = uint8_t(d);
            }
          }
          prev = int(b) + (31 - __clz(int(m)));
          c += __popc(m) + (esc ? 4 : 0);
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
class DeltaSlotNeighborList {
 public:
  template <class T>
  using Buffer = typename Exec::template Buffer<T>;

  // room for n slots of `capacity` bytes (the contents are lost)
  void reserve(Exec& ex, int n, int capacity) {
    if (n < 0 || capacity < 5)
      throw Error("neighbour list: needs n >= 0 slots and a capacity of at least 5 bytes, got " + std::to_string(n) +
                  " and " + std::to_string(capacity));
    n_ = n;
    capacity_ = capacity;
    stride_ = size_t(n > 0 ? n : 1);
    ex.resize(nbr_, stride_ * size_t(capacity));
    ex.resize(counts_, stride_);
  }
  static double bytes(int n, int capacity) {
    return double(n > 0 ? n : 1) * (double(capacity) * sizeof(uint8_t) + sizeof(int));
  }

  // as SlotNeighborList::fill
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
    DeltaSlotListFillFn<View> f{src.with_radius(list_radius), nbr_.data(), counts_.data(), stride_, capacity_, begin,
                                overflow, code};
    if constexpr (W == 1) {
      if (when) ex.for_each_if(when, count, f);
      else ex.for_each(count, f);
    } else {
      if (when) ex.template for_each_lanes_w_if<W>(when, count, f);
      else ex.template for_each_lanes_w<W>(count, f);
    }
  }

  DeltaSlotListView<D> view(const VecA<D>* pos, float radius, int pos_stride = 1, const Periodic<D>& per = {}) const {
    if (radius > list_radius_)
      throw Error("neighbour list: a query radius of " + std::to_string(radius) + " exceeds the list radius " +
                  std::to_string(list_radius_));
    DeltaSlotListView<D> v;
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

  // the most bytes a list of the last build needed (a host read-back: growing after an overflow)
  int max_count(Exec& ex) const {
    if (n_ <= 0) return 0;
    std::vector<int> c(n_);
    ex.synchronize();
    ex.to_host(c.data(), counts_.data(), size_t(n_) * sizeof(int));
    return *std::max_element(c.begin(), c.end());
  }

  int size() const { return n_; }
  int capacity() const { return capacity_; }
  float list_radius() const { return list_radius_; }

 private:
  int n_ = 0, capacity_ = 0;
  size_t stride_ = 1;
  float list_radius_ = 0.0f;
  Buffer<uint8_t> nbr_;
  Buffer<int> counts_;
};

}  // namespace cps
