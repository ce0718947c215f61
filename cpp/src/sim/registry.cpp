// The registry: which kinds exist, with which index plug-ins, and the backend dispatch.
#include "corpuscle/sim/registry.h"

#include <unistd.h>

#include <fstream>
#include <sstream>

#include "corpuscle/core/error.h"
#include "corpuscle/scenes/magic8ball/build.h"
#include "cpu/exec_cpu.h"

namespace cps {

Vec3 ParamSource::vec3(const std::string& key) const {
  auto v = numbers(key);
  if (v.size() != 3) throw Error("parameter '" + key + "' needs 3 numbers");
  return Vec3{{float(v[0]), float(v[1]), float(v[2])}};
}

const std::vector<KindInfo>& kinds() {
  static const std::vector<KindInfo> k = {{"magic8ball", m8::index_names()}};
  return k;
}

static const KindInfo& kind_of(const SimRequest& r) {
  for (const KindInfo& k : kinds()) {
    if (k.kind != r.kind) continue;
    if (!r.index.empty() && std::find(k.indexes.begin(), k.indexes.end(), r.index) == k.indexes.end()) {
      std::string names;
      for (const auto& i : k.indexes) names += (names.empty() ? "" : ", ") + i;
      throw Error(r.kind + ": unknown index '" + r.index + "' (indexes: " + names + ")");
    }
    return k;
  }
  throw Error("unknown scene kind '" + r.kind + "'");
}

std::unique_ptr<Sim> make_sim(const SimRequest& r) {
  kind_of(r);
  if (r.backend == "serial") return make_sim_cpu(r, false);
  if (r.backend == "cpu") return make_sim_cpu(r, true);
  if (r.backend == "cuda") return make_sim_cuda(r);
  throw Error("unknown backend '" + r.backend + "' (backends: serial, cpu, cuda)");
}

double bytes_needed(const SimRequest& r) {
  kind_of(r);
  return m8::bytes<CpuExec>(r);
}

// MemAvailable of /proc/meminfo (what can be allocated without swapping), else free pages
static double bytes_available_host() {
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

double bytes_available(const std::string& backend, int device) {
  return backend == "cuda" ? bytes_available_cuda(device) : bytes_available_host();
}

}  // namespace cps
