// corpuscle._testing on the CUDA backend: the spatial indexes over CudaExec.
#include "cuda/exec_cuda.cuh"
#include "testing_ops.h"

namespace cps::testing {

std::unique_ptr<SpatialOps> make_cuda_spatial_ops(int device) {
  std::string why;
  if (!cuda_usable(why)) throw Error("no usable CUDA device: " + why);
  return std::make_unique<SpatialOpsImpl<CudaExec>>(CudaExec(device));
}

}  // namespace cps::testing
