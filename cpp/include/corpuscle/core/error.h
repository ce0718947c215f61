// Error helpers: CPS_CUDA_CHECK throws with file:line, the call and the CUDA message.
#pragma once
#include <stdexcept>
#include <string>

namespace cps {

struct Error : std::runtime_error {
  using std::runtime_error::runtime_error;
};

}  // namespace cps

#ifdef __CUDACC__
#define CPS_CUDA_CHECK(call)                                                                       \
  do {                                                                                             \
    cudaError_t cps_err_ = (call);                                                                 \
    if (cps_err_ != cudaSuccess)                                                                   \
      throw ::cps::Error(std::string(__FILE__) + ":" + std::to_string(__LINE__) + ": " #call ": " + \
                         cudaGetErrorString(cps_err_));                                            \
  } while (0)
#define CPS_CUDA_LAUNCH_CHECK() CPS_CUDA_CHECK(cudaGetLastError())
#endif
