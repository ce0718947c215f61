// The registry: which kinds exist, with which index plug-ins, and the backend dispatch.
#include "corpuscle/sim/registry.h"

#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>

#include "corpuscle/core/error.h"
#include "corpuscle/sim/kinds.h"
#include "cpu/exec_cpu.h"

namespace cps {

Vec3 ParamSource::vec3(const std::string& key) const {
  auto v = numbers(key);
  if (v.size() != 3) throw Error("parameter '" + key + "' needs 3 numbers");
  return Vec3{{float(v[0]), float(v[1]), float(v[2])}};
}

const std::vector<KindInfo>& kinds() {
  static const std::vector<KindInfo> k = Kinds::infos<KindInfo>();
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
  return Kinds::with(r.kind, [&](auto kind) { return decltype(kind)::template bytes<CpuExec>(r); });
}

// MemAvailable of /proc/meminfo (what can be allocated without swapping), else free pages.
// C stdio, not iostreams: a Python process may have loaded another libstdc++ (PyTorch's
// environment does), and number extraction from a stream crashed there
static double bytes_available_host() {
  if (FILE* f = std::fopen("/proc/meminfo", "r")) {
    char line[256];
    double kib = -1.0;
    while (std::fgets(line, sizeof line, f)) {
      if (std::strncmp(line, "MemAvailable:", 13) == 0) {
        kib = std::strtod(line + 13, nullptr);
        break;
      }
    }
    std::fclose(f);
    if (kib >= 0.0) return kib * 1024.0;
  }
  long pages = sysconf(_SC_AVPHYS_PAGES), size = sysconf(_SC_PAGE_SIZE);
  return pages > 0 && size > 0 ? double(pages) * double(size) : 0.0;
}

double bytes_available(const std::string& backend, int device) {
  return backend == "cuda" ? bytes_available_cuda(device) : bytes_available_host();
}

}  // namespace cps
