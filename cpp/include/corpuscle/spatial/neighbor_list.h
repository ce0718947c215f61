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
#pragma once
#include <string>

#include "corpuscle/core/error.h"
#include "corpuscle/spatial/index.h"

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

}  // namespace cps
