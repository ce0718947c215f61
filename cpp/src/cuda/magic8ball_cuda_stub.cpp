// CPU-only builds: the CUDA backend factory and device list report why there is none.
#include "corpuscle/core/devices.h"
#include "corpuscle/core/error.h"
#include "corpuscle/scenes/magic8ball_api.h"

namespace cps {

std::vector<GpuInfo> cuda_device_list(std::string& error) {
  error = "this build has no CUDA backend (built with CORPUSCLE_CUDA=OFF or without a CUDA compiler)";
  return {};
}

namespace m8 {
std::unique_ptr<Sim> make_cuda(const Model&, const InitialState&) {
  throw Error("this corpuscle build has no CUDA backend (built with CORPUSCLE_CUDA=OFF or no CUDA compiler)");
}
double bytes_available_cuda() { return 0.0; }
}  // namespace m8

}  // namespace cps
