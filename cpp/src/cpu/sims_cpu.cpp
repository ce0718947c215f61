// Every kind on the CPU backends (serial and OpenMP): the shared pipelines over CpuExec.
#include "corpuscle/sim/kinds.h"
#include "corpuscle/sim/registry.h"
#include "cpu/exec_cpu.h"

namespace cps {

std::unique_ptr<Sim> make_sim_cpu(const SimRequest& r, bool parallel) {
  CpuExec ex;
  ex.parallel = parallel;
  return make_kind(std::move(ex), r);
}

}  // namespace cps
