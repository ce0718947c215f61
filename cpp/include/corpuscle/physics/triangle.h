// Closest point on a triangle and the signed distance to a closed triangle mesh: the contact
// geometry of a body loaded from an STL/OBJ/PLY mesh (DEM particles against its triangles).
//
// Closest point: Ericson, "Real-Time Collision Detection" (2005), 5.1.5
// (ClosestPtPointTriangle): the Voronoi regions of the three vertices, three edges and the
// face are told apart by the signs of dot products and barycentric determinants; the answer
// names the feature (face, edge, vertex) the closest point lies on.
//
// Sign and normal: Baerentzen & Aanaes, "Signed distance computation using the angle weighted
// pseudonormal", IEEE TVCG 11 (2005): for a closed, consistently oriented (outward) manifold
// mesh, p is outside iff (p - q) . N > 0, with q the closest point and N the pseudo-normal of
// the feature q lies on: the face normal on a face, the normalised sum of the two adjacent
// face normals on an edge, the angle-weighted sum of the incident face normals at a vertex.
// Every triangle record carries its three edge and three vertex pseudo-normals (the same
// vectors in every record that shares the edge or vertex), so two triangles equally near give
// the same sign. The contact normal is the gradient of the signed distance, sign (p - q) / |p - q|
// (outward), and the feature's pseudo-normal where p lies (within float noise) on the surface:
// a particle at an edge or vertex is pushed out through the nearer side, never along a
// direction that keeps it inside.
#pragma once
#include <cstdint>

#include "corpuscle/core/vec.h"

namespace cps {

// the feature of a triangle a closest point lies on
enum TriFeature : int {
  kTriFace = 0,
  kTriEdgeAB = 1,
  kTriEdgeBC = 2,
  kTriEdgeCA = 3,
  kTriVertA = 4,
  kTriVertB = 5,
  kTriVertC = 6,
};

struct TriClosest {
  Vec3 q;       // the closest point
  int feature;  // TriFeature
};

// the point of triangle (a, b, c) closest to p (Ericson 2005, 5.1.5)
CPS_HD CPS_INLINE TriClosest closest_point_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const float d1 = dot(ab, ap), d2 = dot(ac, ap);
  if (d1 <= 0.0f && d2 <= 0.0f) return TriClosest{a, kTriVertA};
  const Vec3 bp = p - b;
  const float d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0.0f && d4 <= d3) return TriClosest{b, kTriVertB};
  const float vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0f && d1 >= 0.0f && d3 <= 0.0f) {
    const float v = d1 / (d1 - d3);
    return TriClosest{a + ab * v, kTriEdgeAB};
  }
  const Vec3 cp = p - c;
  const float d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0.0f && d5 <= d6) return TriClosest{c, kTriVertC};
  const float vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0f && d2 >= 0.0f && d6 <= 0.0f) {
    const float w = d2 / (d2 - d6);
    return TriClosest{a + ac * w, kTriEdgeCA};
  }
  const float va = d3 * d6 - d5 * d4;
  if (va <= 0.0f && (d4 - d3) >= 0.0f && (d5 - d6) >= 0.0f) {
    const float w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return TriClosest{b + (c - b) * w, kTriEdgeBC};
  }
  const float denom = 1.0f / (va + vb + vc);
  const float v = vb * denom, w = vc * denom;
  return TriClosest{a + ab * v + ac * w, kTriFace};
}

// one triangle record of a mesh: kTriStride floats
//   [0, 9)   the corners a, b, c (counter-clockwise seen from outside)
//   [9, 12)  the unit face normal (outward)
//   [12, 21) the edge pseudo-normals of ab, bc, ca
//   [21, 30) the vertex pseudo-normals of a, b, c
constexpr int kTriStride = 30;

struct MeshTriangles {
  const float* t;  // n records
  int n;
  CPS_HD CPS_INLINE Vec3 corner(int i, int k) const {
    const float* r = t + size_t(kTriStride) * i + 3 * k;
    return Vec3{{r[0], r[1], r[2]}};
  }
  // the pseudo-normal of feature f of triangle i
  CPS_HD CPS_INLINE Vec3 pseudo_normal(int i, int f) const {
    const float* r = t + size_t(kTriStride) * i + 9 + 3 * f;  // face 0, edges 1..3, vertices 4..6
    return Vec3{{r[0], r[1], r[2]}};
  }
};

// the closest feature of a mesh to p
struct MeshHit {
  float distance;  // signed: negative inside
  Vec3 normal;     // outward unit normal (the signed distance's gradient)
  Vec3 closest;    // the closest point on the surface
  int triangle;    // its triangle (-1: no triangle given)
  int feature;     // TriFeature
};

// the hit of p whose nearest triangle is bi (-1: none) at closest point bq, squared distance
// best2: the sign and normal from bq's feature as the header says
CPS_HD CPS_INLINE MeshHit mesh_hit_of(const MeshTriangles& M, const Vec3& p, int bi, const TriClosest& bq,
                                      float best2) {
  MeshHit h;
  h.triangle = bi;
  h.feature = bq.feature;
  h.closest = bq.q;
  if (bi < 0) {
    h.distance = 3.0e38f;
    h.normal = Vec3{{0.0f, 0.0f, 1.0f}};
    return h;
  }
  const Vec3 N = M.pseudo_normal(bi, bq.feature);
  const Vec3 d = p - bq.q;
  const float dist = fsqrt(best2);
  const bool inside = dot(d, N) < 0.0f;
  h.distance = inside ? -dist : dist;
  // the scale of the coordinates: below 1e-6 of it a distance is float noise
  float scale = 1e-30f;
  for (int k = 0; k < 3; ++k) scale = fmax2(scale, bq.q[k] < 0.0f ? -bq.q[k] : bq.q[k]);
  if (dist > 1e-6f * scale) {
    h.normal = d * ((inside ? -1.0f : 1.0f) / dist);
  } else {
    const float l = norm(N);
    h.normal = l > 0.0f ? N * (1.0f / l) : M.pseudo_normal(bi, kTriFace);
  }
  return h;
}

// the running nearest triangle of a search: offer(i) keeps triangle i when it is strictly nearer
struct MeshNearest {
  const MeshTriangles* M;
  Vec3 p;
  float best2 = 3.0e38f;
  int bi = -1;
  TriClosest bq{};
  CPS_HD CPS_INLINE void offer(int i) {
    const TriClosest c = closest_point_on_triangle(p, M->corner(i, 0), M->corner(i, 1), M->corner(i, 2));
    const float d2 = norm2(p - c.q);
    if (d2 < best2) {
      best2 = d2;
      bi = i;
      bq = c;
    }
  }
  CPS_HD CPS_INLINE MeshHit hit() const { return mesh_hit_of(*M, p, bi, bq, best2); }
};

// the nearest point over triangles ids[0, count) (null: 0 .. count - 1), ties to the lowest
// position in the list; sign and normal from its feature as the header says
CPS_HD CPS_INLINE MeshHit mesh_sdf_over(const MeshTriangles& M, const Vec3& p, const int* ids, int count) {
  MeshNearest s{&M, p};
  for (int k = 0; k < count; ++k) s.offer(ids ? ids[k] : k);
  return s.hit();
}

// over every triangle (a reference and small meshes)
CPS_HD CPS_INLINE MeshHit mesh_sdf(const MeshTriangles& M, const Vec3& p) { return mesh_sdf_over(M, p, nullptr, M.n); }

}  // namespace cps
