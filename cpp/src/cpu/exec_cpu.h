// The CPU backend: serial or OpenMP loops over the same functors the CUDA backend launches.
//
// Reductions use a fixed chunking (kReduceChunks chunks combined in order), so serial and
// OpenMP runs produce bit-identical results; the sort is a stable sort by key, so its
// order matches CUB's stable radix sort on the device.
#pragma once
#include <algorithm>
#include <chrono>
#include <cstring>
#include <numeric>
#include <string>
#include <vector>
#ifdef CPS_WITH_OPENMP
#include <omp.h>
#include <parallel/algorithm>
#endif

#include "corpuscle/core/lanes.h"

namespace cps {

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

  // parallel_for of a functor f(i, lanes) written for cooperating lanes: one lane per item
  template <class F>
  void for_each_lanes(int n, const F& f) const {
    for_each(n, [&](int i) { f(i, SingleLane{}); });
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

  // reduce in[0, n) with op into *out, in a fixed order independent of thread count
  template <class T, class Op>
  void reduce(const T* in, int n, T* out, Op op, T init) const {
    T part[kReduceChunks];
    int chunk = (n + kReduceChunks - 1) / kReduceChunks;
    for_each(kReduceChunks, [&](int c) {
      T acc = init;
      int b = c * chunk, e = std::min(n, b + chunk);
      for (int i = b; i < e; ++i) acc = op(acc, in[i]);
      part[c] = acc;
    });
    T acc = init;
    for (int c = 0; c < kReduceChunks; ++c) acc = op(acc, part[c]);
    *out = acc;
  }

  // reduce, then run a one-item stage that reads the result
  template <class T, class Op, class F>
  void reduce_then(const T* in, int n, T* out, Op op, T init, const F& f) const {
    reduce(in, n, out, op, init);
    f(0);
  }

  void zero(void* p, size_t bytes) const { std::memset(p, 0, bytes); }
  void to_host(void* dst, const void* src, size_t bytes) const { std::memcpy(dst, src, bytes); }
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
