// corpuscle._core.build_info(): what was compiled and which devices are usable.
#include <nanobind/nanobind.h>
#include <nanobind/stl/string.h>

#include <string>

#ifdef CPS_WITH_OPENMP
#include <omp.h>
#endif

namespace nb = nanobind;

#include "corpuscle/core/devices.h"

void bind_info(nb::module_& m) {
  m.def("build_info", []() {
    nb::dict d;
#ifdef CPS_VERSION
    d["version"] = CPS_VERSION;
#else
    d["version"] = "unknown";
#endif
#ifdef CPS_WITH_CUDA
    d["cuda_compiled"] = true;
    d["cuda_architectures"] = CPS_CUDA_ARCHS;
#else
    d["cuda_compiled"] = false;
    d["cuda_architectures"] = "";
#endif
#ifdef CPS_WITH_OPENMP
    d["openmp"] = true;
    d["omp_threads"] = omp_get_max_threads();
#else
    d["openmp"] = false;
    d["omp_threads"] = 1;
#endif
    std::string err;
    nb::list gpus;
    for (const auto& g : cps::cuda_device_list(err)) {
      nb::dict gd;
      gd["name"] = g.name;
      gd["compute_capability"] = std::to_string(g.major) + "." + std::to_string(g.minor);
      gd["memory_gib"] = g.memory_gib;
      gd["multiprocessors"] = g.multiprocessors;
      gpus.append(gd);
    }
    d["gpus"] = gpus;
    d["gpu_error"] = err.empty() ? nb::none() : nb::cast(err);
    return d;
  }, "Build facts: version, CUDA architectures, OpenMP threads, usable GPUs (or why none).");
}
