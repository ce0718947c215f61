// corpuscle._testing: the SPH kernel families (physics/sph_kernel_families.h), the pair terms
// (physics/sph_pair_terms.h) and the CFL step (physics/timestep.h) evaluated on the host, so
// pytest can check them against float64 NumPy (tests/physics/test_sph_kernel_families.py,
// tests/physics/test_sph_pair_terms.py). The pair-term functions sum over all pairs i != j within the
// support, evaluating (i, j) and (j, i) as two separate calls, as a pipeline's gather does.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <type_traits>
#include <string>
#include <vector>

#include "corpuscle/physics/sph_kernel_families.h"
#include "corpuscle/physics/sph_pair_terms.h"
#include "corpuscle/physics/timestep.h"

namespace nb = nanobind;
using namespace cps;

namespace {

using FArray = nb::ndarray<const float, nb::c_contig, nb::device::cpu>;

nb::ndarray<nb::numpy, float> out_array(std::vector<float> v, size_t rows, size_t cols) {
  auto* buf = new float[v.size() > 0 ? v.size() : 1];
  if (!v.empty()) std::memcpy(buf, v.data(), v.size() * sizeof(float));
  nb::capsule owner(buf, [](void* p) noexcept { delete[] static_cast<float*>(p); });
  size_t shape[2] = {rows, cols};
  return nb::ndarray<nb::numpy, float>(buf, cols ? 2 : 1, shape, owner);
}

SphKernelKind kernel_kind(const std::string& s) {
  if (s == "poly6") return SphKernelKind::Poly6;
  if (s == "spiky") return SphKernelKind::Spiky;
  if (s == "viscosity") return SphKernelKind::Viscosity;
  if (s == "cubic_spline") return SphKernelKind::CubicSpline;
  if (s == "wendland_c2") return SphKernelKind::WendlandC2;
  throw nb::value_error(("unknown kernel '" + s + "' (poly6, spiky, viscosity, cubic_spline, wendland_c2)").c_str());
}

void check_dim(int dim) {
  if (dim != 2 && dim != 3) throw nb::value_error("dim must be 2 or 3");
}
// rows of an (n, dim) float32 array
size_t rows(const FArray& a, int dim, const char* what) {
  if (a.ndim() != 2 || a.shape(1) != size_t(dim))
    throw nb::value_error((std::string(what) + " must have shape (n, dim)").c_str());
  return a.shape(0);
}
void check_len(const FArray& a, size_t n, const char* what) {
  if (a.ndim() != 1 || a.shape(0) != n) throw nb::value_error((std::string(what) + ": one value per row").c_str());
}
template <int D>
Vec<D> row(const FArray& a, size_t i) {
  Vec<D> v;
  for (int k = 0; k < D; ++k) v[k] = a.data()[i * D + k];
  return v;
}

// W, grad W (D) and, for the viscosity kernel, lap W (NaN for the others)
template <int D, SphKernelKind K>
void eval_static(float h, const FArray& d, size_t n, bool from_r2, std::vector<float>& out) {
  auto k = Kernel<D, K>::make(h);
  for (size_t i = 0; i < n; ++i) {
    Vec<D> v = row<D>(d, i);
    float r = norm(v);
    float* o = out.data() + i * (D + 2);
    o[0] = from_r2 ? k.w_r2(norm2(v)) : k.w(r);
    Vec<D> g = k.grad(v, r);
    for (int c = 0; c < D; ++c) o[1 + c] = g[c];
    if constexpr (K == SphKernelKind::Viscosity) o[D + 1] = KernelFormula<D, K>::lap(k.k, r);
    else o[D + 1] = std::numeric_limits<float>::quiet_NaN();
  }
}

template <int D>
nb::ndarray<nb::numpy, float> eval_kernel(SphKernelKind kind, float h, const FArray& d, bool compile_time, bool from_r2) {
  size_t n = rows(d, D, "d");
  std::vector<float> out(n * (D + 2));
  if (compile_time) {
    switch (kind) {
      case SphKernelKind::Poly6: eval_static<D, SphKernelKind::Poly6>(h, d, n, from_r2, out); break;
      case SphKernelKind::Spiky: eval_static<D, SphKernelKind::Spiky>(h, d, n, from_r2, out); break;
      case SphKernelKind::Viscosity: eval_static<D, SphKernelKind::Viscosity>(h, d, n, from_r2, out); break;
      case SphKernelKind::CubicSpline: eval_static<D, SphKernelKind::CubicSpline>(h, d, n, from_r2, out); break;
      default: eval_static<D, SphKernelKind::WendlandC2>(h, d, n, from_r2, out); break;
    }
  } else {
    auto k = SphKernel<D>::make(kind, h);
    for (size_t i = 0; i < n; ++i) {
      Vec<D> v = row<D>(d, i);
      float r = norm(v);
      float* o = out.data() + i * (D + 2);
      o[0] = from_r2 ? k.w_r2(norm2(v)) : k.w(r);
      Vec<D> g = k.grad(v, r);
      for (int c = 0; c < D; ++c) o[1 + c] = g[c];
      o[D + 1] = kind == SphKernelKind::Viscosity ? KernelFormula<D, SphKernelKind::Viscosity>::lap(k.k, r)
                                                  : std::numeric_limits<float>::quiet_NaN();
    }
  }
  return out_array(std::move(out), n, D + 2);
}

// a set of n particles: positions, velocities, densities, sound speeds, masses
struct Particles {
  size_t n;
  const FArray &x, &v, &rho, &c, &m;
};

// sum over j != i within the support of f(i, j, d, dv, r2, gradW) -> Vec<D> or float
template <int D, class Out, class F>
std::vector<Out> pair_sum(const SphKernel<D>& k, const FArray& x, const FArray& v, size_t n, F f) {
  std::vector<Out> acc(n);
  for (size_t i = 0; i < n; ++i) {
    if constexpr (std::is_same_v<Out, float>) acc[i] = 0.0f;
    else acc[i] = Out::zero();
    Vec<D> xi = row<D>(x, i), vi = row<D>(v, i);
    for (size_t j = 0; j < n; ++j) {
      if (j == i) continue;
      Vec<D> d = xi - row<D>(x, j);
      float r2 = norm2(d);
      if (r2 >= k.k.h2) continue;
      Vec<D> dv = vi - row<D>(v, j);
      acc[i] += f(i, j, d, dv, r2, k.grad(d, fsqrt(r2)));
    }
  }
  return acc;
}

template <int D>
nb::ndarray<nb::numpy, float> vec_out(const std::vector<Vec<D>>& a) {
  std::vector<float> out(a.size() * D);
  for (size_t i = 0; i < a.size(); ++i)
    for (int c = 0; c < D; ++c) out[i * D + c] = a[i][c];
  return out_array(std::move(out), a.size(), D);
}

template <int D>
nb::ndarray<nb::numpy, float> artificial_viscosity(SphKernelKind kind, float h, float alpha, float beta, float hs,
                                                   const FArray& x, const FArray& v, const FArray& rho,
                                                   const FArray& c, const FArray& m) {
  size_t n = rows(x, D, "x");
  rows(v, D, "v");
  check_len(rho, n, "rho");
  check_len(c, n, "c");
  check_len(m, n, "m");
  auto k = SphKernel<D>::make(kind, h);
  auto p = ArtificialViscosity::make(alpha, beta, hs);
  const float *R = rho.data(), *C = c.data(), *M = m.data();
  auto acc = pair_sum<D, Vec<D>>(k, x, v, n, [&](size_t i, size_t j, const Vec<D>& d, const Vec<D>& dv, float r2,
                                                 const Vec<D>& g) {
    return artificial_viscosity_acc(p, d, dv, r2, C[i], C[j], R[i], R[j], M[j], g);
  });
  return vec_out<D>(acc);
}

template <int D>
nb::ndarray<nb::numpy, float> laminar_viscosity(SphKernelKind kind, float h, float nu0, float hs, const FArray& x,
                                                const FArray& v, const FArray& rho, const FArray& m) {
  size_t n = rows(x, D, "x");
  rows(v, D, "v");
  check_len(rho, n, "rho");
  check_len(m, n, "m");
  auto k = SphKernel<D>::make(kind, h);
  auto p = LaminarViscosity::make(nu0, hs);
  const float *R = rho.data(), *M = m.data();
  auto acc = pair_sum<D, Vec<D>>(k, x, v, n, [&](size_t i, size_t j, const Vec<D>& d, const Vec<D>& dv, float r2,
                                                 const Vec<D>& g) {
    return laminar_viscosity_acc(p, d, dv, r2, R[i], R[j], M[j], g);
  });
  return vec_out<D>(acc);
}

// the transport-velocity terms (Adami et al. 2013): per particle, the extra stress's
// acceleration (D columns) then the background pressure's push (D columns), V = m / rho
template <int D>
nb::ndarray<nb::numpy, float> tvf_terms(SphKernelKind kind, float h, float p_b, const FArray& x, const FArray& v,
                                        const FArray& dvt, const FArray& rho, const FArray& m) {
  size_t n = rows(x, D, "x");
  rows(v, D, "v");
  if (rows(dvt, D, "dvt") != n) throw nb::value_error("dvt: one row per particle");
  check_len(rho, n, "rho");
  check_len(m, n, "m");
  auto k = SphKernel<D>::make(kind, h);
  const float *R = rho.data(), *M = m.data();
  std::vector<float> out(n * 2 * D, 0.0f);
  for (size_t i = 0; i < n; ++i) {
    Vec<D> xi = row<D>(x, i), vi = row<D>(v, i), ti = row<D>(dvt, i);
    Vec<D> a = Vec<D>::zero(), b = Vec<D>::zero();
    const float vol_i = M[i] / R[i];
    for (size_t j = 0; j < n; ++j) {
      if (j == i) continue;
      Vec<D> d = xi - row<D>(x, j);
      float r2 = norm2(d);
      if (r2 >= k.k.h2) continue;
      Vec<D> g = k.grad(d, fsqrt(r2));
      const float vol_j = M[j] / R[j];
      a += tvf_stress_acc<D>(R[i], vi, ti, R[j], row<D>(v, j), row<D>(dvt, j), vol_i, vol_j, M[i], g);
      b += tvf_background_acc<D>(p_b, vol_i, vol_j, M[i], g);
    }
    for (int c = 0; c < D; ++c) {
      out[i * 2 * D + c] = a[c];
      out[i * 2 * D + D + c] = b[c];
    }
  }
  return out_array(std::move(out), n, 2 * D);
}

DensityDiffusion diffusion(const std::string& kind, float delta, float hs, float c0, float rho0, float gamma,
                           float g) {
  if (kind == "none") return DensityDiffusion::none();
  if (kind == "molteni") return DensityDiffusion::molteni(delta, hs, c0);
  if (kind == "fourtakas") return DensityDiffusion::fourtakas(delta, hs, c0, rho0, gamma, g);
  throw nb::value_error("diffusion kind must be none, molteni or fourtakas");
}

template <int D>
nb::ndarray<nb::numpy, float> density_diffusion(SphKernelKind kind, float h, const DensityDiffusion& p,
                                                const FArray& x, const FArray& rho, const FArray& m) {
  size_t n = rows(x, D, "x");
  check_len(rho, n, "rho");
  check_len(m, n, "m");
  auto k = SphKernel<D>::make(kind, h);
  const float *R = rho.data(), *M = m.data();
  // velocities do not enter: pass the positions as v (dv unused)
  auto acc = pair_sum<D, float>(k, x, x, n, [&](size_t i, size_t j, const Vec<D>& d, const Vec<D>&, float r2,
                                                const Vec<D>& g) {
    return density_diffusion_rate(p, d, r2, R[i], R[j], M[j], g);
  });
  return out_array(std::move(acc), n, 0);
}

template <int D>
nb::ndarray<nb::numpy, float> pairwise(const FArray& d, const FArray& dv, bool pi,
                                       float alpha, float beta, float hs, const FArray* cbar, const FArray* rhobar) {
  size_t n = rows(d, D, "d");
  if (rows(dv, D, "dv") != n) throw nb::value_error("d and dv: the same number of rows");
  std::vector<float> out(n);
  auto p = ArtificialViscosity::make(alpha, beta, hs);
  for (size_t i = 0; i < n; ++i) {
    Vec<D> a = row<D>(d, i), b = row<D>(dv, i);
    float r2 = norm2(a);
    out[i] = pi ? monaghan_pi(p, a, b, r2, cbar->data()[i], rhobar->data()[i]) : sph_mu(hs, p.eta2, a, b, r2);
  }
  return out_array(std::move(out), n, 0);
}

template <class F>
auto by_dim(int dim, F f) {
  check_dim(dim);
  return dim == 2 ? f(std::integral_constant<int, 2>{}) : f(std::integral_constant<int, 3>{});
}

}  // namespace

void bind_sph(nb::module_& m) {
  m.def(
      "sph_kernel",
      [](const std::string& kernel, int dim, float h, const FArray& d, bool compile_time, bool from_r2) {
        auto kind = kernel_kind(kernel);
        return by_dim(dim,
                      [&](auto D) { return eval_kernel<decltype(D)::value>(kind, h, d, compile_time, from_r2); });
      },
      nb::arg("kernel"), nb::arg("dim"), nb::arg("h"), nb::arg("d"), nb::arg("compile_time") = false,
      nb::arg("from_r2") = false,
      "Columns: W(|d|), grad_i W(d) (dim), lap W (viscosity kernel only, else NaN); h is the support radius. "
      "compile_time: Kernel<D, K> instead of the run-time SphKernel<D>; from_r2: W via w_r2(|d|^2).");
  m.def(
      "sph_monaghan_pi",
      [](int dim, float alpha, float beta, float hs, const FArray& d, const FArray& dv, const FArray& c_bar,
         const FArray& rho_bar) {
        check_len(c_bar, d.shape(0), "c_bar");
        check_len(rho_bar, d.shape(0), "rho_bar");
        return by_dim(dim, [&](auto D) {
          return pairwise<decltype(D)::value>(d, dv, true, alpha, beta, hs, &c_bar, &rho_bar);
        });
      },
      nb::arg("dim"), nb::arg("alpha"), nb::arg("beta"), nb::arg("hs"), nb::arg("d"), nb::arg("dv"),
      nb::arg("c_bar"), nb::arg("rho_bar"), "Monaghan's Pi_ij per pair row (d = x_i - x_j, dv = v_i - v_j).");
  m.def(
      "sph_mu",
      [](int dim, float hs, const FArray& d, const FArray& dv) {
        return by_dim(dim, [&](auto D) {
          return pairwise<decltype(D)::value>(d, dv, false, 0.0f, 0.0f, hs, nullptr, nullptr);
        });
      },
      nb::arg("dim"), nb::arg("hs"), nb::arg("d"), nb::arg("dv"), "mu_ij = hs v_ij . r_ij / (r^2 + 0.01 hs^2) per row.");
  m.def(
      "sph_artificial_viscosity",
      [](const std::string& kernel, int dim, float h, float alpha, float beta, float hs, const FArray& x,
         const FArray& v, const FArray& rho, const FArray& c, const FArray& mass) {
        auto kind = kernel_kind(kernel);
        return by_dim(dim, [&](auto D) {
          return artificial_viscosity<decltype(D)::value>(kind, h, alpha, beta, hs, x, v, rho, c, mass);
        });
      },
      nb::arg("kernel"), nb::arg("dim"), nb::arg("h"), nb::arg("alpha"), nb::arg("beta"), nb::arg("hs"),
      nb::arg("x"), nb::arg("v"), nb::arg("rho"), nb::arg("c"), nb::arg("mass"),
      "Per-particle acceleration sum_j -m_j Pi_ij grad_i W_ij over all pairs within the support h.");
  m.def(
      "sph_laminar_viscosity",
      [](const std::string& kernel, int dim, float h, float nu0, float hs, const FArray& x, const FArray& v,
         const FArray& rho, const FArray& mass) {
        auto kind = kernel_kind(kernel);
        return by_dim(dim, [&](auto D) {
          return laminar_viscosity<decltype(D)::value>(kind, h, nu0, hs, x, v, rho, mass);
        });
      },
      nb::arg("kernel"), nb::arg("dim"), nb::arg("h"), nb::arg("nu0"), nb::arg("hs"), nb::arg("x"), nb::arg("v"),
      nb::arg("rho"), nb::arg("mass"), "Per-particle laminar-viscosity acceleration over all pairs within h.");
  m.def(
      "sph_tvf_terms",
      [](const std::string& kernel, int dim, float h, float p_b, const FArray& x, const FArray& v, const FArray& dvt,
         const FArray& rho, const FArray& mass) {
        auto kind = kernel_kind(kernel);
        return by_dim(dim, [&](auto D) { return tvf_terms<decltype(D)::value>(kind, h, p_b, x, v, dvt, rho, mass); });
      },
      nb::arg("kernel"), nb::arg("dim"), nb::arg("h"), nb::arg("p_b"), nb::arg("x"), nb::arg("v"), nb::arg("dvt"),
      nb::arg("rho"), nb::arg("mass"),
      "Per particle over all pairs within h: the transport-velocity extra stress's acceleration (dim columns), "
      "then the background pressure's push (dim columns); dvt = v~ - v.");
  m.def(
      "sph_density_diffusion",
      [](const std::string& kernel, int dim, float h, const std::string& kind, float delta, float hs, float c0,
         float rho0, float gamma, float g, const FArray& x, const FArray& rho, const FArray& mass) {
        auto kk = kernel_kind(kernel);
        auto p = diffusion(kind, delta, hs, c0, rho0, gamma, g);
        return by_dim(dim, [&](auto D) { return density_diffusion<decltype(D)::value>(kk, h, p, x, rho, mass); });
      },
      nb::arg("kernel"), nb::arg("dim"), nb::arg("h"), nb::arg("kind"), nb::arg("delta"), nb::arg("hs"),
      nb::arg("c0"), nb::arg("rho0") = 1000.0f, nb::arg("gamma") = 7.0f, nb::arg("g") = 9.81f, nb::arg("x"),
      nb::arg("rho"), nb::arg("mass"), "Per-particle density-diffusion rate drho_i/dt over all pairs within h.");
  m.def(
      "sph_fourtakas_rho_h",
      [](float c0, float rho0, float gamma, float g, const FArray& z, bool published) {
        auto p = DensityDiffusion::fourtakas(0.1f, 1.0f, c0, rho0, gamma, g);
        std::vector<float> out(z.size());
        for (size_t i = 0; i < z.size(); ++i)
          out[i] = published ? fourtakas_rho_h_published(p, z.data()[i]) : fourtakas_rho_h(p, z.data()[i]);
        return out_array(std::move(out), z.size(), 0);
      },
      nb::arg("c0"), nb::arg("rho0"), nb::arg("gamma"), nb::arg("g"), nb::arg("z"), nb::arg("published") = false,
      "The hydrostatic density difference rho^H_ji at z_ij (the odd form used, or the published one).");
  m.def(
      "sph_choose_dt_cfl",
      [](float cfl, float hs, float amax, float c0, float mu_max, float dt_min, float dt_max, float nu) {
        return choose_dt_cfl(cfl, hs, amax, c0, mu_max, nu, dt_min, dt_max);
      },
      nb::arg("cfl"), nb::arg("hs"), nb::arg("amax"), nb::arg("c0"), nb::arg("mu_max"), nb::arg("dt_min"),
      nb::arg("dt_max"), nb::arg("nu") = 0.0f);
}
