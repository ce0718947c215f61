// corpuscle renderer: CPU loops (OpenMP) around the per-pixel math in raster.h.
//
// Particles are binned into horizontal bands of rows (a counting sort that keeps index order),
// then each band is drawn by one thread: no two threads touch a pixel, so there are no races
// and the picture is the same for any thread count.
#include "raster.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#if defined(_OPENMP)
#  include <omp.h>
#endif

namespace cps::render {

namespace {

#if defined(_OPENMP)
int thread_id() { return omp_get_thread_num(); }
int team_size() { return omp_get_num_threads(); }
#else
int thread_id() { return 0; }
int team_size() { return 1; }
#endif

// rows per band: small enough to balance threads, large enough that most discs fit one band
constexpr int kBand = 16;

// one particle after projection: screen centre, view depth, pixel radius and its colour
struct Splat {
  float x, y, z, r;
  uint32_t color;
};

// colour of particle i from its value (or the base colour)
inline uint32_t particle_color(const SplatSpec& s, const ColorSpec& c, int64_t i) {
  if (s.values == nullptr || c.lut == nullptr) return c.base;
  float v;
  if (s.value_dim == 1) {
    v = s.values[i];
  } else {
    // vector field: its magnitude (speed from velocity)
    float acc = 0.0f;
    for (int k = 0; k < s.value_dim; ++k) {
      const float e = s.values[i * s.value_dim + k];
      acc += e * e;
    }
    v = sqrtf(acc);
  }
  if (std::isnan(v)) return c.nan_color;
  const int k = lut_index(transform_value(v, c.transform), c.lo, c.hi, c.lut_size);
  return pack_rgb(c.lut[3 * k], c.lut[3 * k + 1], c.lut[3 * k + 2]);
}

// draw one disc into rows [row0, row1): each row's covered span comes from the circle, and a
// pixel whose depth already beats the sphere's nearest point is skipped before any shading
inline void raster_splat(const Target& t, const SplatSpec& s, const Splat& p, int row0, int row1) {
  const float r = p.r, r2 = r * r, inv_r = 1.0f / r;
  // the depth change across a sphere is its world radius (view units)
  const float rw = s.radius;
  const float z_front = s.sphere ? p.z - rw : p.z;
  const bool test = s.depth_test && t.depth;
  const int y0 = std::max(row0, static_cast<int>(std::ceil(p.y - r - 0.5f)));
  const int y1 = std::min(row1 - 1, static_cast<int>(std::floor(p.y + r - 0.5f)));
  for (int y = y0; y <= y1; ++y) {
    const float dy = static_cast<float>(y) + 0.5f - p.y;
    const float rem = r2 - dy * dy;
    if (rem < 0.0f) continue;
    // pixel centres x + 0.5 within the chord at this row
    const float half = sqrtf(rem);
    const int x0 = std::max(0, static_cast<int>(std::ceil(p.x - half - 0.5f)));
    const int x1 = std::min(t.width - 1, static_cast<int>(std::floor(p.x + half - 0.5f)));
    const int64_t row = static_cast<int64_t>(y) * t.width;
    for (int x = x0; x <= x1; ++x) {
      const int64_t idx = row + x;
      if (test && !(z_front < t.depth[idx])) continue;
      uint8_t* px = t.rgb + 3 * idx;
      if (s.sphere) {
        // impostor normal from the disc offset; its depth bulges toward the camera
        const float dx = static_cast<float>(x) + 0.5f - p.x;
        const float nx = dx * inv_r, ny = -dy * inv_r;
        const float nz = sqrtf(fmaxf(1.0f - nx * nx - ny * ny, 0.0f));
        const float z = p.z - rw * nz;
        if (test) {
          if (!(z < t.depth[idx])) continue;
          t.depth[idx] = z;
        }
        shade(p.color, nx, ny, nz, px);
      } else {
        if (test) t.depth[idx] = p.z;
        px[0] = channel(p.color, 0);
        px[1] = channel(p.color, 1);
        px[2] = channel(p.color, 2);
      }
    }
  }
}

}  // namespace

int max_threads() {
#if defined(_OPENMP)
  return omp_get_max_threads();
#else
  return 1;
#endif
}

int64_t splat_particles(const Target& t, const Camera& cam, const SplatSpec& s, const ColorSpec& c) {
  const int64_t n = s.n;
  if (n <= 0 || t.width <= 0 || t.height <= 0) return 0;
  const int nbands = (t.height + kBand - 1) / kBand;
  std::unique_ptr<Splat[]> splat(new Splat[n]);
  std::unique_ptr<int32_t[]> band_lo(new int32_t[n]);
  std::unique_ptr<int32_t[]> band_hi(new int32_t[n]);
  std::vector<int64_t> band_start(static_cast<size_t>(nbands) + 1, 0);
  std::unique_ptr<Splat[]> binned;
  std::vector<int64_t> counts;
  int64_t visible = 0;

#pragma omp parallel reduction(+ : visible)
  {
    const int nt = team_size(), tid = thread_id();
    const int64_t begin = n * tid / nt, end = n * (tid + 1) / nt;

    // project, colour and find each particle's band range (empty when culled)
    for (int64_t i = begin; i < end; ++i) {
      const float* q = s.pos + i * s.dim;
      const Projected p = project(cam, q[0], q[1], s.dim > 2 ? q[2] : 0.0f);
      const float r = fmaxf(s.radius * p.scale, s.min_radius_px);
      const bool culled = (!cam.ortho && p.z <= kNear) || p.z < s.clip_depth || !(p.x + r >= 0.0f) || !(p.x - r <= t.width) ||
                          !(p.y + r >= 0.0f) || !(p.y - r <= t.height);
      if (culled) {
        band_lo[i] = 1;
        band_hi[i] = 0;
        continue;
      }
      splat[i] = {p.x, p.y, p.z, r, particle_color(s, c, i)};
      band_lo[i] = std::max(0, static_cast<int>(std::floor((p.y - r) / kBand)));
      band_hi[i] = std::min(nbands - 1, static_cast<int>(std::floor((p.y + r) / kBand)));
      ++visible;
    }

    // count entries per (thread, band)
#pragma omp single
    counts.assign(static_cast<size_t>(nt) * nbands, 0);
    int64_t* my = counts.data() + static_cast<size_t>(tid) * nbands;
    for (int64_t i = begin; i < end; ++i)
      for (int b = band_lo[i]; b <= band_hi[i]; ++b) ++my[b];
#pragma omp barrier

    // exclusive scan band-major, so each band lists thread 0's particles, then thread 1's: index order
#pragma omp single
    {
      int64_t total = 0;
      for (int b = 0; b < nbands; ++b) {
        band_start[b] = total;
        for (int k = 0; k < nt; ++k) {
          const int64_t cnt = counts[static_cast<size_t>(k) * nbands + b];
          counts[static_cast<size_t>(k) * nbands + b] = total;
          total += cnt;
        }
      }
      band_start[nbands] = total;
      binned.reset(new Splat[total]);
    }

    // scatter copies of the splats into their bands, so drawing reads memory in order
    for (int64_t i = begin; i < end; ++i)
      for (int b = band_lo[i]; b <= band_hi[i]; ++b) binned[my[b]++] = splat[i];
#pragma omp barrier

    // draw each band's particles in index order, one band per thread at a time
#pragma omp for schedule(dynamic, 1)
    for (int b = 0; b < nbands; ++b) {
      const int row0 = b * kBand, row1 = std::min(t.height, row0 + kBand);
      for (int64_t k = band_start[b]; k < band_start[b + 1]; ++k) raster_splat(t, s, binned[k], row0, row1);
    }
  }
  return visible;
}

void draw_triangles(const Target& t, const float* verts, const uint8_t* colors, int64_t m, int ortho,
                    int depth_test) {
  for (int64_t k = 0; k < m; ++k) {
    const float* v = verts + 9 * k;
    const float ax = v[0], ay = v[1], az = v[2], bx = v[3], by = v[4], bz = v[5], cx = v[6], cy = v[7], cz = v[8];
    // skip degenerate triangles and those behind a perspective camera
    const float area = edge(ax, ay, bx, by, cx, cy);
    if (std::fabs(area) < 1e-12f) continue;
    if (!ortho && (az <= kNear || bz <= kNear || cz <= kNear)) continue;
    const int x0 = std::max(0, static_cast<int>(std::floor(std::min({ax, bx, cx}))));
    const int x1 = std::min(t.width - 1, static_cast<int>(std::ceil(std::max({ax, bx, cx}))));
    const int y0 = std::max(0, static_cast<int>(std::floor(std::min({ay, by, cy}))));
    const int y1 = std::min(t.height - 1, static_cast<int>(std::ceil(std::max({ay, by, cy}))));
    const uint8_t* rgb = colors + 3 * k;
    const float inv_area = 1.0f / area;
    // rows are independent: split them over threads when the triangle is large
#pragma omp parallel for schedule(static) if ((x1 - x0) * (y1 - y0) > 16384)
    for (int y = y0; y <= y1; ++y) {
      const float py = static_cast<float>(y) + 0.5f;
      for (int x = x0; x <= x1; ++x) {
        const float px = static_cast<float>(x) + 0.5f;
        // barycentric weights from the three edge functions; inside when all are non-negative
        const float b0 = edge(bx, by, cx, cy, px, py) * inv_area;
        const float b1 = edge(cx, cy, ax, ay, px, py) * inv_area;
        const float b2 = edge(ax, ay, bx, by, px, py) * inv_area;
        if (b0 < 0.0f || b1 < 0.0f || b2 < 0.0f) continue;
        const int64_t idx = static_cast<int64_t>(y) * t.width + x;
        if (depth_test && t.depth) {
          const float z = interp_depth(b0, b1, b2, az, bz, cz, ortho);
          if (!(z < t.depth[idx])) continue;
          t.depth[idx] = z;
        }
        uint8_t* out = t.rgb + 3 * idx;
        out[0] = rgb[0];
        out[1] = rgb[1];
        out[2] = rgb[2];
      }
    }
  }
}

void draw_lines(const Target& t, const float* segs, int64_t m, const uint8_t* rgb, float width, float opacity,
                int depth_test, float depth_bias, int ortho) {
  const float half = 0.5f * width;
  for (int64_t k = 0; k < m; ++k) {
    const float* g = segs + 6 * k;
    const float ax = g[0], ay = g[1], az = g[2], bx = g[3], by = g[4], bz = g[5];
    if (!ortho && (az <= kNear || bz <= kNear)) continue;
    if (!std::isfinite(ax + ay + bx + by)) continue;
    // walk the major axis; at each step visit the pixels within reach of the line on the minor axis
    const bool steep = std::fabs(by - ay) > std::fabs(bx - ax);
    const float a_major = steep ? ay : ax, b_major = steep ? by : bx;
    const float a_minor = steep ? ax : ay, b_minor = steep ? bx : by;
    const float lo = std::min(a_major, b_major) - half - 1.0f, hi = std::max(a_major, b_major) + half + 1.0f;
    const int limit_major = steep ? t.height : t.width, limit_minor = steep ? t.width : t.height;
    const int c0 = std::max(0, static_cast<int>(std::floor(lo))), c1 = std::min(limit_major - 1, static_cast<int>(std::ceil(hi)));
    const float d_major = b_major - a_major;
    const float slope = std::fabs(d_major) > 1e-12f ? (b_minor - a_minor) / d_major : 0.0f;
    const float reach = (half + 1.5f) * std::sqrt(1.0f + slope * slope);
    for (int c = c0; c <= c1; ++c) {
      const float cm = static_cast<float>(c) + 0.5f;
      const float tm = std::fabs(d_major) > 1e-12f ? std::clamp((cm - a_major) / d_major, 0.0f, 1.0f) : 0.0f;
      const float centre = a_minor + tm * (b_minor - a_minor);
      const int m0 = std::max(0, static_cast<int>(std::floor(centre - reach)));
      const int m1 = std::min(limit_minor - 1, static_cast<int>(std::ceil(centre + reach)));
      for (int mm = m0; mm <= m1; ++mm) {
        const int x = steep ? mm : c, y = steep ? c : mm;
        float ts;
        const float dist = segment_distance(ax, ay, bx, by, static_cast<float>(x) + 0.5f, static_cast<float>(y) + 0.5f, &ts);
        // coverage of a pixel by a line of this width (box filter approximation)
        const float cov = std::clamp(half + 0.5f - dist, 0.0f, 1.0f) * opacity;
        if (cov <= 0.0f) continue;
        const int64_t idx = static_cast<int64_t>(y) * t.width + x;
        if (depth_test && t.depth) {
          const float z = ortho ? az + ts * (bz - az) : 1.0f / ((1.0f - ts) / az + ts / bz);
          if (z - depth_bias > t.depth[idx]) continue;
        }
        blend(t.rgb + 3 * idx, rgb, cov);
      }
    }
  }
}

void fill_polygon(const Target& t, const float* pts, int64_t k, const uint8_t* rgb, float opacity) {
  if (k < 3) return;
  float ymin = pts[1], ymax = pts[1];
  for (int64_t i = 1; i < k; ++i) {
    ymin = std::min(ymin, pts[2 * i + 1]);
    ymax = std::max(ymax, pts[2 * i + 1]);
  }
  const int y0 = std::max(0, static_cast<int>(std::floor(ymin))), y1 = std::min(t.height - 1, static_cast<int>(std::ceil(ymax)));
  // scanlines through pixel centres: sorted edge crossings, filled between pairs (even-odd rule)
#pragma omp parallel for schedule(static)
  for (int y = y0; y <= y1; ++y) {
    const float py = static_cast<float>(y) + 0.5f;
    std::vector<float> xs;
    for (int64_t i = 0; i < k; ++i) {
      const float* a = pts + 2 * i;
      const float* b = pts + 2 * ((i + 1) % k);
      if ((a[1] <= py) == (b[1] <= py)) continue;
      xs.push_back(a[0] + (py - a[1]) * (b[0] - a[0]) / (b[1] - a[1]));
    }
    std::sort(xs.begin(), xs.end());
    for (size_t j = 0; j + 1 < xs.size(); j += 2) {
      const int x0 = std::max(0, static_cast<int>(std::ceil(xs[j] - 0.5f)));
      const int x1 = std::min(t.width - 1, static_cast<int>(std::ceil(xs[j + 1] - 0.5f)) - 1);
      for (int x = x0; x <= x1; ++x) blend(t.rgb + 3 * (static_cast<int64_t>(y) * t.width + x), rgb, opacity);
    }
  }
}

}  // namespace cps::render
