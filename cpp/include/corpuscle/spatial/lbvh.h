// A linear bounding-volume hierarchy over points, or over boxes (leaf_boxes: a mesh's triangles) (Karras, "Maximizing Parallelism in the
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
// 5. a gather query: each point walks the tree from the root with its query box, going down
//    into a child the box overlaps and keeping the other one (when both overlap) on a stack
//    of `stack_depth` nodes; a stack that would overflow raises `overflow` (the caller stops
//    the run) instead of silently skipping a subtree, as the original did. The walk is
//    written once (LbvhView::walk); its stack is the backend's: a local array on the CPU,
//    this thread's slice of the launch's dynamic shared memory on the device (the seed's
//    choice: the stack traffic stays on the SM, not in local memory), entry k of thread t at
//    k * blockDim + t, so a warp's lanes hit distinct banks at any depth. A kernel launched
//    with too little shared memory gets a shallower stack and raises the flag: never a
//    write past the slice (lbvh_shared_stack). Launch with Exec::for_each_shared(n, f,
//    lbvh_stack_bytes(depth)).
//
// The view answers gather(i, xi, visit) like every index (index.h): visit(j, xi - x_j, r2)
// for every j (i included) with r2 < radius^2, in an order fixed by the tree (deterministic).
#pragma once
#include <cstddef>
#include <cstdint>

#include "corpuscle/core/atomics.h"
#include "corpuscle/core/vec.h"
#include "corpuscle/spatial/morton.h"

namespace cps {

// traversal stack entries per thread: the default, and the most a scene may ask for (the size
// of the CPU's local array; on the device 128 threads x 4 bytes x depth of shared memory per
// block). The walk below keeps one entry per level where the query box overlaps both
// children, so the depth a query needs grows with the tree's depth only where the box
// straddles splits: the default wind tunnel needs 5 or 6 at 131,072 and 2,097,152 particles
// (see docs/architecture.md).
constexpr int kLbvhStack = 32;
constexpr int kLbvhMaxStack = 128;

// bytes of dynamic shared memory per thread a launch reserves for a stack of depth entries
constexpr size_t lbvh_stack_bytes(int depth) { return size_t(depth) * sizeof(int); }

// a traversal stack of `depth` entries, entry k at base[k * stride]
struct LbvhStack {
  int* base;
  int stride;
  int depth;
  CPS_HD CPS_INLINE int& at(int k) const { return base[k * stride]; }
};

#ifdef __CUDA_ARCH__
// this thread's slice of the launch's dynamic shared memory (what Exec::for_each_shared
// reserved): entry k of thread t at k * threads + t. As many entries as were asked for, or as
// fit in what the launch reserved when that is less (none: depth 0, and the first push
// raises the overflow flag)
__device__ CPS_INLINE LbvhStack lbvh_shared_stack(int depth) {
  extern __shared__ int cps_lbvh_stack_smem[];
  unsigned bytes;
  asm("mov.u32 %0, %%dynamic_smem_size;" : "=r"(bytes));
  const int threads = int(blockDim.x * blockDim.y * blockDim.z);
  const int t = int(threadIdx.x + blockDim.x * (threadIdx.y + blockDim.y * threadIdx.z));
  const int have = int(bytes / (unsigned(sizeof(int)) * unsigned(threads)));
  return LbvhStack{cps_lbvh_stack_smem + t, threads, depth < have ? depth : have};
}
#endif

// read-only loads of the tree (the read-only data path on the device)
CPS_HD CPS_INLINE int lbvh_ro(const int* p) {
#ifdef __CUDA_ARCH__
  return __ldg(p);
#else
  return *p;
#endif
}

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
  const float* leaf_boxes = nullptr;  // null: the leaves are the points; else each sorted leaf's box (lo, hi)
  CPS_HD void child_box(int c, float* lo, float* hi) const {
    if (c >= n - 1 && leaf_boxes) {
      const float* b = leaf_boxes + 2 * D * (c - (n - 1));
      for (int k = 0; k < D; ++k) {
        lo[k] = b[k];
        hi[k] = b[D + k];
      }
    } else if (c >= n - 1) {
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
  int stack_depth = kLbvhStack;  // traversal stack entries (at most kLbvhMaxStack on the CPU)
  // null: the leaves are points (particles); else boxes, 2 D floats per sorted leaf (lo, hi):
  // a tree over objects with extent (spatial/triangle_tree.h: a mesh's triangles), whose walk
  // visits every leaf whose box overlaps the query box
  const float* leaf_boxes = nullptr;

  CPS_HD int size() const { return n; }
  CPS_HD bool active(int) const { return true; }
  CPS_HD const Vec<D>& position(int i) const { return pos[i]; }
  CPS_HD float max_radius() const { return radius; }

  // does the query box [qlo, qhi] overlap internal node c's box?
  CPS_HD CPS_INLINE bool overlaps(int c, const float* qlo, const float* qhi) const {
    const float* b = boxes + 2 * D * c;
#ifdef __CUDA_ARCH__
    if constexpr (D == 2) {  // one 16-byte load: lo x, lo y, hi x, hi y
      const float4 q = __ldg(reinterpret_cast<const float4*>(b));
      return q.x <= qhi[0] && q.y <= qhi[1] && q.z >= qlo[0] && q.w >= qlo[1];
    }
#endif
    bool hit = true;
    for (int k = 0; k < D; ++k) hit = hit && b[k] <= qhi[k] && b[D + k] >= qlo[k];
    return hit;
  }
  CPS_HD CPS_INLINE bool in_box(int j, const float* qlo, const float* qhi) const {
    if (leaf_boxes) {
      const float* b = leaf_boxes + 2 * D * j;
      bool hit = true;
      for (int k = 0; k < D; ++k) hit = hit && b[k] <= qhi[k] && b[D + k] >= qlo[k];
      return hit;
    }
    bool in = true;
    for (int k = 0; k < D; ++k) in = in && pos[j][k] >= qlo[k] && pos[j][k] <= qhi[k];
    return in;
  }

  // The walk, written once for both queries and every backend: from the root, each node's
  // children are met right one first (a leaf child is visited there and then), and the walk
  // goes down into the left child the box overlaps, keeping the right one on the stack when
  // both do (the order of the stack traversal that pushed both: the same leaves in the same
  // order). kAfter: only slots j > i, and subtrees whose rightmost leaf is not right of i
  // are skipped (the reflexive traversal: each pair met once, by its lower slot). A push
  // onto a full stack raises the overflow flag and skips that subtree (the caller discards
  // the step and stops the run).
  template <bool kAfter, class Visit>
  CPS_HD void walk(const LbvhStack& st, int i, const float* qlo, const float* qhi, Visit& visit) const {
    if (n == 1) {
      if (!kAfter && in_box(0, qlo, qhi)) visit(0);
      return;
    }
    int node = 0, sp = 0;
    for (;;) {
      const int kids[2] = {lbvh_ro(left + node), lbvh_ro(right + node)};
      bool down[2] = {false, false};
      for (int c = 1; c >= 0; --c) {
        const int ch = kids[c];
        if (ch >= n - 1) {
          const int j = ch - (n - 1);
          if (kAfter && j <= i) continue;
          if (in_box(j, qlo, qhi)) visit(j);
        } else {
          if (kAfter && lbvh_ro(rightmost + ch) <= i) continue;  // no leaf right of i below it
          down[c] = overlaps(ch, qlo, qhi);
        }
      }
      if (down[0]) {
        if (down[1]) {
          if (sp < st.depth) st.at(sp++) = kids[1];
          else atomic_cas(overflow, 0, overflow_code);
        }
        node = kids[0];
      } else if (down[1]) {
        node = kids[1];
      } else {
        if (sp == 0) return;
        node = st.at(--sp);
      }
    }
  }

  // the walk with the backend's stack (see the header)
  template <bool kAfter, class Visit>
  CPS_HD void walk(int i, const float* qlo, const float* qhi, Visit& visit) const {
#ifdef __CUDA_ARCH__
    walk<kAfter>(lbvh_shared_stack(stack_depth), i, qlo, qhi, visit);
#else
    int local[kLbvhMaxStack];
    walk<kAfter>(LbvhStack{local, 1, stack_depth < kLbvhMaxStack ? stack_depth : kLbvhMaxStack}, i, qlo, qhi,
                 visit);
#endif
  }

  // every slot j whose position lies in the box [qlo, qhi] (tree order)
  template <class Visit>
  CPS_HD void query_box(const float* qlo, const float* qhi, Visit&& visit) const {
    walk<false>(-1, qlo, qhi, visit);
  }

  // every slot j > i whose position lies in the box: the reflexive traversal, which skips a
  // subtree whose rightmost leaf is not to the right of i (each pair is met once, by its
  // lower slot)
  template <class Visit>
  CPS_HD void query_box_after(int i, const float* qlo, const float* qhi, Visit&& visit) const {
    walk<true>(i, qlo, qhi, visit);
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
  // the hierarchy over the sorted positions (leaf_boxes: the sorted leaves' boxes, for leaves
  // with extent; their positions then only ordered them along the curve)
  void build(Exec& ex, const Vec<D>* sorted, const float* leaf_boxes = nullptr) {
    if (n_ < 2) return;
    ex.for_each(n_ - 1, LbvhBuildFn{codes_[1].data(), n_, left_.data(), right_.data(), parent_.data(),
                                    visits_.data(), rightmost_.data()});
    ex.for_each(n_, LbvhFitFn<D>{sorted, n_, left_.data(), right_.data(), parent_.data(), visits_.data(),
                                 boxes_.data(), leaf_boxes});
  }
  // overflow: where a traversal raises code when its stack (of depth entries) would overflow
  LbvhView<D> view(const Vec<D>* sorted, int* overflow, int code, int depth = kLbvhStack) {
    return LbvhView<D>{sorted, left_.data(), right_.data(), rightmost_.data(), boxes_.data(), n_, radius_, overflow,
                       code, depth};
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
