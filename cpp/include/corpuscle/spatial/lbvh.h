// A linear bounding-volume hierarchy over points (Karras, "Maximizing Parallelism in the
// Construction of BVHs, Octrees, and k-d Trees", HPG 2012; the seed-000 WingSimulator's
// broad phase), built through an Exec so the same functors run on the CPU and on CUDA:
//
// 1. a 32-bit Morton code per point (16 bits per axis in 2-D, 10 in 3-D) over the domain;
// 2. (code, index) pairs sorted (CUB radix sort on the device, a stable sort on the CPU);
//    the caller reorders its particles along the curve with the sorted indices;
// 3. the n - 1 internal nodes in parallel: node i finds its range's direction from the
//    common-prefix lengths with its neighbours, the other end by an exponential then a
//    binary search, and its split by a binary search for the highest differing bit
//    (count-leading-zeros of code_a ^ code_b); duplicate codes are ordered by their index
//    (the prefix of equal codes continues into the indices, 32 + clz(a ^ b)), so every
//    split is defined. Internal nodes are 0 .. n-2 (0 the root), leaf k is n - 1 + k;
// 4. bottom-up box fitting: one thread per leaf climbs through its parents; at each node an
//    atomic visit counter decides: the first child to arrive stops, the second (whose
//    sibling's box is complete) writes the union and goes on. The box is written before a
//    memory fence that precedes the atomic (release), and the sibling's box is read after
//    it from L2 (__ldcg on the device: no stale L1 line), so the arrival order never lets a
//    thread read a box that is not yet written;
// 5. a gather query: each point walks the tree from the root with its query box on a stack
//    of kLbvhStack nodes; a stack that would overflow raises `overflow` (the caller stops
//    the run) instead of silently skipping a subtree, as the original did.
//
// The view answers gather(i, xi, visit) like every index (index.h): visit(j, xi - x_j, r2)
// for every j (i included) with r2 < radius^2, in an order fixed by the tree (deterministic).
#pragma once
#include <cstdint>

#include "corpuscle/core/atomics.h"
#include "corpuscle/core/vec.h"
#include "corpuscle/spatial/morton.h"

namespace cps {

constexpr int kLbvhStack = 64;

struct LbvhBox {
  float lo[3], hi[3];
};

CPS_HD CPS_INLINE int lbvh_clz(uint32_t x) {
#ifdef __CUDA_ARCH__
  return __clz(int(x));
#else
  return x == 0 ? 32 : __builtin_clz(x);
#endif
}

// the first arrival at a node gets 0; the fence orders this thread's box writes first
CPS_HD CPS_INLINE int lbvh_arrive(int* counter) {
#ifdef __CUDA_ARCH__
  __threadfence();
  int old = atomicAdd(counter, 1);
  __threadfence();
  return old;
#else
  return __atomic_fetch_add(counter, 1, __ATOMIC_ACQ_REL);
#endif
}

CPS_HD CPS_INLINE float lbvh_load(const float* p) {
#ifdef __CUDA_ARCH__
  return __ldcg(p);
#else
  float v;
  __atomic_load(p, &v, __ATOMIC_ACQUIRE);
  return v;
#endif
}

template <int D>
struct LbvhCodesFn {
  const Vec<D>* pos;
  Vec<D> lo;
  float scale[D];  // cells per unit length
  uint32_t* codes;
  int* ids;
  CPS_HD void operator()(int i) const {
    constexpr int bits = D == 3 ? 10 : 16;
    constexpr int top = (1 << bits) - 1;
    int c[D];
    for (int k = 0; k < D; ++k) {
      float q = (pos[i][k] - lo[k]) * scale[k];
      c[k] = q < 0.0f ? 0 : (q > float(top) ? top : int(q));
    }
    codes[i] = morton_encode<D>(c);
    ids[i] = i;
  }
};

// the common-prefix length of sorted codes a and b (indices into codes; -1 outside)
CPS_HD CPS_INLINE int lbvh_delta(const uint32_t* codes, int n, int a, int b) {
  if (b < 0 || b >= n) return -1;
  uint32_t x = codes[a] ^ codes[b];
  if (x == 0) return 32 + lbvh_clz(uint32_t(a) ^ uint32_t(b));
  return lbvh_clz(x);
}

struct LbvhBuildFn {
  const uint32_t* codes;
  int n;
  int* left;    // n - 1 internal nodes
  int* right;
  int* parent;  // 2n - 1 nodes (the root's: -1)
  int* visits;  // n - 1 counters, zeroed here for the fit
  int* rightmost;  // n - 1: the last leaf (sorted slot) under each internal node
  CPS_HD void operator()(int i) const {
    visits[i] = 0;
    if (i == 0) parent[0] = -1;
    const int d = lbvh_delta(codes, n, i, i + 1) - lbvh_delta(codes, n, i, i - 1) >= 0 ? 1 : -1;
    const int dmin = lbvh_delta(codes, n, i, i - d);
    int lmax = 2;
    while (lbvh_delta(codes, n, i, i + lmax * d) > dmin) lmax <<= 1;
    int l = 0;
    for (int t = lmax >> 1; t >= 1; t >>= 1)
      if (lbvh_delta(codes, n, i, i + (l + t) * d) > dmin) l += t;
    const int j = i + l * d;
    const int dnode = lbvh_delta(codes, n, i, j);
    int s = 0;
    int t = l;
    do {
      t = (t + 1) >> 1;
      if (lbvh_delta(codes, n, i, i + (s + t) * d) > dnode) s += t;
    } while (t > 1);
    const int g = i + s * d + (d < 0 ? -1 : 0);
    const int lo = i < j ? i : j, hi = i < j ? j : i;
    const int a = lo == g ? (n - 1) + g : g;
    const int b = hi == g + 1 ? (n - 1) + g + 1 : g + 1;
    left[i] = a;
    right[i] = b;
    rightmost[i] = hi;
    parent[a] = i;
    parent[b] = i;
  }
};

template <int D>
struct LbvhFitFn {
  const Vec<D>* pos;  // sorted
  int n;
  const int* left;
  const int* right;
  const int* parent;
  int* visits;
  float* boxes;  // n - 1 boxes of 2 D floats (lo, hi)
  CPS_HD void child_box(int c, float* lo, float* hi) const {
    if (c >= n - 1) {
      const Vec<D>& p = pos[c - (n - 1)];
      for (int k = 0; k < D; ++k) lo[k] = hi[k] = p[k];
    } else {
      const float* b = boxes + 2 * D * c;
      for (int k = 0; k < D; ++k) {
        lo[k] = lbvh_load(b + k);
        hi[k] = lbvh_load(b + D + k);
      }
    }
  }
  CPS_HD void operator()(int leaf) const {
    int node = parent[(n - 1) + leaf];
    while (node >= 0) {
      if (lbvh_arrive(&visits[node]) == 0) return;  // the sibling's box is not ready: it goes on
      float l0[D], h0[D], l1[D], h1[D];
      child_box(left[node], l0, h0);
      child_box(right[node], l1, h1);
      float* b = boxes + 2 * D * node;
      for (int k = 0; k < D; ++k) {
        b[k] = l0[k] < l1[k] ? l0[k] : l1[k];
        b[D + k] = h0[k] > h1[k] ? h0[k] : h1[k];
      }
      node = parent[node];
    }
  }
};

template <int D>
struct LbvhView {
  static constexpr int kDim = D;
  const Vec<D>* pos = nullptr;  // sorted along the curve
  const int* left = nullptr;
  const int* right = nullptr;
  const int* rightmost = nullptr;
  const float* boxes = nullptr;
  int n = 0;
  float radius = 0.0f;
  int* overflow = nullptr;  // raised (overflow_code, if still 0) when a traversal stack would overflow
  int overflow_code = 1;

  CPS_HD int size() const { return n; }
  CPS_HD bool active(int) const { return true; }
  CPS_HD const Vec<D>& position(int i) const { return pos[i]; }
  CPS_HD float max_radius() const { return radius; }

  // every slot j whose position lies in the box [qlo, qhi] (tree order)
  template <class Visit>
  CPS_HD void query_box(const float* qlo, const float* qhi, Visit&& visit) const {
    if (n == 1) {
      bool in = true;
      for (int k = 0; k < D; ++k) in = in && pos[0][k] >= qlo[k] && pos[0][k] <= qhi[k];
      if (in) visit(0);
      return;
    }
    int stack[kLbvhStack];
    int sp = 0;
    stack[sp++] = 0;
    while (sp > 0) {
      const int node = stack[--sp];
      const int kids[2] = {left[node], right[node]};
      for (int c = 1; c >= 0; --c) {  // the right child pushed first: the left one is walked first
        const int ch = kids[c];
        if (ch >= n - 1) {
          const int j = ch - (n - 1);
          bool in = true;
          for (int k = 0; k < D; ++k) in = in && pos[j][k] >= qlo[k] && pos[j][k] <= qhi[k];
          if (in) visit(j);
        } else {
          const float* b = boxes + 2 * D * ch;
          bool hit = true;
          for (int k = 0; k < D; ++k) hit = hit && b[k] <= qhi[k] && b[D + k] >= qlo[k];
          if (!hit) continue;
          if (sp == kLbvhStack) {
            atomic_cas(overflow, 0, overflow_code);
            continue;
          }
          stack[sp++] = ch;
        }
      }
    }
  }

  // every slot j > i whose position lies in the box: the reflexive traversal, which skips a
  // subtree whose rightmost leaf is not to the right of i (each pair is met once, by its
  // lower slot)
  template <class Visit>
  CPS_HD void query_box_after(int i, const float* qlo, const float* qhi, Visit&& visit) const {
    if (n == 1) return;
    int stack[kLbvhStack];
    int sp = 0;
    stack[sp++] = 0;
    while (sp > 0) {
      const int node = stack[--sp];
      const int kids[2] = {left[node], right[node]};
      for (int c = 1; c >= 0; --c) {
        const int ch = kids[c];
        if (ch >= n - 1) {
          const int j = ch - (n - 1);
          if (j <= i) continue;
          bool in = true;
          for (int k = 0; k < D; ++k) in = in && pos[j][k] >= qlo[k] && pos[j][k] <= qhi[k];
          if (in) visit(j);
        } else {
          if (rightmost[ch] <= i) continue;  // no leaf right of i below it
          const float* b = boxes + 2 * D * ch;
          bool hit = true;
          for (int k = 0; k < D; ++k) hit = hit && b[k] <= qhi[k] && b[D + k] >= qlo[k];
          if (!hit) continue;
          if (sp == kLbvhStack) {
            atomic_cas(overflow, 0, overflow_code);
            continue;
          }
          stack[sp++] = ch;
        }
      }
    }
  }

  template <class Visit>
  CPS_HD void pairs(int i, const Vec<D>& xi, Visit&& visit) const {
    float qlo[D], qhi[D];
    for (int k = 0; k < D; ++k) {
      qlo[k] = xi[k] - radius;
      qhi[k] = xi[k] + radius;
    }
    const float r2 = radius * radius;
    query_box_after(i, qlo, qhi, [&](int j) {
      Vec<D> d = xi - pos[j];
      float rr = norm2(d);
      if (rr < r2) visit(j, d, rr);
    });
  }

  template <class Visit>
  CPS_HD void gather(int /*i*/, const Vec<D>& xi, Visit&& visit) const {
    float qlo[D], qhi[D];
    for (int k = 0; k < D; ++k) {
      qlo[k] = xi[k] - radius;
      qhi[k] = xi[k] + radius;
    }
    const float r2 = radius * radius;
    query_box(qlo, qhi, [&](int j) {
      Vec<D> d = xi - pos[j];
      float rr = norm2(d);
      if (rr < r2) visit(j, d, rr);
    });
  }
};

// the tree's buffers and its build on an Exec (positions are sorted by the caller between
// sort() and build(): the codes' order is the particles' order)
template <int D, class Exec>
class Lbvh {
 public:
  template <class T> using Buf = typename Exec::template Buffer<T>;
  Lbvh(const Vec<D>& lo, const Vec<D>& hi, float radius) : lo_(lo), radius_(radius) {
    const int bits = D == 3 ? 10 : 16;
    for (int k = 0; k < D; ++k) {
      float ext = hi[k] - lo[k];
      scale_[k] = ext > 0.0f ? float((1 << bits) - 1) / ext : 0.0f;
    }
  }
  void resize(int n) {
    codes_[0].resize(n);
    codes_[1].resize(n);
    ids_[0].resize(n);
    ids_[1].resize(n);
    const int m = n > 1 ? n - 1 : 1;
    left_.resize(m);
    right_.resize(m);
    visits_.resize(m);
    rightmost_.resize(m);
    parent_.resize(2 * n);
    boxes_.resize(size_t(2 * D) * m);
  }
  // Morton codes and the sort: order() maps sorted slot -> input slot
  void sort(Exec& ex, const Vec<D>* pos, int n) {
    n_ = n;
    LbvhCodesFn<D> f{pos, lo_, {}, codes_[0].data(), ids_[0].data()};
    for (int k = 0; k < D; ++k) f.scale[k] = scale_[k];
    ex.for_each(n, f);
    ex.sort_pairs(codes_[0].data(), codes_[1].data(), ids_[0].data(), ids_[1].data(), n, D == 3 ? 30 : 32);
  }
  const int* order() const { return ids_[1].data(); }
  // the hierarchy over the sorted positions
  void build(Exec& ex, const Vec<D>* sorted) {
    if (n_ < 2) return;
    ex.for_each(n_ - 1, LbvhBuildFn{codes_[1].data(), n_, left_.data(), right_.data(), parent_.data(),
                                    visits_.data(), rightmost_.data()});
    ex.for_each(n_, LbvhFitFn<D>{sorted, n_, left_.data(), right_.data(), parent_.data(), visits_.data(),
                                 boxes_.data()});
  }
  // overflow: where a traversal raises code when its stack would overflow
  LbvhView<D> view(const Vec<D>* sorted, int* overflow, int code) {
    return LbvhView<D>{sorted, left_.data(), right_.data(), rightmost_.data(), boxes_.data(), n_, radius_, overflow,
                       code};
  }

 private:
  Vec<D> lo_;
  float scale_[D];
  float radius_;
  int n_ = 0;
  Buf<uint32_t> codes_[2];
  Buf<int> ids_[2];
  Buf<int> left_, right_, parent_, visits_, rightmost_;
  Buf<float> boxes_;
};

}  // namespace cps
