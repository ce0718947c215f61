// The triangle records of a closed mesh (physics/triangle.h's layout), built once on the host
// from its vertices and faces: corners, face normals and the edge and vertex pseudo-normals
// (Baerentzen & Aanaes 2005) in double, stored as float. The mesh must be closed and
// consistently oriented: every edge shared by exactly two faces that run it in opposite
// directions (outward normals by the right-hand rule); a fault is returned as a message.
#pragma once
#include <array>
#include <cmath>
#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include "corpuscle/physics/triangle.h"

namespace cps {

// fill out (kTriStride floats per face) from vertices (nv x 3) and faces (nf x 3 vertex ids);
// returns "" or what is wrong with the mesh
inline std::string write_triangle_records(const double* vertices, int64_t nv, const int64_t* faces, int64_t nf,
                                          std::vector<float>& out) {
  using D3 = std::array<double, 3>;
  auto sub = [](const D3& a, const D3& b) { return D3{a[0] - b[0], a[1] - b[1], a[2] - b[2]}; };
  auto crs = [](const D3& a, const D3& b) {
    return D3{a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
  };
  auto dt = [](const D3& a, const D3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; };
  auto unit = [&](D3 a) {
    const double l = std::sqrt(dt(a, a));
    if (l > 0.0) for (double& x : a) x /= l;
    return a;
  };
  if (nf < 4) return "a closed mesh needs at least 4 triangles, got " + std::to_string(nf);
  std::vector<D3> V(static_cast<size_t>(nv)), fn(static_cast<size_t>(nf)), vn(static_cast<size_t>(nv), D3{0, 0, 0});
  for (int64_t i = 0; i < nv; ++i) {
    V[i] = D3{vertices[3 * i], vertices[3 * i + 1], vertices[3 * i + 2]};
    for (double x : V[i])
      if (!std::isfinite(x)) return "vertex " + std::to_string(i) + " is not finite";
  }
  // directed edges: key (from, to) -> face
  std::unordered_map<uint64_t, int64_t> directed;
  directed.reserve(size_t(3 * nf));
  auto key = [](int64_t a, int64_t b) { return (uint64_t(a) << 32) | uint64_t(b); };
  for (int64_t f = 0; f < nf; ++f) {
    const int64_t* t = faces + 3 * f;
    for (int k = 0; k < 3; ++k)
      if (t[k] < 0 || t[k] >= nv || t[k] >= (int64_t(1) << 31))
        return "face " + std::to_string(f) + " names vertex " + std::to_string(t[k]) + " of " + std::to_string(nv);
    if (t[0] == t[1] || t[1] == t[2] || t[2] == t[0]) return "face " + std::to_string(f) + " repeats a vertex";
    const D3 n = crs(sub(V[t[1]], V[t[0]]), sub(V[t[2]], V[t[0]]));
    if (!(dt(n, n) > 0.0)) return "face " + std::to_string(f) + " has no area";
    fn[f] = unit(n);
    for (int k = 0; k < 3; ++k) {
      const int64_t a = t[k], b = t[(k + 1) % 3];
      if (!directed.emplace(key(a, b), f).second)
        return "edge " + std::to_string(a) + "-" + std::to_string(b) +
               " is run the same way by two faces (inconsistent orientation or more than two faces on an edge)";
      // angle-weighted vertex normal: the face's angle at corner k
      const int64_t c = t[(k + 2) % 3];
      const D3 e1 = unit(sub(V[b], V[a])), e2 = unit(sub(V[c], V[a]));
      const double ang = std::acos(std::fmax(-1.0, std::fmin(1.0, dt(e1, e2))));
      for (int j = 0; j < 3; ++j) vn[a][j] += ang * fn[f][j];
    }
  }
  out.assign(size_t(kTriStride) * size_t(nf), 0.0f);
  for (int64_t f = 0; f < nf; ++f) {
    const int64_t* t = faces + 3 * f;
    float* r = out.data() + size_t(kTriStride) * f;
    for (int k = 0; k < 3; ++k)
      for (int j = 0; j < 3; ++j) r[3 * k + j] = float(V[t[k]][j]);
    for (int j = 0; j < 3; ++j) r[9 + j] = float(fn[f][j]);
    for (int k = 0; k < 3; ++k) {
      const int64_t a = t[k], b = t[(k + 1) % 3];
      auto other = directed.find(key(b, a));
      if (other == directed.end())
        return "edge " + std::to_string(a) + "-" + std::to_string(b) + " of face " + std::to_string(f) +
               " has no face on its other side (the mesh is not closed)";
      const D3 e = unit(D3{fn[f][0] + fn[other->second][0], fn[f][1] + fn[other->second][1],
                           fn[f][2] + fn[other->second][2]});
      for (int j = 0; j < 3; ++j) r[12 + 3 * k + j] = float(e[j]);
      const D3 v = unit(vn[a]);
      for (int j = 0; j < 3; ++j) r[21 + 3 * k + j] = float(v[j]);
    }
  }
  return "";
}

}  // namespace cps
