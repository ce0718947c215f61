// corpuscle._testing without the CUDA backend: the CUDA entry points report why there is none.
#include "testing_ops.h"

namespace cps::testing {

namespace {
const char* kNoCuda = "this build has no CUDA backend (built with CORPUSCLE_CUDA=OFF or without a CUDA compiler)";
}

bool cuda_usable(std::string& why) {
  why = kNoCuda;
  return false;
}
std::unique_ptr<PrimOps> make_cuda_prim_ops(int) { throw Error(kNoCuda); }
std::unique_ptr<SpatialOps> make_cuda_spatial_ops(int) { throw Error(kNoCuda); }

}  // namespace cps::testing
