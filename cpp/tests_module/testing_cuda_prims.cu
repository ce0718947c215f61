// corpuscle._testing on the CUDA backend: the exec primitives over CudaExec, and whether a
// device is usable.
#include "cuda/exec_cuda.cuh"
#include "testing_ops.h"

namespace cps::testing {

bool cuda_usable(std::string& why) {
  int n = 0;
  cudaError_t e = cudaGetDeviceCount(&n);
  if (e != cudaSuccess) {
    why = std::string("CUDA runtime: ") + cudaGetErrorString(e);
    cudaGetLastError();
    return false;
  }
  if (n == 0) {
    why = "no CUDA device found";
    return false;
  }
  why.clear();
  return true;
}

std::unique_ptr<PrimOps> make_cuda_prim_ops(int device) {
  std::string why;
  if (!cuda_usable(why)) throw Error("no usable CUDA device: " + why);
  return std::make_unique<PrimOpsImpl<CudaExec>>(CudaExec(device));
}

}  // namespace cps::testing
