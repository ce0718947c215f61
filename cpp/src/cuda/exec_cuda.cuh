// The CUDA backend: one-thread-per-item kernels over the shared functors, CUB for sort and
// reduce, a stream per simulation, CUDA graphs for steady-state steps, CUDA events for timing.
#pragma once
#include <cuda_runtime.h>

#include <cub/cub.cuh>
#include <cstring>
#include <utility>
#include <vector>

#include "corpuscle/core/error.h"
#include "corpuscle/core/lanes.h"

namespace cps {

template <class F>
__global__ void k_for_each(int n, F f) {
  int i = int(blockIdx.x) * int(blockDim.x) + int(threadIdx.x);
  if (i < n) f(i);
}

// a warp per item: functor f(i, WarpLanes)
template <class F>
__global__ void k_for_each_warp(int n, F f) {
  int i = int((blockIdx.x * blockDim.x + threadIdx.x) >> 5);
  if (i < n) f(i, WarpLanes{});
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
  __shared__ bool last;
  __threadfence();
  __syncthreads();
  if (threadIdx.x == 0) last = atomicAdd(counter, 1u) == gridDim.x - 1u;
  __syncthreads();
  if (!last) return;
  __threadfence();
  block_reduce_then<T, Op, Fin, kThreads>(items, n, out, op, init, fin);
  if (threadIdx.x == 0) *counter = 0u;  // ready for the next launch
}

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

struct CudaExec {
  static constexpr bool on_device = true;
  static constexpr int kBlock = 128;
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

  CudaExec() {
    CPS_CUDA_CHECK(cudaStreamCreateWithFlags(&stream_, cudaStreamNonBlocking));
  }
  CudaExec(CudaExec&& o) noexcept
      : stream_(std::exchange(o.stream_, nullptr)), temp_(std::exchange(o.temp_, nullptr)),
        temp_bytes_(std::exchange(o.temp_bytes_, 0)), counter_(std::exchange(o.counter_, nullptr)),
        poll_bytes_(std::exchange(o.poll_bytes_, 0)), stage_host_(std::exchange(o.stage_host_, nullptr)),
        stage_event_(std::exchange(o.stage_event_, nullptr)), stage_bytes_(std::exchange(o.stage_bytes_, 0)) {
    for (int p = 0; p < 2; ++p) {
      graph_[p] = std::exchange(o.graph_[p], nullptr);
      eager_[p] = o.eager_[p];
      poll_host_[p] = std::exchange(o.poll_host_[p], nullptr);
      poll_event_[p] = std::exchange(o.poll_event_[p], nullptr);
    }
  }
  CudaExec(const CudaExec&) = delete;
  ~CudaExec() {
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
    if (stream_) cudaStreamDestroy(stream_);
  }

  const char* name() const { return "cuda"; }

  template <class F>
  void for_each(int n, const F& f) {
    if (n <= 0) return;
    k_for_each<<<(n + kBlock - 1) / kBlock, kBlock, 0, stream_>>>(n, f);
    CPS_CUDA_LAUNCH_CHECK();
  }

  template <class F>
  void for_each_lanes(int n, const F& f) {
    if (n <= 0) return;
    long long threads = 32LL * n;
    k_for_each_warp<<<unsigned((threads + kBlock - 1) / kBlock), kBlock, 0, stream_>>>(n, f);
    CPS_CUDA_LAUNCH_CHECK();
  }

  // for_each_lanes(n, f), then reduce_then(items, n, out, op, init, fin): fused into one
  // kernel for small n (the last block reduces), two launches otherwise
  template <class F, class T, class Op, class Fin>
  void for_each_lanes_reduce_then(int n, const F& f, const T* items, T* out, Op op, T init, const Fin& fin) {
    if (n <= 0 || n > kSmallReduce) {
      for_each_lanes(n, f);
      reduce_then(items, n, out, op, init, fin);
      return;
    }
    if (!counter_) {
      CPS_CUDA_CHECK(cudaMalloc(&counter_, sizeof(unsigned)));
      CPS_CUDA_CHECK(cudaMemset(counter_, 0, sizeof(unsigned)));
    }
    long long threads = 32LL * n;
    k_for_each_warp_reduce_then<F, T, Op, Fin, kBlock>
        <<<unsigned((threads + kBlock - 1) / kBlock), kBlock, 0, stream_>>>(n, f, items, out, op, init, fin, counter_);
    CPS_CUDA_LAUNCH_CHECK();
  }

  template <class F>
  void single(const F& f) {
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

  void sort_pairs(const uint32_t* kin, uint32_t* kout, const int* vin, int* vout, int n, int bits) {
    size_t bytes = 0;
    CPS_CUDA_CHECK(cub::DeviceRadixSort::SortPairs(nullptr, bytes, kin, kout, vin, vout, n, 0, bits, stream_));
    ensure_temp(bytes);
    CPS_CUDA_CHECK(cub::DeviceRadixSort::SortPairs(temp_, bytes, kin, kout, vin, vout, n, 0, bits, stream_));
  }

  // deterministic reduction: one block for small inputs, CUB's device reduce beyond
  template <class T, class Op>
  void reduce(const T* in, int n, T* out, Op op, T init) {
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
    if (n <= kSmallReduce) {
      k_reduce_block_then<T, Op, F, kReduceThreads><<<1, kReduceThreads, 0, stream_>>>(in, n, out, op, init, f);
      CPS_CUDA_LAUNCH_CHECK();
      return;
    }
    reduce(in, n, out, op, init);
    single(f);
  }

  void zero(void* p, size_t bytes) { CPS_CUDA_CHECK(cudaMemsetAsync(p, 0, bytes, stream_)); }
  void to_host(void* dst, const void* src, size_t bytes) {
    CPS_CUDA_CHECK(cudaMemcpyAsync(dst, src, bytes, cudaMemcpyDeviceToHost, stream_));
    CPS_CUDA_CHECK(cudaStreamSynchronize(stream_));
  }
  void to_device(void* dst, const void* src, size_t bytes) {
    CPS_CUDA_CHECK(cudaMemcpyAsync(dst, src, bytes, cudaMemcpyHostToDevice, stream_));
    CPS_CUDA_CHECK(cudaStreamSynchronize(stream_));
  }
  void synchronize() { CPS_CUDA_CHECK(cudaStreamSynchronize(stream_)); }

  // a small upload ordered before the next launch, without waiting for the device: the
  // bytes go through pinned staging (reused once its last copy has been done)
  void upload_async(void* dst, const void* src, size_t bytes) {
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
    slot &= 1;
    CPS_CUDA_CHECK(cudaEventSynchronize(poll_event_[slot]));
    return poll_host_[slot];
  }

  // a whole step: the first step of each parity runs eagerly (allocating CUB's temporary
  // storage), later ones replay a CUDA graph captured once per parity
  template <class F>
  void launch_step(int parity, const F& enqueue) {
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

  // stage timing with CUDA events between stages
  void profile_begin() {
    profiling_ = true;
    marks_.clear();
    marks_.push_back({-1, event(0)});
    CPS_CUDA_CHECK(cudaEventRecord(marks_.back().second, stream_));
  }
  void mark(int stage) {
    if (!profiling_) return;
    marks_.push_back({stage, event(marks_.size())});
    CPS_CUDA_CHECK(cudaEventRecord(marks_.back().second, stream_));
  }
  std::vector<double> profile_end() {
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

 private:
  void ensure_temp(size_t bytes) {
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
    while (events_.size() <= k) {
      cudaEvent_t e;
      CPS_CUDA_CHECK(cudaEventCreate(&e));
      events_.push_back({int(events_.size()), e});
    }
    return events_[k].second;
  }

  cudaStream_t stream_ = nullptr;
  void* temp_ = nullptr;
  size_t temp_bytes_ = 0;
  unsigned* counter_ = nullptr;  // blocks finished, for the fused reduction
  void* poll_host_[2] = {nullptr, nullptr};
  cudaEvent_t poll_event_[2] = {nullptr, nullptr};
  size_t poll_bytes_ = 0;
  void* stage_host_ = nullptr;
  cudaEvent_t stage_event_ = nullptr;
  size_t stage_bytes_ = 0;
  cudaGraphExec_t graph_[2] = {nullptr, nullptr};
  int eager_[2] = {0, 0};
  bool graphs_ = true;
  bool profiling_ = false;
  std::vector<std::pair<int, cudaEvent_t>> marks_;
  std::vector<std::pair<int, cudaEvent_t>> events_;
};

}  // namespace cps
