// The core's closed forms that Python needs a value of (the SPH box's hydrostatic start, the
// wind tunnel's contact damping): the same template functions the core runs in float
// (physics/tait.h, physics/dem.h), evaluated here in double for Python's float64 scene keys.
// Each takes scalars (a float back) or, for its first argument, a 1-D float64 array (an array
// back, the others broadcast).
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/array.h>
#include <nanobind/stl/vector.h>

#include <cmath>
#include <cstddef>
#include <stdexcept>
#include <vector>

#include "corpuscle/physics/dem.h"
#include "corpuscle/physics/tait.h"
#include "corpuscle/scenes/sph/probe.h"
#include "corpuscle/scenes/sph/bodies.h"

#include <array>
#include <vector>

namespace nb = nanobind;
using namespace cps;

namespace {

using F64In = nb::ndarray<const double, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using F64Out = nb::ndarray<nb::numpy, double, nb::ndim<1>>;

// f(x[i], args...) for each element of x, into a new NumPy array
template <class F>
F64Out map1(const F64In& x, F f) {
  const size_t n = x.shape(0);
  auto* out = new double[n];
  const double* in = x.data();
  for (size_t i = 0; i < n; ++i) out[i] = f(in[i]);
  nb::capsule owner(out, [](void* p) noexcept { delete[] static_cast<double*>(p); });
  return F64Out(out, {n}, owner);
}

// a function of four doubles, bound for a scalar and for an array first argument
template <class F>
void def4(nb::module_& m, const char* name, F f, const char* a, const char* b, const char* c, const char* d,
          const char* doc) {
  m.def(name, [f](const F64In& x, double p, double q, double r) { return map1(x, [&](double v) { return f(v, p, q, r); }); },
        nb::arg(a), nb::arg(b), nb::arg(c), nb::arg(d), doc);
  m.def(name, [f](double x, double p, double q, double r) { return f(x, p, q, r); }, nb::arg(a), nb::arg(b),
        nb::arg(c), nb::arg(d), doc);
}

template <class F>
void def3(nb::module_& m, const char* name, F f, const char* a, const char* b, const char* c, const char* doc) {
  m.def(name, [f](const F64In& x, double p, double q) { return map1(x, [&](double v) { return f(v, p, q); }); },
        nb::arg(a), nb::arg(b), nb::arg(c), doc);
  m.def(name, [f](double x, double p, double q) { return f(x, p, q); }, nb::arg(a), nb::arg(b), nb::arg(c), doc);
}

}  // namespace

void bind_physics(nb::module_& m) {
  // a moving body's pose at time t (scenes/sph/bodies.h, the SPH box's): its build pose and the
  // checks that it stays in the tank
  m.def("sph_body_pose",
        [](int kind, std::array<double, 3> c0, std::array<double, 3> a0, std::array<double, 3> vel,
           std::array<double, 3> omega, nb::ndarray<const float, nb::ndim<2>, nb::c_contig, nb::device::cpu> table,
           double t) {
          sph::BodyMotion b{};
          b.kind = kind;
          b.row0 = 0;
          b.rows = int(table.shape(0));
          if (kind == sph::kBodyTable && (b.rows < 1 || table.shape(1) != sph::kBodyTableCols))
            throw nb::value_error("sph_body_pose: a table needs rows of 7 floats");
          for (int k = 0; k < 3; ++k) {
            b.c0[k] = c0[k];
            b.a0[k] = a0[k];
            b.vel[k] = vel[k];
            b.omega[k] = omega[k];
          }
          double out[sph::kBodyPoseFloats];
          sph::body_pose(b, table.data(), t, out);
          return std::vector<double>(out, out + sph::kBodyPoseFloats);
        },
        nb::arg("kind"), nb::arg("c0"), nb::arg("a0"), nb::arg("velocity"), nb::arg("omega"), nb::arg("table"),
        nb::arg("t"),
        "A moving body's pose at time t (scenes/sph/bodies.h, in double): 18 numbers, the reference point c (3), "
        "the rotation R (9, row-major), its velocity (3) and angular velocity (3, rad/s). kind 1: constant velocity "
        "and angular velocity from c0 and the angles a0 (degrees); kind 2: the float32 table of rows t, x, y, z, rx, "
        "ry, rz (degrees) interpolated linearly.");
  // Tait's equation of state (physics/tait.h)
  def4(m, "tait_pressure", [](double rho, double rho0, double B, double gamma) { return tait_pressure(rho, rho0, B, gamma); },
       "rho", "rho0", "B", "gamma", "Tait's pressure B ((rho / rho0)^gamma - 1) (physics/tait.h, in double).");
  def4(m, "tait_density", [](double p, double rho0, double B, double gamma) { return tait_density(p, rho0, B, gamma); },
       "p", "rho0", "B", "gamma", "Tait's density at pressure p: rho0 (1 + p / B)^(1 / gamma) (physics/tait.h).");
  def3(m, "tait_stiffness", [](double c0, double rho0, double gamma) { return tait_stiffness(c0, rho0, gamma); },
       "c0", "rho0", "gamma", "Tait's B for sound speed c0: c0^2 rho0 / gamma (physics/tait.h).");
  def3(m, "tait_sound_speed", [](double B, double rho0, double gamma) { return tait_sound_speed(B, rho0, gamma); },
       "B", "rho0", "gamma", "The sound speed at rest density: sqrt(gamma B / rho0) (physics/tait.h).");
  // the spring-dashpot contact law (physics/dem.h)
  def3(m, "dem_restitution_for_damping",
       [](double k, double c, double m_eff) { return restitution_from_damping(k, c, m_eff); }, "k", "c", "m_eff",
       "Normal restitution of the spring-dashpot law with stiffness k, damping c and reduced mass m_eff "
       "(0 when overdamped; physics/dem.h, in double).");
  def3(m, "dem_damping_for_restitution",
       [](double k, double e, double m_eff) { return damping_from_restitution(k, e, m_eff); }, "k", "e", "m_eff",
       "The damping c that gives restitution e (0 < e <= 1) with stiffness k and reduced mass m_eff "
       "(physics/dem.h, in double).");
  // the SPH box probe's sample points (scenes/sph/probe.h, the float the core samples at)
  m.def(
      "probe_samples",
      [](std::vector<double> center, std::vector<double> normal, int shape, double size, int samples) {
        const size_t D = center.size();
        if ((D != 2 && D != 3) || normal.size() != D) throw std::invalid_argument("center and normal: 2 or 3 numbers each");
        if (shape < 0 || shape > 3 || samples < 1) throw std::invalid_argument("shape 0, 1, 2 or 3 and samples >= 1");
        double n2 = 0.0;
        for (double x : normal) n2 += x * x;
        if (!(n2 > 0.0)) throw std::invalid_argument("normal must be non-zero");
        float c[3] = {0, 0, 0}, n[3] = {0, 0, 0};
        for (size_t k = 0; k < D; ++k) {
          c[k] = float(center[k]);
          n[k] = float(normal[k] / std::sqrt(n2));
        }
        const int ns = shape == cps::sph::kProbePoint ? 1 : samples;
        auto* out = new double[size_t(ns) * D];
        for (int s = 0; s < ns; ++s) {
          float x[3];
          if (D == 2) cps::sph::probe_sample_point<2>(c, n, shape, float(size), ns, s, x);
          else cps::sph::probe_sample_point<3>(c, n, shape, float(size), ns, s, x);
          for (size_t k = 0; k < D; ++k) out[size_t(s) * D + k] = x[k];
        }
        nb::capsule owner(out, [](void* q) noexcept { delete[] static_cast<double*>(q); });
        return nb::ndarray<nb::numpy, double, nb::ndim<2>>(out, {size_t(ns), D}, owner);
      },
      nb::arg("center"), nb::arg("normal"), nb::arg("shape"), nb::arg("size"), nb::arg("samples"),
      "The sample points (samples x dim, float64 of the core's float32) of a probe: shape 0 point, 1 disc, 2 square, "
      "3 gauge (scenes/sph/probe.h).");
}
