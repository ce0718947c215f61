// Initial conditions: Poisson-disk sampling in a sphere minus a box.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/array.h>

#include <cmath>

#include "corpuscle/core/quat.h"
#include "corpuscle/physics/rigid.h"
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
        Vec3 c{{box_center[0], box_center[1], box_center[2]}};
        Vec3 half{{box_half[0], box_half[1], box_half[2]}};
        Quat q = qnormalize(Quat{box_q[0], box_q[1], box_q[2], box_q[3]});
        // inside the sphere and at least `clearance` outside the box
        auto inside = [&](const Vec3& p) {
          if (norm2(p) > radius * radius) return false;
          Vec3 n;
          return box_sdf(half, qrotate_inv(q, p - c), n) >= clearance;
        };
        double box_vol = 8.0 * double(half[0]) * half[1] * half[2];
        double volume = 4.0 / 3.0 * M_PI * double(radius) * radius * radius - box_vol;
        float r_used = 0.0f;
        std::vector<Vec3> pts;
        {
          nb::gil_scoped_release release;
          pts = poisson_disk_count(radius, count, inside, volume, seed, &r_used);
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
