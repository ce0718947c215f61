// Magic 8-Ball on the CPU backends (serial and OpenMP): the shared pipeline over CpuExec.
#include "cpu/exec_cpu.h"
#include "corpuscle/scenes/magic8ball_sim.h"

namespace cps::m8 {

std::unique_ptr<Sim> make_cpu(const Model& m, const InitialState& s, bool parallel) {
  CpuExec ex;
  ex.parallel = parallel;
  return std::make_unique<SimImpl<CpuExec>>(ex, m, s);
}

}  // namespace cps::m8
