// Every kind on the CUDA backend: the shared pipelines over CudaExec, and the device list.
#include "corpuscle/core/devices.h"
#include "corpuscle/sim/kinds.h"
#include "corpuscle/sim/registry.h"
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

// the device to use, checked against what this machine has
static void use_device(int device) {
  std::string err;
  auto gpus = cuda_device_list(err);
  if (gpus.empty()) throw Error("no usable CUDA device: " + err);
  if (device < 0 || device >= int(gpus.size()))
    throw Error("--device " + std::to_string(device) + ": this machine has " + std::to_string(gpus.size()) +
                " CUDA device(s), numbered from 0");
  CPS_CUDA_CHECK(cudaSetDevice(device));
}

std::unique_ptr<Sim> make_sim_cuda(const SimRequest& r) {
  use_device(r.device);
  return make_kind(CudaExec(), r);
}

double bytes_available_cuda(int device) {
  use_device(device);
  size_t free_b = 0, total_b = 0;
  CPS_CUDA_CHECK(cudaMemGetInfo(&free_b, &total_b));
  return double(free_b);
}

}  // namespace cps
