// The CPU backend: serial or OpenMP loops over the same functors the CUDA backend launches.
//
// Reductions use a fixed chunking (kReduceChunks chunks combined in order), so serial and
// OpenMP runs produce bit-identical results; the sort is a stable sort by key, so its
// order matches CUB's stable radix sort on the device.
//
// The engine primitives (scan, stream compaction, segmented reduce, 64-bit sort, tiles,
// flag-guarded loops) follow the same rule: their results do not depend on the thread
// count, so serial and OpenMP runs are bitwise identical.
#pragma once
#include <algorithm>
#include <chrono>
#include <cstddef>
#include <cstring>
#include <numeric>
#include <string>
#include <vector>
#ifdef CPS_WITH_OPENMP
#include <omp.h>
#include <parallel/algorithm>
#endif

#include "corpuscle/core/copies.h"
#include "corpuscle/core/lanes.h"

namespace cps {

// A tile on the CPU: the kTile lanes of a CUDA block, emulated by one thread. A tile
// functor is written in phases: code outside `lanes` runs once per tile here and on every
// thread of the block on CUDA, so it must be uniform (the same for all lanes: loop bounds,
// shared pointers, no per-lane writes); `lanes(g)` runs g(lane) for every lane (here one
// after another, on CUDA each thread its own); `sync()` separates phases (a no-op here,
// since a phase ends when its `lanes` call returns; __syncthreads on CUDA). A lane's values
// that outlive a phase live in a PerLane<T> (an array here, one register on CUDA), indexed
// by the lane. Shared memory comes from `shared<T>(count)` (the same pointer for every lane,
// uninitialised, at most the bytes given to for_each_tile in all).
template <int kTile>
struct CpuTile {
  static constexpr int kSize = kTile;
  template <class T>
  struct PerLane {
    T v[kTile];
    CPS_HD T& operator[](int lane) { return v[lane]; }
    CPS_HD const T& operator[](int lane) const { return v[lane]; }
  };

  CPS_HD static constexpr int size() { return kTile; }
  CPS_HD void sync() const {}
  template <class G>
  CPS_HD void lanes(G&& g) const {
    for (int l = 0; l < kTile; ++l) g(l);
  }
  // `count` Ts of the tile's shared memory (aligned for T); nullptr past the bytes reserved
  template <class T>
  CPS_HD T* shared(size_t count) {
    size_t at = (used_ + alignof(T) - 1) / alignof(T) * alignof(T);
    if (at + count * sizeof(T) > bytes_) return nullptr;
    used_ = at + count * sizeof(T);
    return reinterpret_cast<T*>(base_ + at);
  }

  unsigned char* base_ = nullptr;
  size_t bytes_ = 0;
  size_t used_ = 0;
};

struct CpuExec {
  bool parallel = true;

  static constexpr bool on_device = false;
  static constexpr int kReduceChunks = 64;

  // owning host buffer
  template <class T>
  struct Buffer {
    std::vector<T> v;
    void resize(size_t n) { v.assign(n, T{}); }
    T* data() { return v.data(); }
    const T* data() const { return v.data(); }
    size_t size() const { return v.size(); }
  };

  const char* name() const { return parallel ? "cpu" : "serial"; }

  // parallel_for over [0, n)
  template <class F>
  void for_each(int n, const F& f) const {
#ifdef CPS_WITH_OPENMP
    if (parallel) {
#pragma omp parallel for schedule(static)
      for (int i = 0; i < n; ++i) f(i);
      return;
    }
#endif
    for (int i = 0; i < n; ++i) f(i);
  }

  // for_each (CUDA: with launch bounds of kMinBlocks blocks per multiprocessor)
  template <int kMinBlocks, class F>
  void for_each_bounded(int n, const F& f) const {
    for_each(n, f);
  }

  // for_each(n, f): the CUDA backend gives each thread of a block bytes_per_thread of shared
  // memory (a traversal stack); here such scratch lives on the functor's own stack
  template <class F>
  void for_each_shared(int n, const F& f, size_t /*bytes_per_thread*/) const {
    for_each(n, f);
  }

  // parallel_for of a functor f(i, lanes) written for cooperating lanes: one lane per item
  template <class F>
  void for_each_lanes(int n, const F& f) const {
    for_each(n, [&](int i) { f(i, SingleLane{}); });
  }
  // the same with a stage's own lane width (the CPU runs one lane whatever W is)
  template <int W, class F>
  void for_each_lanes_w(int n, const F& f) const {
    for_each_lanes(n, f);
  }

  template <int W, int kMinBlocks, class F>
  void for_each_lanes_w_bounded(int n, const F& f) const {
    for_each_lanes(n, f);
  }

  // for_each_lanes, then reduce_then
  template <class F, class T, class Op, class Fin>
  void for_each_lanes_reduce_then(int n, const F& f, const T* items, T* out, Op op, T init, const Fin& fin) const {
    for_each_lanes(n, f);
    reduce_then(items, n, out, op, init, fin);
  }

  // a one-item stage (per-scene work)
  template <class F>
  void single(const F& f) const { f(0); }

  // stable sort of (key, value) pairs by key
  void sort_pairs(const uint32_t* kin, uint32_t* kout, const int* vin, int* vout, int n, int /*bits*/) {
    order_.resize(n);
    std::iota(order_.begin(), order_.end(), 0);
    auto less = [kin](int a, int b) { return kin[a] < kin[b]; };
#ifdef CPS_WITH_OPENMP
    if (parallel && n > 50000)
      __gnu_parallel::stable_sort(order_.begin(), order_.end(), less);
    else
#endif
      std::stable_sort(order_.begin(), order_.end(), less);
    for_each(n, [&](int j) {
      kout[j] = kin[order_[j]];
      vout[j] = vin[order_[j]];
    });
  }

  // sort when enabled(), then run a stage over the n slots
  template <class E, class F>
  void sort_then(const uint32_t* kin, uint32_t* kout, const int* vin, int* vout, int n, int bits, const E& enabled,
                 const F& f) {
    if (enabled()) sort_pairs(kin, kout, vin, vout, n, bits);
    for_each(n, f);
  }

  // `segments` segments of `len` slots each: a segment for which enabled(segment) has its
  // pairs sorted by key bits [0, bits), stably (the others' outputs are not written), then the
  // stage over every slot (CudaExec: a block per segment)
  static bool segment_sort_fits(int len) { return len >= 1; }
  template <class E, class F>
  void sort_segments_then(const uint32_t* kin, uint32_t* kout, const int* vin, int* vout, int segments, int len,
                          int bits, const E& enabled, const F& f) {
    if (segments <= 0 || len <= 0) return;
    const uint32_t mask = bits >= 32 ? ~uint32_t(0) : ((uint32_t(1) << bits) - 1u);
    for_each(segments, [&](int seg) {
      if (!enabled(seg)) return;
      const size_t begin = size_t(seg) * size_t(len);
      std::vector<int> order(static_cast<size_t>(len));
      std::iota(order.begin(), order.end(), 0);
      const uint32_t* k = kin + begin;
      std::stable_sort(order.begin(), order.end(), [k, mask](int a, int b) { return (k[a] & mask) < (k[b] & mask); });
      for (int t = 0; t < len; ++t) {
        kout[begin + t] = k[order[t]];
        vout[begin + t] = vin[begin + order[t]];
      }
    });
    for_each(int(size_t(segments) * size_t(len)), f);
  }

  // op over item(0), ..., item(n-1) into *out, in a fixed order independent of thread count:
  // kReduceChunks chunks, each left to right from init, then the chunks in order
  template <class Item, class T, class Op>
  void reduce_items(int n, const Item& item, T* out, Op op, T init) const {
    T part[kReduceChunks];
    const int chunk = (n + kReduceChunks - 1) / kReduceChunks;
    for_each(kReduceChunks, [&](int c) {
      T acc = init;
      const int b = c * chunk, e = std::min(n, b + chunk);
      for (int i = b; i < e; ++i) acc = op(acc, item(i));
      part[c] = acc;
    });
    T acc = init;
    for (int c = 0; c < kReduceChunks; ++c) acc = op(acc, part[c]);
    *out = acc;
  }

  // reduce in[0, n) with op into *out, in a fixed order independent of thread count
  template <class T, class Op>
  void reduce(const T* in, int n, T* out, Op op, T init) const {
    reduce_items(n, [in](int i) -> const T& { return in[i]; }, out, op, init);
  }

  // f(i) returns item i's T; op over the n items from init (op's identity) into *out, then fin(0):
  // reduce()'s chunks and order (so the same result as over stored items, bit for bit),
  // without storing them (kMinBlocks: the CUDA backend's launch bounds)
  template <int kMinBlocks = 0, class F, class T, class Op, class Fin>
  void for_each_reduce_then(int n, const F& f, T* out, Op op, T init, const Fin& fin) const {
    reduce_items(n, f, out, op, init);
    fin(0);
  }

  // reduce, then run a one-item stage that reads the result
  template <class T, class Op, class F>
  void reduce_then(const T* in, int n, T* out, Op op, T init, const F& f) const {
    reduce(in, n, out, op, init);
    f(0);
  }

  // ---- engine primitives (pointers are host memory; names match CudaExec's) ----

  // allocate b for n elements (zero-filled)
  template <class T>
  void resize(Buffer<T>& b, size_t n) const { b.resize(n); }

  // out[i] = in[0] + ... + in[i-1] (out[0] = 0), summed in U (e.g. int counts into int64
  // offsets); *total = the sum of all n (total may be out + n for CSR offsets, or null).
  // in and out must not overlap. Integer sums: the same on every backend.
  template <class T, class U>
  void exclusive_scan(const T* in, U* out, int n, U* total = nullptr) const {
    U part[kReduceChunks + 1];
    const int chunk = (n + kReduceChunks - 1) / kReduceChunks;
    for_each(kReduceChunks, [&](int c) {
      U acc = U(0);
      const int b = c * chunk, e = std::min(n, b + chunk);
      for (int i = b; i < e; ++i) acc = U(acc + U(in[i]));
      part[c + 1] = acc;
    });
    part[0] = U(0);
    for (int c = 0; c < kReduceChunks; ++c) part[c + 1] = U(part[c] + part[c + 1]);
    for_each(kReduceChunks, [&](int c) {
      U acc = part[c];
      const int b = c * chunk, e = std::min(n, b + chunk);
      for (int i = b; i < e; ++i) {
        const U v = U(in[i]);
        out[i] = acc;
        acc = U(acc + v);
      }
    });
    if (total) *total = part[kReduceChunks];
  }

  // stream compaction: the indices i with flags[i] != 0, ascending, into out_indices[0, *out_count)
  void select_flagged(const int* flags, int n, int* out_indices, int* out_count) const {
    int part[kReduceChunks + 1];
    const int chunk = (n + kReduceChunks - 1) / kReduceChunks;
    for_each(kReduceChunks, [&](int c) {
      int cnt = 0;
      const int b = c * chunk, e = std::min(n, b + chunk);
      for (int i = b; i < e; ++i) cnt += flags[i] != 0;
      part[c + 1] = cnt;
    });
    part[0] = 0;
    for (int c = 0; c < kReduceChunks; ++c) part[c + 1] += part[c];
    for_each(kReduceChunks, [&](int c) {
      int at = part[c];
      const int b = c * chunk, e = std::min(n, b + chunk);
      for (int i = b; i < e; ++i)
        if (flags[i] != 0) out_indices[at++] = i;
    });
    *out_count = part[kReduceChunks];
  }

  // out[s] = op(...op(op(init, items[offsets[s]]), items[offsets[s] + 1])..., items[offsets[s+1] - 1])
  // for s in [0, nsegments): left to right within a segment (an empty one gives init), so
  // the result does not depend on the thread count. offsets: int or int64, nsegments + 1 entries.
  template <class T, class O, class Op>
  void segmented_reduce(const T* items, const O* offsets, int nsegments, T* out, Op op, T init) const {
    for_each(nsegments, [&](int s) {
      T acc = init;
      for (O k = offsets[s]; k < offsets[s + 1]; ++k) acc = op(acc, items[k]);
      out[s] = acc;
    });
  }

  // stable sort of (64-bit key, value) pairs by the low `bits` bits of the key (CUB's radix
  // sort looks at those bits only, and so does this)
  void sort_pairs(const uint64_t* kin, uint64_t* kout, const int* vin, int* vout, int n, int bits) {
    if (n <= 0) return;
    const uint64_t mask = bits >= 64 ? ~uint64_t(0) : ((uint64_t(1) << bits) - 1u);
    order_.resize(n);
    std::iota(order_.begin(), order_.end(), 0);
    auto less = [kin, mask](int a, int b) { return (kin[a] & mask) < (kin[b] & mask); };
#ifdef CPS_WITH_OPENMP
    if (parallel && n > 50000)
      __gnu_parallel::stable_sort(order_.begin(), order_.end(), less);
    else
#endif
      std::stable_sort(order_.begin(), order_.end(), less);
    for_each(n, [&](int j) {
      kout[j] = kin[order_[j]];
      vout[j] = vin[order_[j]];
    });
  }

  // the most scratch a tile may ask for (a CPU tile's is heap memory: no device limit)
  size_t tile_shared_limit() const { return size_t(1) << 30; }

  // f(tile, CpuTile<kTile>&) for tile in [0, ntiles): CUDA runs a block of kTile threads per
  // tile; here one thread runs a tile's lanes phase by phase (see CpuTile), tiles spread over
  // the OpenMP threads, each with its own shared_bytes of scratch
  template <int kTile, class F>
  void for_each_tile(int ntiles, const F& f, size_t shared_bytes = 0) const {
    if (ntiles <= 0) return;
    const size_t words = (shared_bytes + sizeof(std::max_align_t) - 1) / sizeof(std::max_align_t);
    auto run = [&](int begin, int end, int step) {
      std::vector<std::max_align_t> scratch(words);
      for (int t = begin; t < end; t += step) {
        CpuTile<kTile> tile;
        tile.base_ = reinterpret_cast<unsigned char*>(scratch.data());
        tile.bytes_ = shared_bytes;
        f(t, tile);
      }
    };
#ifdef CPS_WITH_OPENMP
    if (parallel && ntiles > 1) {
#pragma omp parallel
      {
        // static round-robin: which thread runs a tile changes nothing in the results
        run(omp_get_thread_num(), ntiles, omp_get_num_threads());
      }
      return;
    }
#endif
    run(0, ntiles, 1);
  }

  // for_each(n, f) when *flag != 0 (flag: a value a previous stage wrote; on CUDA it is
  // read on the device, with no host round trip)
  template <class F>
  void for_each_if(const int* flag, int n, const F& f) const {
    if (*flag != 0) for_each(n, f);
  }

  // for_each_lanes_w<W>(n, f) when *flag != 0
  template <int W, class F>
  void for_each_lanes_w_if(const int* flag, int n, const F& f) const {
    if (*flag != 0) for_each_lanes(n, f);
  }

  void zero(void* p, size_t bytes) const { std::memset(p, 0, bytes); }
  void to_host(void* dst, const void* src, size_t bytes) const { std::memcpy(dst, src, bytes); }
  void to_host_many(const std::vector<HostCopy>& copies) const {
    for (const HostCopy& c : copies)
      if (c.bytes) std::memcpy(c.dst, c.src, c.bytes);
  }
  void to_device(void* dst, const void* src, size_t bytes) const { std::memcpy(dst, src, bytes); }
  void synchronize() const {}
  // a small upload ordered before the next launch (the CPU's is immediate)
  void upload_async(void* dst, const void* src, size_t bytes) const { std::memcpy(dst, src, bytes); }

  // scalar snapshots between batches of steps: the CPU's memory is the host's, so a
  // snapshot is the buffer itself
  void poll_begin(int slot, const void* src, size_t /*bytes*/) { poll_[slot & 1] = src; }
  const void* poll_wait(int slot) const { return poll_[slot & 1]; }

  // a whole step: CPU runs it directly
  template <class F>
  void launch_step(int /*parity*/, const F& enqueue) { enqueue(); }
  // body() (the launches of a part of a step) when *flag != 0: here the flag is read at once
  // (the stages before have run); CUDA skips the part inside a captured graph
  template <class F>
  void run_if(const int* flag, const F& body) {
    if (*flag != 0) body();
  }
  void reset_graphs() {}  // nothing is captured on the CPU

  // stage timing: host clock (the CPU work is synchronous)
  void profile_begin() { prof_ = true; t_last_ = clock::now(); }
  void mark(int stage) {
    if (!prof_) return;
    auto t = clock::now();
    if (stage >= int(stage_ms_.size())) stage_ms_.resize(stage + 1, 0.0);
    stage_ms_[stage] += std::chrono::duration<double, std::milli>(t - t_last_).count();
    t_last_ = t;
  }
  std::vector<double> profile_end() {
    prof_ = false;
    auto r = stage_ms_;
    stage_ms_.clear();
    return r;
  }
  // seconds for `run()` (steps), timed after a synchronise
  template <class F>
  double time(const F& run) {
    auto t0 = clock::now();
    run();
    return std::chrono::duration<double>(clock::now() - t0).count();
  }

 private:
  using clock = std::chrono::steady_clock;
  std::vector<int> order_;
  const void* poll_[2] = {nullptr, nullptr};
  bool prof_ = false;
  clock::time_point t_last_;
  std::vector<double> stage_ms_;
};

}  // namespace cps
