// Magic 8-Ball on the CUDA backend: the shared pipeline over CudaExec, and the device list.
#include "corpuscle/core/devices.h"
#include "corpuscle/scenes/magic8ball_sim.h"
#include "cuda/exec_cuda.cuh"

namespace cps {

std::vector<GpuInfo> cuda_device_list(std::string& error) {
  std::vector<GpuInfo> out;
  int n = 0;
  cudaError_t e = cudaGetDeviceCount(&n);
  if (e != cudaSuccess) {
    error = std::string("CUDA runtime: ") + cudaGetErrorString(e);
    cudaGetLastError();
    return out;
  }
  if (n == 0) error = "no CUDA device found";
  for (int d = 0; d < n; ++d) {
    cudaDeviceProp p;
    if (cudaGetDeviceProperties(&p, d) != cudaSuccess) continue;
    GpuInfo g;
    g.name = p.name;
    g.major = p.major;
    g.minor = p.minor;
    g.memory_gib = double(p.totalGlobalMem) / (1024.0 * 1024.0 * 1024.0);
    g.multiprocessors = p.multiProcessorCount;
    out.push_back(g);
  }
  return out;
}

namespace m8 {

std::unique_ptr<Sim> make_cuda(const Model& m, const InitialState& s) {
  std::string err;
  if (cuda_device_list(err).empty()) throw Error("no usable CUDA device: " + err);
  CPS_CUDA_CHECK(cudaSetDevice(0));
  return std::make_unique<SimImpl<CudaExec>>(CudaExec(), m, s);
}

// free memory of device 0
double bytes_available_cuda() {
  std::string err;
  if (cuda_device_list(err).empty()) return 0.0;
  CPS_CUDA_CHECK(cudaSetDevice(0));
  size_t free_b = 0, total_b = 0;
  CPS_CUDA_CHECK(cudaMemGetInfo(&free_b, &total_b));
  return double(free_b);
}

}  // namespace m8
}  // namespace cps
