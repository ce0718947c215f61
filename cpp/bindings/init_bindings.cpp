// Initial conditions: Poisson-disk sampling in a sphere minus a box.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/array.h>

#include <cmath>

#include "corpuscle/core/quat.h"
#include "init/poisson_disk.h"

namespace nb = nanobind;
using namespace cps;

void bind_init(nb::module_& m) {
  m.def(
      "poisson_disk_sphere",
      [](float radius, int count, std::array<float, 3> box_center, std::array<float, 3> box_half,
         std::array<float, 4> box_q, float clearance, uint64_t seed) {
        if (!(radius > 0.0f)) throw nb::value_error("radius must be positive");
        if (count < 1) throw nb::value_error("count must be positive");
        // inside the sphere and at least `clearance` outside the box
        SphereMinusBox region{radius, Vec3{{box_center[0], box_center[1], box_center[2]}},
                              Vec3{{box_half[0], box_half[1], box_half[2]}},
                              qnormalize(Quat{box_q[0], box_q[1], box_q[2], box_q[3]}), clearance};
        float r_used = 0.0f;
        std::vector<Vec3> pts;
        {
          // parallel over the OpenMP threads; the points do not depend on their number
          nb::gil_scoped_release release;
          pts = poisson_disk_count(region, count, seed, &r_used);
        }
        auto* data = new float[pts.size() * 3];
        for (size_t i = 0; i < pts.size(); ++i)
          for (int k = 0; k < 3; ++k) data[3 * i + k] = pts[i][k];
        nb::capsule owner(data, [](void* p) noexcept { delete[] static_cast<float*>(p); });
        auto arr = nb::ndarray<nb::numpy, float, nb::shape<-1, 3>>(data, {pts.size(), 3}, owner);
        return nb::make_tuple(arr, r_used);
      },
      nb::arg("radius"), nb::arg("count"), nb::arg("box_center"), nb::arg("box_half"), nb::arg("box_q"),
      nb::arg("clearance"), nb::arg("seed"),
      "Poisson-disk samples (count, 3) inside a sphere, outside a box; returns (positions, spacing).");
}

#include "corpuscle/physics/sph_kernel_families.h"

// the SPH kernels evaluated at displacement vectors d (n, 3), for the kernel tests
void bind_kernels(nb::module_& m) {
  m.def(
      "sph_kernels",
      [](float h, nb::ndarray<const float, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu> d) {
        auto k = MuellerKernels<3>::make(h);
        size_t n = d.shape(0);
        auto* out = new float[n * 6];
        for (size_t i = 0; i < n; ++i) {
          Vec3 v{{d(i, 0), d(i, 1), d(i, 2)}};
          float r2 = norm2(v), r = std::sqrt(r2);
          Vec3 g = k.spiky.grad(v, r);
          out[6 * i + 0] = k.poly6.w_r2(r2);
          out[6 * i + 1] = g[0];
          out[6 * i + 2] = g[1];
          out[6 * i + 3] = g[2];
          out[6 * i + 4] = k.visc.lap(r);
          out[6 * i + 5] = KernelFormula<3, SphKernelKind::Poly6>::beyond_plane(k.poly6.k, v[2]);
        }
        nb::capsule owner(out, [](void* p) noexcept { delete[] static_cast<float*>(p); });
        return nb::ndarray<nb::numpy, float, nb::shape<-1, 6>>(out, {n, 6}, owner);
      },
      nb::arg("h"), nb::arg("d"),
      "Columns: poly6(|d|^2), spiky gradient (3), viscosity Laplacian, Poly6 fraction beyond the plane z = d_z.");
}
