// corpuscle renderer: per-pixel math shared by the CPU loops (raster.cpp) and any device path.
//
// Everything here is a small CPS_HD function over plain data, so a CUDA rasterizer can call
// the same formulas the OpenMP one does (docs/architecture.md: physics -- and pixels -- written once).
//
// Conventions: images are row-major RGB8 (H, W, 3); pixel (row i, column j) has its centre at
// (j + 0.5, i + 0.5) in screen coordinates, x to the right, y down. View space has x right,
// y up and z forward (depth grows away from the camera), in world units.
#pragma once

#include <cmath>
#include <cstdint>

#ifndef CPS_HD
#  ifdef __CUDACC__
#    define CPS_HD __host__ __device__
#  else
#    define CPS_HD
#  endif
#endif

namespace cps::render {

// pinhole (perspective) or orthographic camera as a 3x4 world-to-view matrix plus intrinsics
struct Camera {
  float m[12];   // rows: right, up, forward; each 3 rotation entries then a translation
  float focal;   // perspective: pixels per world unit at depth 1; orthographic: pixels per unit
  float cx, cy;  // principal point in pixels
  int ortho;     // 1 for an orthographic camera
};

// a point on screen: pixel coordinates, view depth, and pixels per world unit at that depth
struct Projected {
  float x, y, z, scale;
};

// nearest depth a perspective camera accepts (world units in front of the eye)
constexpr float kNear = 1e-6f;

// world point -> screen (x, y in pixels), view depth z and the local pixels-per-unit scale
CPS_HD inline Projected project(const Camera& c, float px, float py, float pz) {
  const float xv = c.m[0] * px + c.m[1] * py + c.m[2] * pz + c.m[3];
  const float yv = c.m[4] * px + c.m[5] * py + c.m[6] * pz + c.m[7];
  const float zv = c.m[8] * px + c.m[9] * py + c.m[10] * pz + c.m[11];
  const float s = c.ortho ? c.focal : c.focal / fmaxf(zv, kNear);
  return {c.cx + s * xv, c.cy - s * yv, zv, s};
}

// value transform before the colour ramp: 0 linear, 1 signed log(1+|v|) (= log(p+1) for p >= 0)
CPS_HD inline float transform_value(float v, int transform) {
  return transform == 1 ? copysignf(log1pf(fabsf(v)), v) : v;
}

// transformed value -> index into an n-entry lookup table over [lo, hi], clamped at both ends
CPS_HD inline int lut_index(float tv, float lo, float hi, int n) {
  float u = (tv - lo) / (hi - lo);
  u = fminf(fmaxf(u, 0.0f), 1.0f);
  const int k = static_cast<int>(u * static_cast<float>(n));
  return k < n ? k : n - 1;
}

// pack and unpack an RGB8 colour in one 32-bit word
CPS_HD inline uint32_t pack_rgb(uint8_t r, uint8_t g, uint8_t b) {
  return static_cast<uint32_t>(r) | (static_cast<uint32_t>(g) << 8) | (static_cast<uint32_t>(b) << 16);
}
CPS_HD inline uint8_t channel(uint32_t c, int k) { return static_cast<uint8_t>((c >> (8 * k)) & 0xffu); }

// fixed key light in camera space (+z toward the viewer): upper left, in front
struct Light {
  float lx = -0.42f, ly = 0.56f, lz = 0.71f;  // unit direction to the light
  float hx = -0.22f, hy = 0.29f, hz = 0.93f;  // unit half vector between light and viewer
  float ambient = 0.32f, diffuse = 0.68f, specular = 0.28f;
};

// Lambert diffuse plus a Blinn-Phong highlight (exponent 16) for a unit normal in camera space
// (Blinn 1977, "Models of light reflection for computer synthesized pictures", eq. for N.H^n)
CPS_HD inline void shade(uint32_t base, float nx, float ny, float nz, uint8_t* out) {
  const Light L;
  const float d = fmaxf(nx * L.lx + ny * L.ly + nz * L.lz, 0.0f);
  float s = fmaxf(nx * L.hx + ny * L.hy + nz * L.hz, 0.0f);
  s *= s; s *= s; s *= s; s *= s;  // s^16
  const float k = L.ambient + L.diffuse * d;
  const float spec = 255.0f * L.specular * s;
  for (int c = 0; c < 3; ++c) {
    const float v = static_cast<float>(channel(base, c)) * k + spec;
    out[c] = static_cast<uint8_t>(fminf(v, 255.0f) + 0.5f);
  }
}

// alpha-blend colour (r, g, b) over a pixel with coverage a in [0, 1]
CPS_HD inline void blend(uint8_t* px, const uint8_t* rgb, float a) {
  for (int c = 0; c < 3; ++c) {
    const float v = static_cast<float>(px[c]) + a * (static_cast<float>(rgb[c]) - static_cast<float>(px[c]));
    px[c] = static_cast<uint8_t>(v + 0.5f);
  }
}

// signed doubled area of triangle (a, b, p): the edge function of Pineda 1988,
// "A parallel algorithm for polygon rasterization"
CPS_HD inline float edge(float ax, float ay, float bx, float by, float px, float py) {
  return (bx - ax) * (py - ay) - (by - ay) * (px - ax);
}

// depth at barycentric weights: perspective-correct (1/z is affine in screen space) or linear
CPS_HD inline float interp_depth(float b0, float b1, float b2, float z0, float z1, float z2, int ortho) {
  if (ortho) return b0 * z0 + b1 * z1 + b2 * z2;
  return 1.0f / (b0 / z0 + b1 / z1 + b2 / z2);
}

// distance from (px, py) to segment a-b and the segment parameter t of the closest point
CPS_HD inline float segment_distance(float ax, float ay, float bx, float by, float px, float py, float* t_out) {
  const float dx = bx - ax, dy = by - ay;
  const float l2 = dx * dx + dy * dy;
  float t = l2 > 0.0f ? ((px - ax) * dx + (py - ay) * dy) / l2 : 0.0f;
  t = fminf(fmaxf(t, 0.0f), 1.0f);
  const float ex = ax + t * dx - px, ey = ay + t * dy - py;
  *t_out = t;
  return sqrtf(ex * ex + ey * ey);
}

}  // namespace cps::render

// ---- host loops (raster.cpp): OpenMP over screen bands, deterministic for any thread count ----
namespace cps::render {

// the picture being drawn: RGB8 pixels and an optional view-depth buffer (nullptr: none)
struct Target {
  uint8_t* rgb;
  float* depth;
  int width, height;
};

// how a per-particle value becomes a colour: lookup table over [lo, hi] after a transform
struct ColorSpec {
  const uint8_t* lut;   // lut_size x 3 RGB8 entries; nullptr: every particle gets `base`
  int lut_size;
  float lo, hi;         // range in transformed units
  int transform;        // see transform_value
  uint32_t base;        // colour when there is no value array
  uint32_t nan_color;   // colour for NaN values
};

// particles drawn as screen-space discs: lit sphere impostors or flat dots
struct SplatSpec {
  const float* pos;        // n x dim positions (dim 2: z = 0)
  int64_t n;
  int dim;
  const float* values;     // n x value_dim values (magnitude when value_dim > 1), or nullptr
  int value_dim;
  float radius;            // world radius
  float min_radius_px;     // smallest disc drawn, so no particle vanishes between pixel centres
  int sphere;              // 1: shaded sphere with per-pixel depth; 0: flat disc
  int depth_test;          // 1: nearest wins (depth buffer); 0: later particles paint over earlier
  float clip_depth;        // particles nearer than this view depth are left out (cutaway); -inf: none
};

// draw particles; returns how many were on screen
int64_t splat_particles(const Target& t, const Camera& cam, const SplatSpec& s, const ColorSpec& c);

// flat-coloured triangles given in screen space (x, y, view depth) per vertex, depth-tested
void draw_triangles(const Target& t, const float* verts, const uint8_t* colors, int64_t m, int ortho,
                    int depth_test);

// anti-aliased line segments (x0, y0, z0, x1, y1, z1) in screen space, blended over the image
void draw_lines(const Target& t, const float* segs, int64_t m, const uint8_t* rgb, float width, float opacity,
                int depth_test, float depth_bias, int ortho);

// even-odd filled polygon (k screen points), blended over the image without depth
void fill_polygon(const Target& t, const float* pts, int64_t k, const uint8_t* rgb, float opacity);

// threads the loops will use
int max_threads();

}  // namespace cps::render
