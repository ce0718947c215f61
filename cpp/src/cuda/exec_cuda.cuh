// The CUDA backend: one-thread-per-item kernels over the shared functors, CUB for sort and
// reduce, a stream per simulation, CUDA graphs for steady-state steps, CUDA events for timing.
//
// An exec belongs to one device (CudaExec(device), or the current device when constructed
// without one): every call makes that device current before it launches or allocates.
#pragma once
#include <cuda_runtime.h>
#include <thrust/iterator/counting_iterator.h>

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cub/cub.cuh>
#include <cstdlib>
#include <cstring>
#include <string>
#include <utility>
#include <vector>

#include "corpuscle/core/error.h"
#include "corpuscle/core/copies.h"
#include "corpuscle/core/lanes.h"

namespace cps {

template <class F>
__global__ void k_for_each(int n, F f) {
  int i = int(blockIdx.x) * int(blockDim.x) + int(threadIdx.x);
  if (i < n) f(i);
}

// the same with launch bounds: kThreads a block and at least kMinBlocks blocks resident per
// multiprocessor (the compiler keeps the registers a thread uses within that)
template <int kThreads, int kMinBlocks, class F>
__global__ void __launch_bounds__(kThreads, kMinBlocks) k_for_each_bounded(int n, F f) {
  int i = int(blockIdx.x) * int(blockDim.x) + int(threadIdx.x);
  if (i < n) f(i);
}

// a warp per item: functor f(i, WarpLanes)
template <class F>
__global__ void k_for_each_warp(int n, F f) {
  int i = int((blockIdx.x * blockDim.x + threadIdx.x) >> 5);
  if (i < n) f(i, WarpLanes{});
}

// W lanes per item (a group of a warp): functor f(i, SubWarpLanes<W>); the groups of an
// item leave together, so the group masks stay whole
template <int W, class F>
__global__ void k_for_each_lanes_w(int n, F f) {
  long long t = (long long)blockIdx.x * blockDim.x + threadIdx.x;
  int i = int(t / W);
  if (i < n) f(i, SubWarpLanes<W>{});
}

// the same with launch bounds (kThreads a block, at least kMinBlocks blocks per multiprocessor)
template <int W, int kThreads, int kMinBlocks, class F>
__global__ void __launch_bounds__(kThreads, kMinBlocks) k_for_each_lanes_w_bounded(int n, F f) {
  long long t = (long long)blockIdx.x * blockDim.x + threadIdx.x;
  int i = int(t / W);
  if (i < n) f(i, SubWarpLanes<W>{});
}

// reduce in[0, n) in one block (fixed striding and tree, so the same on every run); thread
// 0 writes *out and runs f(0) on it
template <class T, class Op, class F, int kThreads>
__device__ void block_reduce_then(const T* in, int n, T* out, Op op, T init, const F& f) {
  using BlockReduce = cub::BlockReduce<T, kThreads>;
  __shared__ typename BlockReduce::TempStorage tmp;
  T acc = init;
  for (int i = int(threadIdx.x); i < n; i += kThreads) acc = op(acc, in[i]);
  T r = BlockReduce(tmp).Reduce(acc, op);
  if (threadIdx.x == 0) {
    *out = r;
    f(0);
  }
}

// one-launch reductions: every thread's writes made visible, then whether this block is the
// last of the grid to arrive (the counter counts the blocks; the last one resets it)
__device__ inline bool block_arrives_last(unsigned* counter) {
  __shared__ bool last;
  __threadfence();
  __syncthreads();
  if (threadIdx.x == 0) last = atomicAdd(counter, 1u) == gridDim.x - 1u;
  __syncthreads();
  return last;
}
// ... and the last block's part: reduce in[0, n) in a fixed order, run fin, reset the counter
// for the next launch
template <class T, class Op, class Fin, int kThreads>
__device__ void last_block_reduce_then(const T* in, int n, T* out, Op op, T init, const Fin& fin,
                                       unsigned* counter) {
  __threadfence();
  block_reduce_then<T, Op, Fin, kThreads>(in, n, out, op, init, fin);
  if (threadIdx.x == 0) *counter = 0u;
}

// a stage that does nothing (a reduction with no follow-up)
struct NoStage {
  CPS_HD void operator()(int) const {}
};

// a warp per item, then the last block to finish reduces items[0, n) in a fixed order (so
// the result does not depend on which block that is) and runs fin on the result
template <class F, class T, class Op, class Fin, int kThreads>
__global__ void __launch_bounds__(kThreads) k_for_each_warp_reduce_then(int n, F f, const T* items, T* out, Op op,
                                                                        T init, Fin fin, unsigned* counter) {
  int i = int((blockIdx.x * blockDim.x + threadIdx.x) >> 5);
  if (i < n) f(i, WarpLanes{});
  if (block_arrives_last(counter)) last_block_reduce_then<T, Op, Fin, kThreads>(items, n, out, op, init, fin, counter);
}

// f(i) returns item i (a T); a fixed grid of blocks strides over [0, n) (thread t takes t,
// t + stride, ... in order), each block reduces its threads' sums in CUB's fixed tree into
// partials[block], and the last block to finish reduces the partials in a fixed order into
// *out and runs fin on it: the items are never stored, and the result depends on n and the
// grid only (the same on every run of one device)
template <class F, class T, class Op, class Fin, int kThreads>
__device__ __forceinline__ void for_each_reduce_then_body(int n, F f, T* partials, T* out, Op op, T init,
                                                          Fin fin, unsigned* counter) {
  using BlockReduce = cub::BlockReduce<T, kThreads>;
  __shared__ typename BlockReduce::TempStorage tmp;
  T acc = init;
  const int stride = int(gridDim.x) * kThreads;
  for (int i = int(blockIdx.x) * kThreads + int(threadIdx.x); i < n; i += stride) acc = op(acc, f(i));
  const T r = BlockReduce(tmp).Reduce(acc, op);
  if (threadIdx.x == 0) partials[blockIdx.x] = r;
  if (block_arrives_last(counter))
    last_block_reduce_then<T, Op, Fin, kThreads>(partials, int(gridDim.x), out, op, init, fin, counter);
}
template <class F, class T, class Op, class Fin, int kThreads>
__global__ void __launch_bounds__(kThreads) k_for_each_reduce_then(int n, F f, T* partials, T* out, Op op, T init,
                                                                   Fin fin, unsigned* counter) {
  for_each_reduce_then_body<F, T, Op, Fin, kThreads>(n, f, partials, out, op, init, fin, counter);
}
// the same with at least kMinBlocks blocks resident per multiprocessor: the registers a thread
// may use are 64 K / (kThreads kMinBlocks) (a stage the compiler's own choice would make spill)
template <class F, class T, class Op, class Fin, int kThreads, int kMinBlocks>
__global__ void __launch_bounds__(kThreads, kMinBlocks) k_for_each_reduce_then_bounded(int n, F f, T* partials, T* out,
                                                                                    Op op, T init, Fin fin,
                                                                                    unsigned* counter) {
  for_each_reduce_then_body<F, T, Op, Fin, kThreads>(n, f, partials, out, op, init, fin, counter);
}

#if CUDART_VERSION >= 13000
// the condition of run_if's conditional node: *flag != 0
template <class Flag>
__global__ void k_set_conditional(cudaGraphConditionalHandle h, const Flag* flag) {
  cudaGraphSetConditional(h, *flag != 0 ? 1u : 0u);
}
#endif

template <class F>
__global__ void k_single(F f) {
  f(0);
}

// one-block reduction fused with a one-item stage run on the result (saves a launch)
template <class T, class Op, class F, int kThreads>
__global__ void __launch_bounds__(kThreads) k_reduce_block_then(const T* in, int n, T* out, Op op, T init, F f) {
  block_reduce_then<T, Op, F, kThreads>(in, n, out, op, init, f);
}

// CUB's block radix sort for inputs that fit one block (stable, like the device sort; slots
// past n are padded with all-ones keys, which sort last) when enabled(), then the stage f
// over the slots in the same block; when not enabled, the stage alone over all the blocks
template <int kThreads, int kItems, class E, class F>
__global__ void __launch_bounds__(kThreads) k_block_sort_then(const uint32_t* kin, uint32_t* kout, const int* vin,
                                                              int* vout, int n, int bits, E enabled, F f) {
  if (!enabled()) {
    // no sort: every block takes its share of the stage
    for (int j = int(blockIdx.x * kThreads + threadIdx.x); j < n; j += int(gridDim.x) * kThreads) f(j);
    return;
  }
  if (blockIdx.x != 0) return;
  {
    using Sort = cub::BlockRadixSort<uint32_t, kThreads, kItems, int>;
    __shared__ typename Sort::TempStorage tmp;
    uint32_t k[kItems];
    int v[kItems];
    for (int t = 0; t < kItems; ++t) {
      int idx = int(threadIdx.x) * kItems + t;
      k[t] = idx < n ? kin[idx] : 0xffffffffu;
      v[t] = idx < n ? vin[idx] : 0;
    }
    Sort(tmp).Sort(k, v, 0, bits);
    for (int t = 0; t < kItems; ++t) {
      int idx = int(threadIdx.x) * kItems + t;
      if (idx < n) {
        kout[idx] = k[t];
        vout[idx] = v[t];
      }
    }
    __syncthreads();
  }
  for (int j = int(threadIdx.x); j < n; j += kThreads) f(j);
}

// a block per segment of `len` slots (len <= kThreads * kItems): CUB's block radix sort of the
// segment's pairs over key bits [0, bits) when enabled(segment) (stable; the slots past len
// padded with all-ones keys, which sort last), then the stage f over the segment's slots
template <int kThreads, int kItems, class E, class F>
__global__ void __launch_bounds__(kThreads) k_segment_sort_then(const uint32_t* kin, uint32_t* kout, const int* vin,
                                                                int* vout, int len, int bits, E enabled, F f) {
  const int seg = int(blockIdx.x);
  const long long begin = (long long)seg * len;
  if (enabled(seg)) {
    using Sort = cub::BlockRadixSort<uint32_t, kThreads, kItems, int>;
    __shared__ typename Sort::TempStorage tmp;
    uint32_t k[kItems];
    int v[kItems];
    for (int t = 0; t < kItems; ++t) {
      const int idx = int(threadIdx.x) * kItems + t;
      k[t] = idx < len ? kin[begin + idx] : 0xffffffffu;
      v[t] = idx < len ? vin[begin + idx] : 0;
    }
    Sort(tmp).Sort(k, v, 0, bits);
    for (int t = 0; t < kItems; ++t) {
      const int idx = int(threadIdx.x) * kItems + t;
      if (idx < len) {
        kout[begin + idx] = k[t];
        vout[begin + idx] = v[t];
      }
    }
    __syncthreads();
  }
  for (int t = int(threadIdx.x); t < len; t += kThreads) f(int(begin + t));
}

// ---- engine primitives' kernels ----

// a tile on CUDA: one block of kTile threads (see CpuTile in cpu/exec_cpu.h for the phase
// rules a tile functor follows on both backends)
template <int kTile>
struct CudaTile {
  static constexpr int kSize = kTile;
  template <class T>
  struct PerLane {
    T v;
    CPS_HD T& operator[](int) { return v; }
    CPS_HD const T& operator[](int) const { return v; }
  };

  CPS_HD static constexpr int size() { return kTile; }
  CPS_HD void sync() const {
#ifdef __CUDA_ARCH__
    __syncthreads();
#endif
  }
  template <class G>
  CPS_HD void lanes(G&& g) const {
#ifdef __CUDA_ARCH__
    g(int(threadIdx.x));
#endif
  }
  // `count` Ts of the block's dynamic shared memory (aligned for T); nullptr past the bytes reserved
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

template <int kTile, class F>
__global__ void __launch_bounds__(kTile) k_for_each_tile(int ntiles, F f, size_t bytes) {
  extern __shared__ __align__(16) unsigned char cps_tile_smem[];
  CudaTile<kTile> t;
  t.base_ = cps_tile_smem;
  t.bytes_ = bytes;
  f(int(blockIdx.x), t);
}

// f(i) for i in [0, n) unless *flag is 0: every thread reads the flag and leaves at once (a
// grid-stride loop keeps the grid small, so a skipped stage costs one short launch)
template <class F>
__global__ void k_for_each_if(const int* flag, int n, F f) {
  if (*flag == 0) return;
  const long long stride = (long long)gridDim.x * blockDim.x;
  for (long long i = (long long)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += stride) f(int(i));
}

// the same with W lanes per item (f(i, SubWarpLanes<W>), a group of a warp per item): the
// grid strides over whole groups, so a group's lanes stay together
template <int W, class F>
__global__ void k_for_each_lanes_w_if(const int* flag, int n, F f) {
  if (*flag == 0) return;
  const long long stride = (long long)gridDim.x * blockDim.x;
  for (long long t = (long long)blockIdx.x * blockDim.x + threadIdx.x; t / W < n; t += stride)
    f(int(t / W), SubWarpLanes<W>{});
}

// the sum of a scan's n inputs: its last output plus its last input
template <class T, class U>
__global__ void k_scan_total(const T* in, const U* out, int n, U* total) {
  *total = n > 0 ? U(out[n - 1] + U(in[n - 1])) : U(0);
}

// the scan's operator: sums in the output type U
template <class U>
struct ScanPlus {
  CPS_HD U operator()(const U& a, const U& b) const { return U(a + b); }
};

struct CudaExec {
  static constexpr bool on_device = true;
  static constexpr int kBlock = 128;
  static constexpr int kMaxDevices = 64;  // devices a per-device cache of function attributes covers
  static constexpr int kReduceThreads = 512;
  static constexpr int kSmallReduce = 1 << 14;

  // owning device buffer (zero-filled)
  template <class T>
  struct Buffer {
    T* p = nullptr;
    size_t n = 0;
    Buffer() = default;
    Buffer(const Buffer&) = delete;
    Buffer& operator=(const Buffer&) = delete;
    Buffer(Buffer&& o) noexcept : p(std::exchange(o.p, nullptr)), n(std::exchange(o.n, 0)) {}
    ~Buffer() { if (p) cudaFree(p); }
    void resize(size_t count) {
      if (p) CPS_CUDA_CHECK(cudaFree(p));
      p = nullptr;
      n = count;
      if (count == 0) return;
      CPS_CUDA_CHECK(cudaMalloc(&p, count * sizeof(T)));
      CPS_CUDA_CHECK(cudaMemset(p, 0, count * sizeof(T)));
    }
    T* data() { return p; }
    const T* data() const { return p; }
    size_t size() const { return n; }
  };

  // the current device
  CudaExec() : CudaExec(current_device()) {}
  // device `device` (made current; later calls make it current again before launching or
  // allocating, so several execs may share a host thread)
  explicit CudaExec(int device) : device_(device) {
    int count = 0;
    CPS_CUDA_CHECK(cudaGetDeviceCount(&count));
    if (device < 0 || device >= count)
      throw Error("CUDA device " + std::to_string(device) + " does not exist (" + std::to_string(count) +
                  " device" + (count == 1 ? "" : "s") + ")");
    CPS_CUDA_CHECK(cudaSetDevice(device_));
    CPS_CUDA_CHECK(cudaDeviceGetAttribute(&sms_, cudaDevAttrMultiProcessorCount, device_));
    CPS_CUDA_CHECK(cudaStreamCreateWithFlags(&stream_, cudaStreamNonBlocking));
  }
  CudaExec(CudaExec&& o) noexcept
      : device_(o.device_), sms_(o.sms_), stream_(std::exchange(o.stream_, nullptr)),
        side_(std::exchange(o.side_, nullptr)),
        temp_(std::exchange(o.temp_, nullptr)), temp_bytes_(std::exchange(o.temp_bytes_, 0)),
        counter_(std::exchange(o.counter_, nullptr)), poll_bytes_(std::exchange(o.poll_bytes_, 0)),
        stage_host_(std::exchange(o.stage_host_, nullptr)), stage_event_(std::exchange(o.stage_event_, nullptr)),
        stage_bytes_(std::exchange(o.stage_bytes_, 0)), frame_host_(std::exchange(o.frame_host_, nullptr)),
        frame_bytes_(std::exchange(o.frame_bytes_, 0)) {
    for (int p = 0; p < 2; ++p) {
      graph_[p] = std::exchange(o.graph_[p], nullptr);
      eager_[p] = o.eager_[p];
      poll_host_[p] = std::exchange(o.poll_host_[p], nullptr);
      poll_event_[p] = std::exchange(o.poll_event_[p], nullptr);
    }
  }
  CudaExec(const CudaExec&) = delete;
  ~CudaExec() {
    if (stream_) cudaSetDevice(device_);
    for (auto& g : graph_)
      if (g) cudaGraphExecDestroy(g);
    for (auto& e : events_) cudaEventDestroy(e.second);
    if (temp_) cudaFree(temp_);
    if (counter_) cudaFree(counter_);
    for (int k = 0; k < 2; ++k) {
      if (poll_host_[k]) cudaFreeHost(poll_host_[k]);
      if (poll_event_[k]) cudaEventDestroy(poll_event_[k]);
    }
    if (stage_host_) cudaFreeHost(stage_host_);
    if (stage_event_) cudaEventDestroy(stage_event_);
    if (frame_host_) cudaFreeHost(frame_host_);
    if (side_) cudaStreamDestroy(side_);
    if (stream_) cudaStreamDestroy(stream_);
  }

  const char* name() const { return "cuda"; }
  int device() const { return device_; }
  // make this exec's device current (Buffer::resize allocates on the current device: call it
  // first, or use resize(buffer, n), where several devices are in use)
  void activate() const {
    int cur = -1;
    if (cudaGetDevice(&cur) != cudaSuccess || cur != device_) CPS_CUDA_CHECK(cudaSetDevice(device_));
  }

  template <class F>
  void for_each(int n, const F& f) {
    activate();
    if (n <= 0) return;
    k_for_each<<<(n + kBlock - 1) / kBlock, kBlock, 0, stream_>>>(n, f);
    CPS_CUDA_LAUNCH_CHECK();
  }

  // for_each with kMinBlocks blocks of kBlock threads resident per multiprocessor (a heavy
  // stage whose registers would otherwise limit its occupancy)
  template <int kMinBlocks, class F>
  void for_each_bounded(int n, const F& f) {
    activate();
    if (n <= 0) return;
    k_for_each_bounded<kBlock, kMinBlocks><<<(n + kBlock - 1) / kBlock, kBlock, 0, stream_>>>(n, f);
    CPS_CUDA_LAUNCH_CHECK();
  }

  // for_each(n, f) with bytes_per_thread of the block's dynamic shared memory for each of its
  // threads (a traversal stack: spatial/lbvh.h's lbvh_shared_stack finds its slice and its
  // size from the launch); more than 48 KiB a block is requested from the device
  template <class F>
  void for_each_shared(int n, const F& f, size_t bytes_per_thread) {
    activate();
    if (n <= 0) return;
    const size_t bytes = bytes_per_thread * size_t(kBlock);
    if (bytes > 48 * 1024) {
      // once per kernel, device and size (the first, eager step: not while a graph is captured)
      static std::atomic<size_t> granted[kMaxDevices] = {};
      const int d = device_ >= 0 && device_ < kMaxDevices ? device_ : 0;
      if (granted[d].load() < bytes) {
        CPS_CUDA_CHECK(cudaFuncSetAttribute(k_for_each<F>, cudaFuncAttributeMaxDynamicSharedMemorySize, int(bytes)));
        granted[d].store(bytes);
      }
    }
    k_for_each<<<(n + kBlock - 1) / kBlock, kBlock, bytes, stream_>>>(n, f);
    CPS_CUDA_LAUNCH_CHECK();
  }

  template <class F>
  void for_each_lanes(int n, const F& f) {
    activate();
    if (n <= 0) return;
    long long threads = 32LL * n;
    k_for_each_warp<<<unsigned((threads + kBlock - 1) / kBlock), kBlock, 0, stream_>>>(n, f);
    CPS_CUDA_LAUNCH_CHECK();
  }

  // a stage's own lane width W (1 ... 32 lanes per item)
  template <int W, class F>
  void for_each_lanes_w(int n, const F& f) {
    activate();
    if (n <= 0) return;
    long long threads = (long long)W * n;
    k_for_each_lanes_w<W><<<unsigned((threads + kBlock - 1) / kBlock), kBlock, 0, stream_>>>(n, f);
    CPS_CUDA_LAUNCH_CHECK();
  }

  // for_each_lanes_w with kMinBlocks blocks of kBlock threads resident per multiprocessor
  template <int W, int kMinBlocks, class F>
  void for_each_lanes_w_bounded(int n, const F& f) {
    activate();
    if (n <= 0) return;
    long long threads = (long long)W * n;
    k_for_each_lanes_w_bounded<W, kBlock, kMinBlocks>
        <<<unsigned((threads + kBlock - 1) / kBlock), kBlock, 0, stream_>>>(n, f);
    CPS_CUDA_LAUNCH_CHECK();
  }

  // for_each_lanes(n, f), then reduce_then(items, n, out, op, init, fin): fused into one
  // kernel for small n (the last block reduces), two launches otherwise
  template <class F, class T, class Op, class Fin>
  void for_each_lanes_reduce_then(int n, const F& f, const T* items, T* out, Op op, T init, const Fin& fin) {
    activate();
    if (n <= 0 || n > kSmallReduce) {
      for_each_lanes(n, f);
      reduce_then(items, n, out, op, init, fin);
      return;
    }
    ensure_counter();
    long long threads = 32LL * n;
    k_for_each_warp_reduce_then<F, T, Op, Fin, kBlock>
        <<<unsigned((threads + kBlock - 1) / kBlock), kBlock, 0, stream_>>>(n, f, items, out, op, init, fin, counter_);
    CPS_CUDA_LAUNCH_CHECK();
  }

  // f(i) returns item i's T for i in [0, n); op over the items from init (op's identity) into *out, then
  // fin(0), in one kernel that never stores the items (k_for_each_reduce_then): as many
  // blocks as the device holds at once, so the last block's reduction of their partials is short
  // (kMinBlocks > 0: launch bounds of that many blocks per multiprocessor, as for_each_bounded)
  static constexpr int kFusedThreads = 256;
  template <int kMinBlocks = 0, class F, class T, class Op, class Fin>
  void for_each_reduce_then(int n, const F& f, T* out, Op op, T init, const Fin& fin) {
    activate();
    using K = decltype(&k_for_each_reduce_then<F, T, Op, Fin, kFusedThreads>);
    K kernel;
    if constexpr (kMinBlocks > 0) kernel = &k_for_each_reduce_then_bounded<F, T, Op, Fin, kFusedThreads, kMinBlocks>;
    else kernel = &k_for_each_reduce_then<F, T, Op, Fin, kFusedThreads>;
    // resident blocks per multiprocessor, once per kernel and device (not a stream operation:
    // allowed while a graph is captured)
    static std::atomic<int> resident[kMaxDevices] = {};
    const int d = device_ >= 0 && device_ < kMaxDevices ? device_ : 0;
    int per_sm = resident[d].load();
    if (per_sm <= 0) {
      CPS_CUDA_CHECK(cudaOccupancyMaxActiveBlocksPerMultiprocessor(&per_sm, kernel, kFusedThreads, 0));
      if (per_sm < 1) per_sm = 1;
      resident[d].store(per_sm);
    }
    long long blocks = (std::max(n, 1) + kFusedThreads - 1) / kFusedThreads;
    const long long cap = (long long)per_sm * (sms_ > 0 ? sms_ : 1);
    if (blocks > cap) blocks = cap;
    ensure_temp(size_t(blocks) * sizeof(T));
    ensure_counter();
    kernel<<<unsigned(blocks), kFusedThreads, 0, stream_>>>(n, f, static_cast<T*>(temp_), out, op, init, fin,
                                                            counter_);
    CPS_CUDA_LAUNCH_CHECK();
  }

  template <class F>
  void single(const F& f) {
    activate();
    k_single<<<1, 1, 0, stream_>>>(f);
    CPS_CUDA_LAUNCH_CHECK();
  }

  // CUB's stable LSD radix sort over the key bits in use when enabled() (read on the device),
  // then a stage over the slots. Sorts that fit one block run as one CUB block sort fused
  // with the stage, which skips the sort when it is not enabled; larger ones sort always.
  static constexpr int kSortThreads = 1024, kSortItems = 8;
  template <class E, class F>
  void sort_then(const uint32_t* kin, uint32_t* kout, const int* vin, int* vout, int n, int bits, const E& enabled,
                 const F& f) {
    activate();
    if (n <= kSortThreads * kSortItems) {
      const unsigned blocks = unsigned((n + kSortThreads - 1) / kSortThreads);
      k_block_sort_then<kSortThreads, kSortItems>
          <<<blocks, kSortThreads, 0, stream_>>>(kin, kout, vin, vout, n, bits, enabled, f);
      CPS_CUDA_LAUNCH_CHECK();
      return;
    }
    sort_pairs(kin, kout, vin, vout, n, bits);
    for_each(n, f);
  }

  // `segments` segments of `len` slots each: a segment for which enabled(segment) (read on
  // the device) has its pairs sorted by key bits [0, bits), stably (the others' outputs are
  // not written), then the stage over its slots: a block per segment, sized to it (up to
  // kSortThreads * kSortItems slots; segment_sort_fits)
  static constexpr int kSegmentItems = 8;
  static bool segment_sort_fits(int len) { return len >= 1 && len <= kSortThreads * kSegmentItems; }
  template <class E, class F>
  void sort_segments_then(const uint32_t* kin, uint32_t* kout, const int* vin, int* vout, int segments, int len,
                          int bits, const E& enabled, const F& f) {
    activate();
    if (segments <= 0 || len <= 0) return;
    if (!segment_sort_fits(len))
      throw Error("sort_segments_then: a segment of " + std::to_string(len) + " slots, more than " +
                  std::to_string(kSortThreads * kSegmentItems));
    const unsigned blocks = unsigned(segments);
    if (len <= 128 * kSegmentItems)
      k_segment_sort_then<128, kSegmentItems><<<blocks, 128, 0, stream_>>>(kin, kout, vin, vout, len, bits, enabled, f);
    else if (len <= 256 * kSegmentItems)
      k_segment_sort_then<256, kSegmentItems><<<blocks, 256, 0, stream_>>>(kin, kout, vin, vout, len, bits, enabled, f);
    else if (len <= 512 * kSegmentItems)
      k_segment_sort_then<512, kSegmentItems><<<blocks, 512, 0, stream_>>>(kin, kout, vin, vout, len, bits, enabled, f);
    else
      k_segment_sort_then<kSortThreads, kSegmentItems>
          <<<blocks, kSortThreads, 0, stream_>>>(kin, kout, vin, vout, len, bits, enabled, f);
    CPS_CUDA_LAUNCH_CHECK();
  }

  void sort_pairs(const uint32_t* kin, uint32_t* kout, const int* vin, int* vout, int n, int bits) {
    activate();
    size_t bytes = 0;
    CPS_CUDA_CHECK(cub::DeviceRadixSort::SortPairs(nullptr, bytes, kin, kout, vin, vout, n, 0, bits, stream_));
    ensure_temp(bytes);
    CPS_CUDA_CHECK(cub::DeviceRadixSort::SortPairs(temp_, bytes, kin, kout, vin, vout, n, 0, bits, stream_));
  }

  // deterministic reduction: one block for small inputs, CUB's device reduce beyond
  template <class T, class Op>
  void reduce(const T* in, int n, T* out, Op op, T init) {
    activate();
    if (n <= kSmallReduce) {
      k_reduce_block_then<T, Op, NoStage, kReduceThreads><<<1, kReduceThreads, 0, stream_>>>(in, n, out, op, init,
                                                                                             NoStage{});
      CPS_CUDA_LAUNCH_CHECK();
      return;
    }
    size_t bytes = 0;
    CPS_CUDA_CHECK(cub::DeviceReduce::Reduce(nullptr, bytes, in, out, n, op, init, stream_));
    ensure_temp(bytes);
    CPS_CUDA_CHECK(cub::DeviceReduce::Reduce(temp_, bytes, in, out, n, op, init, stream_));
  }

  template <class T, class Op, class F>
  void reduce_then(const T* in, int n, T* out, Op op, T init, const F& f) {
    activate();
    if (n <= kSmallReduce) {
      k_reduce_block_then<T, Op, F, kReduceThreads><<<1, kReduceThreads, 0, stream_>>>(in, n, out, op, init, f);
      CPS_CUDA_LAUNCH_CHECK();
      return;
    }
    reduce(in, n, out, op, init);
    single(f);
  }

  // ---- engine primitives (pointers are device memory; names and results match CpuExec's) ----

  // allocate b for n elements (zero-filled) on this exec's device
  template <class T>
  void resize(Buffer<T>& b, size_t n) {
    activate();
    b.resize(n);
  }

  // out[i] = in[0] + ... + in[i-1] (out[0] = 0), summed in U; *total = the sum of all n,
  // written on the device (total may be out + n for CSR offsets, or null). CUB's device
  // scan; in and out must not overlap.
  template <class T, class U>
  void exclusive_scan(const T* in, U* out, int n, U* total = nullptr) {
    activate();
    if (n > 0) {
      size_t bytes = 0;
      CPS_CUDA_CHECK(cub::DeviceScan::ExclusiveScan(nullptr, bytes, in, out, ScanPlus<U>{}, U(0), n, stream_));
      ensure_temp(bytes);
      CPS_CUDA_CHECK(cub::DeviceScan::ExclusiveScan(temp_, bytes, in, out, ScanPlus<U>{}, U(0), n, stream_));
    }
    if (total) {
      k_scan_total<<<1, 1, 0, stream_>>>(in, out, n, total);
      CPS_CUDA_LAUNCH_CHECK();
    }
  }

  // stream compaction: the indices i with flags[i] != 0, ascending, into
  // out_indices[0, *out_count) (*out_count written on the device); CUB's DeviceSelect
  void select_flagged(const int* flags, int n, int* out_indices, int* out_count) {
    activate();
    if (n <= 0) {
      CPS_CUDA_CHECK(cudaMemsetAsync(out_count, 0, sizeof(int), stream_));
      return;
    }
    thrust::counting_iterator<int> iota(0);
    size_t bytes = 0;
    CPS_CUDA_CHECK(cub::DeviceSelect::Flagged(nullptr, bytes, iota, flags, out_indices, out_count, n, stream_));
    ensure_temp(bytes);
    CPS_CUDA_CHECK(cub::DeviceSelect::Flagged(temp_, bytes, iota, flags, out_indices, out_count, n, stream_));
  }

  // out[s] = op over items[offsets[s], offsets[s+1]) seeded with init (an empty segment gives
  // init); CUB's segmented reduce: a block per segment with a fixed tree, so the same on
  // every run (float results differ from the CPU's left-to-right order by rounding only)
  template <class T, class O, class Op>
  void segmented_reduce(const T* items, const O* offsets, int nsegments, T* out, Op op, T init) {
    activate();
    if (nsegments <= 0) return;
    size_t bytes = 0;
    CPS_CUDA_CHECK(cub::DeviceSegmentedReduce::Reduce(nullptr, bytes, items, out, nsegments, offsets, offsets + 1,
                                                      op, init, stream_));
    ensure_temp(bytes);
    CPS_CUDA_CHECK(cub::DeviceSegmentedReduce::Reduce(temp_, bytes, items, out, nsegments, offsets, offsets + 1, op,
                                                      init, stream_));
  }

  // CUB's stable radix sort of (64-bit key, value) pairs over the low `bits` key bits
  void sort_pairs(const uint64_t* kin, uint64_t* kout, const int* vin, int* vout, int n, int bits) {
    activate();
    if (n <= 0) return;
    size_t bytes = 0;
    CPS_CUDA_CHECK(cub::DeviceRadixSort::SortPairs(nullptr, bytes, kin, kout, vin, vout, n, 0, bits, stream_));
    ensure_temp(bytes);
    CPS_CUDA_CHECK(cub::DeviceRadixSort::SortPairs(temp_, bytes, kin, kout, vin, vout, n, 0, bits, stream_));
  }

  // the most dynamic shared memory a tile (block) may request on this device
  size_t tile_shared_limit() const {
    int v = 0;
    CPS_CUDA_CHECK(cudaDeviceGetAttribute(&v, cudaDevAttrMaxSharedMemoryPerBlockOptin, device_));
    return size_t(v);
  }

  // f(tile, CudaTile<kTile>&) on a block of kTile threads per tile, with shared_bytes of
  // dynamic shared memory per block (more than 48 KiB is requested from the device)
  template <int kTile, class F>
  void for_each_tile(int ntiles, const F& f, size_t shared_bytes = 0) {
    static_assert(kTile >= 1 && kTile <= 1024, "a tile is one CUDA block: 1 to 1024 threads");
    activate();
    if (ntiles <= 0) return;
    if (shared_bytes > 48 * 1024)
      CPS_CUDA_CHECK(cudaFuncSetAttribute(k_for_each_tile<kTile, F>, cudaFuncAttributeMaxDynamicSharedMemorySize,
                                          int(shared_bytes)));
    k_for_each_tile<kTile, F><<<unsigned(ntiles), kTile, shared_bytes, stream_>>>(ntiles, f, shared_bytes);
    CPS_CUDA_LAUNCH_CHECK();
  }

  // for_each(n, f) unless *flag (device memory) is 0: the kernel reads the flag and returns
  // at once, so a stage can be switched off by an earlier stage without a host round trip
  // (and inside a captured graph)
  template <class F>
  void for_each_if(const int* flag, int n, const F& f) {
    activate();
    if (n <= 0) return;
    k_for_each_if<<<flagged_blocks(n), kBlock, 0, stream_>>>(flag, n, f);
    CPS_CUDA_LAUNCH_CHECK();
  }

  // for_each_lanes_w<W>(n, f) unless *flag is 0 (as for_each_if)
  template <int W, class F>
  void for_each_lanes_w_if(const int* flag, int n, const F& f) {
    static_assert(kBlock % 32 == 0, "a block holds whole warps (the groups' masks)");
    activate();
    if (n <= 0) return;
    k_for_each_lanes_w_if<W><<<flagged_blocks((long long)W * n), kBlock, 0, stream_>>>(flag, n, f);
    CPS_CUDA_LAUNCH_CHECK();
  }

  // the grid of a flagged grid-stride launch over `threads` threads: at most 16 blocks a
  // multiprocessor (a skipped launch stays one short one)
  unsigned flagged_blocks(long long threads) const {
    const long long blocks = (threads + kBlock - 1) / kBlock;
    const long long cap = 16LL * (sms_ > 0 ? sms_ : 1);
    return unsigned(blocks > cap ? cap : blocks);
  }

  void zero(void* p, size_t bytes) {
    activate();
    CPS_CUDA_CHECK(cudaMemsetAsync(p, 0, bytes, stream_));
  }
  void to_host(void* dst, const void* src, size_t bytes) {
    activate();
    CPS_CUDA_CHECK(cudaMemcpyAsync(dst, src, bytes, cudaMemcpyDeviceToHost, stream_));
    CPS_CUDA_CHECK(cudaStreamSynchronize(stream_));
  }
  // several device ranges to host memory (a frame's fields): every copy enqueued into one
  // pinned buffer, one wait for all of them, then out to the destinations
  void to_host_many(const std::vector<HostCopy>& copies) {
    activate();
    size_t total = 0;
    for (const HostCopy& c : copies) total += (c.bytes + 255) / 256 * 256;
    if (total > frame_bytes_) {
      synchronize();
      if (frame_host_) CPS_CUDA_CHECK(cudaFreeHost(frame_host_));
      frame_host_ = nullptr;
      frame_bytes_ = 0;
      CPS_CUDA_CHECK(cudaMallocHost(&frame_host_, total));
      frame_bytes_ = total;
    }
    size_t at = 0;
    for (const HostCopy& c : copies) {
      if (c.bytes) CPS_CUDA_CHECK(cudaMemcpyAsync(static_cast<char*>(frame_host_) + at, c.src, c.bytes,
                                                  cudaMemcpyDeviceToHost, stream_));
      at += (c.bytes + 255) / 256 * 256;
    }
    CPS_CUDA_CHECK(cudaStreamSynchronize(stream_));
    at = 0;
    for (const HostCopy& c : copies) {
      if (c.bytes) std::memcpy(c.dst, static_cast<const char*>(frame_host_) + at, c.bytes);
      at += (c.bytes + 255) / 256 * 256;
    }
  }
  void to_device(void* dst, const void* src, size_t bytes) {
    activate();
    CPS_CUDA_CHECK(cudaMemcpyAsync(dst, src, bytes, cudaMemcpyHostToDevice, stream_));
    CPS_CUDA_CHECK(cudaStreamSynchronize(stream_));
  }
  void synchronize() {
    activate();
    CPS_CUDA_CHECK(cudaStreamSynchronize(stream_));
  }

  // a small upload ordered before the next launch, without waiting for the device: the
  // bytes go through pinned staging (reused once its last copy has been done)
  void upload_async(void* dst, const void* src, size_t bytes) {
    activate();
    if (bytes > stage_bytes_) {
      synchronize();
      if (stage_host_) CPS_CUDA_CHECK(cudaFreeHost(stage_host_));
      CPS_CUDA_CHECK(cudaMallocHost(&stage_host_, bytes));
      if (!stage_event_) CPS_CUDA_CHECK(cudaEventCreateWithFlags(&stage_event_, cudaEventDisableTiming));
      stage_bytes_ = bytes;
    } else {
      CPS_CUDA_CHECK(cudaEventSynchronize(stage_event_));
    }
    std::memcpy(stage_host_, src, bytes);
    CPS_CUDA_CHECK(cudaMemcpyAsync(dst, stage_host_, bytes, cudaMemcpyHostToDevice, stream_));
    CPS_CUDA_CHECK(cudaEventRecord(stage_event_, stream_));
  }

  // scalar snapshots between batches of steps: an asynchronous copy into pinned host
  // memory (two slots, so one is read while the other is written) and an event per slot
  void poll_begin(int slot, const void* src, size_t bytes) {
    activate();
    slot &= 1;
    if (bytes > poll_bytes_) {
      synchronize();
      for (int k = 0; k < 2; ++k) {
        if (poll_host_[k]) CPS_CUDA_CHECK(cudaFreeHost(poll_host_[k]));
        CPS_CUDA_CHECK(cudaMallocHost(&poll_host_[k], bytes));
        if (!poll_event_[k]) CPS_CUDA_CHECK(cudaEventCreateWithFlags(&poll_event_[k], cudaEventDisableTiming));
      }
      poll_bytes_ = bytes;
    }
    CPS_CUDA_CHECK(cudaMemcpyAsync(poll_host_[slot], src, bytes, cudaMemcpyDeviceToHost, stream_));
    CPS_CUDA_CHECK(cudaEventRecord(poll_event_[slot], stream_));
  }
  const void* poll_wait(int slot) {
    activate();
    slot &= 1;
    CPS_CUDA_CHECK(cudaEventSynchronize(poll_event_[slot]));
    return poll_host_[slot];
  }

  // a whole step: the first step of each parity runs eagerly (allocating CUB's temporary
  // storage), later ones replay a CUDA graph captured once per parity
  template <class F>
  void launch_step(int parity, const F& enqueue) {
    activate();
    if (parity < 0 || profiling_ || !graphs_ || eager_[parity] < 1) {
      if (parity >= 0) eager_[parity] += 1;
      enqueue();
      return;
    }
    if (!graph_[parity]) {
      cudaGraph_t g;
      CPS_CUDA_CHECK(cudaStreamBeginCapture(stream_, cudaStreamCaptureModeThreadLocal));
      enqueue();
      CPS_CUDA_CHECK(cudaStreamEndCapture(stream_, &g));
      CPS_CUDA_CHECK(cudaGraphInstantiate(&graph_[parity], g, 0));
      CPS_CUDA_CHECK(cudaGraphDestroy(g));
    }
    CPS_CUDA_CHECK(cudaGraphLaunch(graph_[parity], stream_));
  }

  // body() (the launches of a part of a step) only when *flag != 0 (device memory, written by
  // an earlier stage): in a captured step the part becomes the body of a conditional graph node
  // (CUDA 12.4+ graphs: its launches, CUB's included, are captured into the node's body from a
  // second stream) that a one-thread kernel switches on the flag, so a skipped part costs
  // nothing of its own. Run eagerly (the first steps, profiling, no graphs), or on an older
  // runtime, the body always runs: it must give the same state when the flag is 0 (every
  // caller's body keeps the state as it was then, e.g. a sort of unchanged keys).
  template <class F>
  void run_if(const int* flag, const F& body) {
    activate();
    cudaStreamCaptureStatus st = cudaStreamCaptureStatusNone;
    CPS_CUDA_CHECK(cudaStreamIsCapturing(stream_, &st));
#if CUDART_VERSION >= 13000
    if (st == cudaStreamCaptureStatusNone && !side_ && conditionals_supported()) {
      // the body's capture stream, made while nothing is being captured
      CPS_CUDA_CHECK(cudaStreamCreateWithFlags(&side_, cudaStreamNonBlocking));
    }
    if (st == cudaStreamCaptureStatusActive && side_) {
      cudaGraph_t graph = nullptr;
      CPS_CUDA_CHECK(cudaStreamGetCaptureInfo(stream_, &st, nullptr, &graph, nullptr, nullptr, nullptr));
      cudaGraphConditionalHandle h;
      CPS_CUDA_CHECK(cudaGraphConditionalHandleCreate(&h, graph, 0u, cudaGraphCondAssignDefault));
      k_set_conditional<<<1, 1, 0, stream_>>>(h, flag);
      CPS_CUDA_LAUNCH_CHECK();
      const cudaGraphNode_t* deps = nullptr;
      size_t ndeps = 0;
      CPS_CUDA_CHECK(cudaStreamGetCaptureInfo(stream_, &st, nullptr, &graph, &deps, nullptr, &ndeps));
      cudaGraphNodeParams params = {};
      params.type = cudaGraphNodeTypeConditional;
      params.conditional.handle = h;
      params.conditional.type = cudaGraphCondTypeIf;
      params.conditional.size = 1;
      cudaGraphNode_t node;
      CPS_CUDA_CHECK(cudaGraphAddNode(&node, graph, deps, nullptr, ndeps, &params));
      CPS_CUDA_CHECK(cudaStreamUpdateCaptureDependencies(stream_, &node, nullptr, 1, cudaStreamSetCaptureDependencies));
      cudaGraph_t body_graph = params.conditional.phGraph_out[0];
      CPS_CUDA_CHECK(cudaStreamBeginCaptureToGraph(side_, body_graph, nullptr, nullptr, 0,
                                                   cudaStreamCaptureModeThreadLocal));
      // the body's launches go to the side stream (restored however the body ends)
      struct Restore {
        cudaStream_t& s;
        cudaStream_t main;
        ~Restore() { s = main; }
      } restore{stream_, stream_};
      stream_ = side_;
      body();
      stream_ = restore.main;
      CPS_CUDA_CHECK(cudaStreamEndCapture(side_, &body_graph));
      return;
    }
#endif
    (void)flag;
    body();
  }

  // stage timing with CUDA events between stages
  void profile_begin() {
    activate();
    profiling_ = true;
    marks_.clear();
    marks_.push_back({-1, event(0)});
    CPS_CUDA_CHECK(cudaEventRecord(marks_.back().second, stream_));
  }
  void mark(int stage) {
    activate();
    if (!profiling_) return;
    marks_.push_back({stage, event(marks_.size())});
    CPS_CUDA_CHECK(cudaEventRecord(marks_.back().second, stream_));
  }
  std::vector<double> profile_end() {
    activate();
    profiling_ = false;
    synchronize();
    std::vector<double> ms;
    for (size_t k = 1; k < marks_.size(); ++k) {
      float t = 0.0f;
      CPS_CUDA_CHECK(cudaEventElapsedTime(&t, marks_[k - 1].second, marks_[k].second));
      int s = marks_[k].first;
      if (s >= int(ms.size())) ms.resize(s + 1, 0.0);
      ms[s] += t;
    }
    return ms;
  }

  // seconds for run(), between two events on the stream
  template <class F>
  double time(const F& run) {
    activate();
    cudaEvent_t a = event(0), b = event(1);
    CPS_CUDA_CHECK(cudaEventRecord(a, stream_));
    run();
    CPS_CUDA_CHECK(cudaEventRecord(b, stream_));
    CPS_CUDA_CHECK(cudaEventSynchronize(b));
    float ms = 0.0f;
    CPS_CUDA_CHECK(cudaEventElapsedTime(&ms, a, b));
    return ms * 1e-3;
  }

  void set_graphs(bool on) { graphs_ = on; }
  // forget the captured steps (a buffer they name was reallocated): the next steps run
  // eagerly once per parity and are captured again
  void reset_graphs() {
    synchronize();
    for (int p = 0; p < 2; ++p) {
      if (graph_[p]) CPS_CUDA_CHECK(cudaGraphExecDestroy(graph_[p]));
      graph_[p] = nullptr;
      eager_[p] = 0;
    }
  }

 private:
  static int current_device() {
    int d = 0;
    CPS_CUDA_CHECK(cudaGetDevice(&d));
    return d;
  }

  // the last-block counter of the fused kernels (zero between launches)
  void ensure_counter() {
    if (counter_) return;
    CPS_CUDA_CHECK(cudaMalloc(&counter_, sizeof(unsigned)));
    CPS_CUDA_CHECK(cudaMemset(counter_, 0, sizeof(unsigned)));
  }

#if CUDART_VERSION >= 13000
  // conditional graph nodes with memsets in their bodies: a driver of CUDA 12.4 or later;
  // CORPUSCLE_GRAPH_CONDITIONALS=0 in the environment turns them off (run_if's body then runs
  // on every step, as before they were used: for timing one against the other)
  static bool conditionals_supported() {
    static const bool ok = [] {
      const char* e = std::getenv("CORPUSCLE_GRAPH_CONDITIONALS");
      if (e && std::strcmp(e, "0") == 0) return false;
      int v = 0;
      return cudaDriverGetVersion(&v) == cudaSuccess && v >= 12040;
    }();
    return ok;
  }
#endif

  void ensure_temp(size_t bytes) {
    activate();
    if (bytes <= temp_bytes_) return;
    cudaStreamCaptureStatus st;
    CPS_CUDA_CHECK(cudaStreamIsCapturing(stream_, &st));
    if (st != cudaStreamCaptureStatusNone) throw Error("CUB temporary storage grew during graph capture");
    CPS_CUDA_CHECK(cudaStreamSynchronize(stream_));
    if (temp_) CPS_CUDA_CHECK(cudaFree(temp_));
    CPS_CUDA_CHECK(cudaMalloc(&temp_, bytes));
    temp_bytes_ = bytes;
  }
  // a pooled event (index k)
  cudaEvent_t event(size_t k) {
    activate();
    while (events_.size() <= k) {
      cudaEvent_t e;
      CPS_CUDA_CHECK(cudaEventCreate(&e));
      events_.push_back({int(events_.size()), e});
    }
    return events_[k].second;
  }

  int device_ = 0;
  int sms_ = 0;  // multiprocessors of the device
  cudaStream_t stream_ = nullptr;
  cudaStream_t side_ = nullptr;  // run_if's capture stream for conditional bodies
  void* temp_ = nullptr;
  size_t temp_bytes_ = 0;
  unsigned* counter_ = nullptr;  // blocks finished, for the fused reduction
  void* poll_host_[2] = {nullptr, nullptr};
  cudaEvent_t poll_event_[2] = {nullptr, nullptr};
  size_t poll_bytes_ = 0;
  void* stage_host_ = nullptr;
  cudaEvent_t stage_event_ = nullptr;
  size_t stage_bytes_ = 0;
  void* frame_host_ = nullptr;  // to_host_many's pinned buffer
  size_t frame_bytes_ = 0;
  cudaGraphExec_t graph_[2] = {nullptr, nullptr};
  int eager_[2] = {0, 0};
  bool graphs_ = true;
  bool profiling_ = false;
  std::vector<std::pair<int, cudaEvent_t>> marks_;
  std::vector<std::pair<int, cudaEvent_t>> events_;
};

}  // namespace cps
