#include "init/poisson_disk.h"

#include <algorithm>
#include <cmath>

namespace cps {

std::vector<Vec3> poisson_disk(float R, float r, const std::function<bool(const Vec3&)>& inside, uint64_t seed,
                               int attempts) {
  SplitMix64 rng{seed};
  // background grid with cells of r / sqrt(3): at most one sample per cell
  const double cell = r / std::sqrt(3.0);
  const int dims = int(std::ceil(2.0 * R / cell)) + 1;
  std::vector<int> grid(size_t(dims) * dims * dims, -1);
  auto cell_of = [&](const Vec3& p, int* c) {
    for (int k = 0; k < 3; ++k) c[k] = std::clamp(int((p[k] + R) / cell), 0, dims - 1);
  };
  auto at = [&](int x, int y, int z) -> int& { return grid[(size_t(z) * dims + y) * dims + x]; };
  std::vector<Vec3> pts;
  std::vector<int> active;
  auto add = [&](const Vec3& p) {
    int c[3];
    cell_of(p, c);
    at(c[0], c[1], c[2]) = int(pts.size());
    active.push_back(int(pts.size()));
    pts.push_back(p);
  };
  // is p at least r from every sample?
  const float r2 = r * r;
  auto free_at = [&](const Vec3& p) {
    int c[3];
    cell_of(p, c);
    for (int z = std::max(0, c[2] - 2); z <= std::min(dims - 1, c[2] + 2); ++z)
      for (int y = std::max(0, c[1] - 2); y <= std::min(dims - 1, c[1] + 2); ++y)
        for (int x = std::max(0, c[0] - 2); x <= std::min(dims - 1, c[0] + 2); ++x) {
          int j = at(x, y, z);
          if (j >= 0 && norm2(pts[j] - p) < r2) return false;
        }
    return true;
  };
  // first sample: a random point of the region
  for (int t = 0; t < 100000 && pts.empty(); ++t) {
    Vec3 p{{float((2 * rng.uniform() - 1) * R), float((2 * rng.uniform() - 1) * R), float((2 * rng.uniform() - 1) * R)}};
    if (inside(p)) add(p);
  }
  // grow from random active samples: candidates in the shell [r, 2r)
  while (!active.empty()) {
    size_t k = size_t(rng.uniform() * double(active.size()));
    if (k >= active.size()) k = active.size() - 1;
    Vec3 base = pts[active[k]];
    bool placed = false;
    for (int t = 0; t < attempts; ++t) {
      double u = 2 * rng.uniform() - 1, phi = 2 * M_PI * rng.uniform();
      double rad = r * std::cbrt(1.0 + 7.0 * rng.uniform());  // uniform in volume of the shell
      double s = std::sqrt(std::max(0.0, 1 - u * u));
      Vec3 p{{float(base[0] + rad * s * std::cos(phi)), float(base[1] + rad * s * std::sin(phi)), float(base[2] + rad * u)}};
      if (inside(p) && free_at(p)) {
        add(p);
        placed = true;
        break;
      }
    }
    if (!placed) {
      active[k] = active.back();
      active.pop_back();
    }
  }
  return pts;
}

std::vector<Vec3> poisson_disk_count(float R, int count, const std::function<bool(const Vec3&)>& inside,
                                     double volume, uint64_t seed, float* r_used) {
  // Bridson sampling fills about 0.67 of the volume fraction of dense random packing;
  // start from the spacing that packing predicts and correct by the observed count
  double r = std::cbrt(volume / count * 0.70);
  std::vector<Vec3> pts;
  for (int it = 0; it < 8; ++it) {
    pts = poisson_disk(R, float(r), inside, seed + uint64_t(it));
    if (int(pts.size()) >= count && int(pts.size()) <= count + count / 25 + 2) break;
    double ratio = double(pts.size()) / double(count);
    // aim slightly above the target so the surplus can be trimmed
    r *= std::cbrt(ratio / 1.02);
  }
  while (int(pts.size()) < count) {
    // could not reach the count: shrink the spacing until it fits
    r *= 0.97;
    pts = poisson_disk(R, float(r), inside, seed + 101);
  }
  // trim the surplus at random (partial Fisher-Yates)
  SplitMix64 rng{seed ^ 0x5eedull};
  for (int i = 0; i < count; ++i) {
    size_t j = size_t(i) + size_t(rng.uniform() * double(pts.size() - i));
    if (j >= pts.size()) j = pts.size() - 1;
    std::swap(pts[i], pts[j]);
  }
  pts.resize(count);
  if (r_used) *r_used = float(r);
  return pts;
}

}  // namespace cps
