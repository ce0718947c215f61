// Magic 8-Ball on the CPU backends (serial and OpenMP): the shared pipeline over CpuExec,
// and the memory a simulation needs and the host has.
#include <unistd.h>

#include <fstream>
#include <sstream>
#include <string>

#include "cpu/exec_cpu.h"
#include "corpuscle/scenes/magic8ball_sim.h"

namespace cps::m8 {

std::unique_ptr<Sim> make_cpu(const Model& m, const InitialState& s, bool parallel) {
  CpuExec ex;
  ex.parallel = parallel;
  return std::make_unique<SimImpl<CpuExec>>(ex, m, s);
}

double bytes_needed(const Model& m) { return SimImpl<CpuExec>::bytes_needed(m); }

// MemAvailable of /proc/meminfo (what can be allocated without swapping), else free pages
double bytes_available_cpu() {
  std::ifstream f("/proc/meminfo");
  std::string line;
  while (std::getline(f, line)) {
    if (line.rfind("MemAvailable:", 0) == 0) {
      std::istringstream in(line.substr(13));
      double kib = 0.0;
      if (in >> kib) return kib * 1024.0;
    }
  }
  long pages = sysconf(_SC_AVPHYS_PAGES), size = sysconf(_SC_PAGE_SIZE);
  return pages > 0 && size > 0 ? double(pages) * double(size) : 0.0;
}

}  // namespace cps::m8
