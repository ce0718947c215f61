// Every kind on the CPU backends (serial and OpenMP): the shared pipelines over CpuExec.
#include "corpuscle/scenes/magic8ball/build.h"
#include "corpuscle/scenes/wind_tunnel/build.h"
#include "corpuscle/scenes/sph/build.h"
#include "corpuscle/sim/registry.h"
#include "cpu/exec_cpu.h"

namespace cps {

std::unique_ptr<Sim> make_sim_cpu(const SimRequest& r, bool parallel) {
  CpuExec ex;
  ex.parallel = parallel;
  if (r.kind == "magic8ball") return m8::make(std::move(ex), r);
  if (wt::is_kind(r.kind)) return wt::make(std::move(ex), r);  // wind-tunnel, wind-tunnel-3d
  if (sph::is_kind(r.kind)) return sph::make_kind(std::move(ex), r);
  throw Error("unknown scene kind '" + r.kind + "'");
}

}  // namespace cps
