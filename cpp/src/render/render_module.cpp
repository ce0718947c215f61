// nanobind module corpuscle._render: the rasterizer behind `corpuscle render`.
//
// A module of its own so the renderer builds and tests without the simulation core. Every
// entry point checks shapes, releases the GIL and draws in place into NumPy arrays.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>

#include <limits>
#include <optional>
#include <stdexcept>
#include <string>

#include "raster.h"

namespace nb = nanobind;
using namespace cps::render;

using Image = nb::ndarray<uint8_t, nb::ndim<3>, nb::c_contig, nb::device::cpu>;
using Depth = nb::ndarray<float, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Floats2 = nb::ndarray<const float, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Floats1 = nb::ndarray<const float, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using Bytes2 = nb::ndarray<const uint8_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Bytes1 = nb::ndarray<const uint8_t, nb::ndim<1>, nb::c_contig, nb::device::cpu>;

namespace {

// image (H, W, 3) and optional depth (H, W) -> a drawing target
Target make_target(Image& img, std::optional<Depth>& depth) {
  if (img.shape(2) != 3) throw std::invalid_argument("image must have shape (H, W, 3)");
  Target t{img.data(), nullptr, static_cast<int>(img.shape(1)), static_cast<int>(img.shape(0))};
  if (depth) {
    if (depth->shape(0) != img.shape(0) || depth->shape(1) != img.shape(1))
      throw std::invalid_argument("depth must have the image's height and width");
    t.depth = depth->data();
  }
  return t;
}

// 15 floats (3x4 world-to-view matrix, focal, cx, cy) and the projection kind -> a camera
Camera make_camera(Floats1& cam, bool ortho) {
  if (cam.shape(0) != 15) throw std::invalid_argument("camera must have 15 floats: 3x4 matrix, focal, cx, cy");
  Camera c{};
  for (int i = 0; i < 12; ++i) c.m[i] = cam.data()[i];
  c.focal = cam.data()[12];
  c.cx = cam.data()[13];
  c.cy = cam.data()[14];
  c.ortho = ortho ? 1 : 0;
  return c;
}

// an RGB triple as three bytes
void check_rgb(Bytes1& rgb) {
  if (rgb.shape(0) != 3) throw std::invalid_argument("colour must have 3 bytes (R, G, B)");
}

}  // namespace

NB_MODULE(_render, m) {
  m.doc() = "corpuscle rasterizer: sphere splats, triangles, lines and polygons into NumPy images";

  m.def(
      "splat",
      [](Image img, std::optional<Depth> depth, Floats2 pos, std::optional<Floats2> values, Floats1 cam, bool ortho,
         float radius, float min_radius_px, std::optional<Bytes2> lut, float lo, float hi, int transform, Bytes1 base,
         Bytes1 nan_color, bool sphere, bool depth_test, float clip_depth) {
        Target t = make_target(img, depth);
        const Camera c = make_camera(cam, ortho);
        check_rgb(base);
        check_rgb(nan_color);
        if (pos.shape(1) != 2 && pos.shape(1) != 3) throw std::invalid_argument("positions must have shape (n, 2) or (n, 3)");
        SplatSpec s{pos.data(), static_cast<int64_t>(pos.shape(0)), static_cast<int>(pos.shape(1)), nullptr, 1,
                    radius, min_radius_px, sphere ? 1 : 0, depth_test ? 1 : 0, clip_depth};
        if (values) {
          if (values->shape(0) != pos.shape(0)) throw std::invalid_argument("values must have one row per particle");
          s.values = values->data();
          s.value_dim = static_cast<int>(values->shape(1));
        }
        ColorSpec cs{nullptr, 0, lo, hi, transform, pack_rgb(base.data()[0], base.data()[1], base.data()[2]),
                     pack_rgb(nan_color.data()[0], nan_color.data()[1], nan_color.data()[2])};
        if (lut) {
          if (lut->shape(1) != 3 || lut->shape(0) < 1) throw std::invalid_argument("lut must have shape (k, 3)");
          cs.lut = lut->data();
          cs.lut_size = static_cast<int>(lut->shape(0));
        }
        if (!(hi > lo)) throw std::invalid_argument("colour range must have hi > lo");
        if (!(radius > 0.0f)) throw std::invalid_argument("radius must be positive");
        nb::gil_scoped_release release;
        return splat_particles(t, c, s, cs);
      },
      nb::arg("image"), nb::arg("depth").none(), nb::arg("positions"), nb::arg("values").none(), nb::arg("camera"),
      nb::arg("ortho"), nb::arg("radius"), nb::arg("min_radius_px"), nb::arg("lut").none(), nb::arg("lo"),
      nb::arg("hi"), nb::arg("transform"), nb::arg("base"), nb::arg("nan_color"), nb::arg("sphere"),
      nb::arg("depth_test"), nb::arg("clip_depth") = -std::numeric_limits<float>::infinity(),
      "Draw particles as lit sphere impostors (sphere=True) or flat discs, coloured by `values` through\n"
      "`lut` over [lo, hi] after `transform` (0 linear, 1 signed log1p), leaving out those nearer than\n"
      "`clip_depth` (a cutaway); returns the number drawn.");

  m.def(
      "triangles",
      [](Image img, std::optional<Depth> depth, Floats2 verts, Bytes2 colors, bool ortho, bool depth_test) {
        Target t = make_target(img, depth);
        if (verts.shape(1) != 9) throw std::invalid_argument("triangles must have shape (m, 9): 3 x (x, y, depth)");
        if (colors.shape(0) != verts.shape(0) || colors.shape(1) != 3)
          throw std::invalid_argument("colors must have shape (m, 3)");
        nb::gil_scoped_release release;
        draw_triangles(t, verts.data(), colors.data(), static_cast<int64_t>(verts.shape(0)), ortho ? 1 : 0,
                       depth_test ? 1 : 0);
      },
      nb::arg("image"), nb::arg("depth").none(), nb::arg("vertices"), nb::arg("colors"), nb::arg("ortho"),
      nb::arg("depth_test"), "Fill flat-coloured triangles given in screen space (x, y, view depth per vertex).");

  m.def(
      "lines",
      [](Image img, std::optional<Depth> depth, Floats2 segs, Bytes1 rgb, float width, float opacity, bool depth_test,
         float depth_bias, bool ortho) {
        Target t = make_target(img, depth);
        check_rgb(rgb);
        if (segs.shape(1) != 6) throw std::invalid_argument("segments must have shape (m, 6): (x0, y0, z0, x1, y1, z1)");
        nb::gil_scoped_release release;
        draw_lines(t, segs.data(), static_cast<int64_t>(segs.shape(0)), rgb.data(), width, opacity, depth_test ? 1 : 0,
                   depth_bias, ortho ? 1 : 0);
      },
      nb::arg("image"), nb::arg("depth").none(), nb::arg("segments"), nb::arg("color"), nb::arg("width"),
      nb::arg("opacity"), nb::arg("depth_test"), nb::arg("depth_bias"), nb::arg("ortho"),
      "Blend anti-aliased line segments given in screen space over the image.");

  m.def(
      "polygon",
      [](Image img, Floats2 pts, Bytes1 rgb, float opacity) {
        std::optional<Depth> none;
        Target t = make_target(img, none);
        check_rgb(rgb);
        if (pts.shape(1) != 2) throw std::invalid_argument("polygon points must have shape (k, 2)");
        nb::gil_scoped_release release;
        fill_polygon(t, pts.data(), static_cast<int64_t>(pts.shape(0)), rgb.data(), opacity);
      },
      nb::arg("image"), nb::arg("points"), nb::arg("color"), nb::arg("opacity"),
      "Fill a polygon given in screen space (even-odd rule), blended over the image.");

  m.def("max_threads", &max_threads, "Threads the rasterizer uses (OpenMP), 1 without OpenMP.");
#if defined(_OPENMP)
  m.attr("has_openmp") = true;
#else
  m.attr("has_openmp") = false;
#endif
}
