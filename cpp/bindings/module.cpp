// nanobind module corpuscle._core: each concept binds itself from its own file.
#include <nanobind/nanobind.h>

namespace nb = nanobind;

void bind_info(nb::module_& m);
void bind_sim(nb::module_& m);
void bind_init(nb::module_& m);
void bind_kernels(nb::module_& m);
void bind_physics(nb::module_& m);

NB_MODULE(_core, m) {
  m.doc() = "corpuscle compiled core (CPU serial/OpenMP and CUDA backends)";
  bind_info(m);
  bind_init(m);
  bind_kernels(m);
  bind_physics(m);
  bind_sim(m);
}
