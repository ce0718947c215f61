// CPU-only builds: the CUDA factory and device list report why there is no CUDA backend.
#include "corpuscle/core/devices.h"
#include "corpuscle/core/error.h"
#include "corpuscle/sim/registry.h"

namespace cps {

std::vector<GpuInfo> cuda_device_list(std::string& error) {
  error = "this build has no CUDA backend (built with CORPUSCLE_CUDA=OFF or without a CUDA compiler)";
  return {};
}

std::unique_ptr<Sim> make_sim_cuda(const SimRequest&) {
  throw Error("this corpuscle build has no CUDA backend (built with CORPUSCLE_CUDA=OFF or no CUDA compiler)");
}

double bytes_available_cuda(int) { return 0.0; }

}  // namespace cps
