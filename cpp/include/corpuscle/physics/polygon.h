// Signed distance from a 2-D point to a closed simple polygon (an airfoil section): negative
// inside, with the outward unit normal and the closest point on the boundary.
//
// The polygon is a flat float array of n vertices (x0, y0, x1, y1, ...), counter-clockwise,
// closed implicitly (edge i runs from vertex i to vertex (i + 1) % n, no repeated closing
// vertex): what corpuscle.airfoils returns. A kernel may instead read precomputed edge records
// (PolygonEdges, kEdgeStride floats per edge); both layouts go through the same polygon_sdf.
//
// Method (the standard one for polylines, e.g. Ericson, "Real-Time Collision Detection" 2005,
// 5.1.2 closest point on a segment; Sunday 2001 / O'Rourke, "Computational Geometry in C"
// 7.4, the crossing-number point-in-polygon test):
// - distance: the minimum over edges of the distance to the segment (parameter t clamped);
// - closest feature: the edge interior (0 < t < 1) or a vertex (t clamped to 0 or 1);
// - sign: crossing parity of the ray from p towards +x, with the half-open rule
//   (an edge counts when exactly one endpoint has y > p.y) so a ray through a vertex or
//   along an edge is counted once or not at all. The side test is an orientation
//   determinant evaluated in double from the float inputs with the products' roundoff
//   recovered by fma (orient2d below), so its sign is exact, also for points lying on an
//   edge's line or its extension (where float roundoff would flip the parity);
// - normal: the gradient of the signed distance, sign * (p - q) / |p - q|. On an edge
//   interior that is the edge's outward normal, used directly (exact, also for p on the
//   edge); at a vertex it points from the vertex towards p (outside) or from p towards the
//   vertex (inside); for p at (or within float noise of) a vertex it falls back to the
//   vertex pseudo-normal, the normalised sum of its two edges' outward normals
//   (Baerentzen & Aanaes 2005). So a sharp trailing edge (a vertex with an acute interior
//   angle) gets, outside, the direction from the vertex and, inside its thin wedge, the
//   normal of the nearer surface: a contact pushes a particle out through the nearer side.
#pragma once
#include <cmath>

#include "corpuscle/core/vec.h"

namespace cps {

struct Box2 {
  Vec2 lo, hi;
};

// one edge record: endpoints a and b (b is the next vertex, stored so that the half-open
// parity test compares exactly the same floats for the two edges meeting at a vertex), the
// outward unit normal (for a counter-clockwise polygon) and 1 / |b - a|^2
struct PolygonEdge {
  float ax, ay, bx, by;
  float nx, ny;
  float inv_len2;
  float len;
};
constexpr int kEdgeStride = 8;  // floats per edge record in a flat edge array

// the vertex layout: n vertices, 2n floats
struct PolygonVertices {
  const float* xy;
  int n;
  CPS_HD CPS_INLINE int size() const { return n; }
  CPS_HD CPS_INLINE PolygonEdge edge(int i) const;
};

// the edge layout: n records of kEdgeStride floats (fill with polygon_write_edges)
struct PolygonEdges {
  const float* e;
  int n;
  CPS_HD CPS_INLINE int size() const { return n; }
  CPS_HD CPS_INLINE PolygonEdge edge(int i) const {
    const float* r = e + kEdgeStride * i;
    return PolygonEdge{r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7]};
  }
};

CPS_HD CPS_INLINE PolygonEdge make_edge(float ax, float ay, float bx, float by) {
  float dx = bx - ax, dy = by - ay;
  float l2 = dx * dx + dy * dy;
  float l = fsqrt(l2);
  float inv = l > 0.0f ? 1.0f / l : 0.0f;
  // counter-clockwise: the interior is on the left of a -> b, so the outward normal is the
  // direction rotated clockwise, (dy, -dx) / |d|
  return PolygonEdge{ax, ay, bx, by, dy * inv, -dx * inv, l2 > 0.0f ? 1.0f / l2 : 0.0f, l};
}

CPS_HD CPS_INLINE PolygonEdge PolygonVertices::edge(int i) const {
  int j = i + 1 == n ? 0 : i + 1;
  return make_edge(xy[2 * i], xy[2 * i + 1], xy[2 * j], xy[2 * j + 1]);
}

// fill out[kEdgeStride * n] with the edge records of the vertex polygon (host or one thread)
CPS_HD CPS_INLINE void polygon_write_edges(const PolygonVertices& P, float* out) {
  for (int i = 0; i < P.n; ++i) {
    PolygonEdge g = P.edge(i);
    float* r = out + kEdgeStride * i;
    r[0] = g.ax; r[1] = g.ay; r[2] = g.bx; r[3] = g.by;
    r[4] = g.nx; r[5] = g.ny; r[6] = g.inv_len2; r[7] = g.len;
  }
}

template <class Poly>
CPS_HD CPS_INLINE Box2 polygon_bbox(const Poly& P) {
  Box2 b{{{1e30f, 1e30f}}, {{-1e30f, -1e30f}}};
  for (int i = 0; i < P.size(); ++i) {
    PolygonEdge g = P.edge(i);
    b.lo[0] = fmin2(b.lo[0], g.ax); b.lo[1] = fmin2(b.lo[1], g.ay);
    b.hi[0] = fmax2(b.hi[0], g.ax); b.hi[1] = fmax2(b.hi[1], g.ay);
  }
  return b;
}

// squared distance from p to the box (0 inside): a cheap early-out before polygon_sdf
CPS_HD CPS_INLINE float box_distance2(const Box2& b, const Vec2& p) {
  float d2 = 0.0f;
  for (int k = 0; k < 2; ++k) {
    float e = p[k] < b.lo[k] ? b.lo[k] - p[k] : (p[k] > b.hi[k] ? p[k] - b.hi[k] : 0.0f);
    d2 += e * e;
  }
  return d2;
}

CPS_HD CPS_INLINE double dfma(double a, double b, double c) {
#ifdef __CUDA_ARCH__
  return ::fma(a, b, c);
#else
  return std::fma(a, b, c);
#endif
}

// orientation determinant (b - a) x (p - a): > 0 when p is left of a -> b, 0 on the line.
// From float inputs: the differences are exact in double (for coordinates whose exponents
// differ by at most 29), each product is split exactly into a double and its roundoff with
// an fma (Ogita, Rump & Oishi 2005, TwoProduct), and the sum (p1 - p2) + (e1 - e2) then has
// the exact sign for the coordinate ranges of a scene (differences of at most 26 significant
// bits: coordinates within a factor of 4 or so of one another, or exactly equal).
CPS_HD CPS_INLINE double orient2d(float ax, float ay, float bx, float by, float px, float py) {
  double abx = double(bx) - double(ax), aby = double(by) - double(ay);
  double apx = double(px) - double(ax), apy = double(py) - double(ay);
  double p1 = abx * apy, p2 = aby * apx;
  double e1 = dfma(abx, apy, -p1), e2 = dfma(aby, apx, -p2);
  return (p1 - p2) + (e1 - e2);
}

// the closest feature of the boundary
struct PolygonHit {
  float distance;  // signed: negative inside
  Vec2 normal;     // outward unit normal (gradient of the signed distance)
  Vec2 closest;    // closest point on the boundary
  int edge;        // edge of the closest point
  int vertex;      // -1: the edge interior; else the vertex index (edge or edge + 1 mod n)
};

// does the ray from p towards +x cross edge g? the half-open rule (exactly one endpoint
// above p.y) and the exact side test: the crossing is right of p when p is left of the
// upward-directed edge
CPS_HD CPS_INLINE bool ray_crosses(const PolygonEdge& g, const Vec2& p) {
  bool ua = g.ay > p[1], ub = g.by > p[1];
  if (ua == ub) return false;
  double o = orient2d(g.ax, g.ay, g.bx, g.by, p[0], p[1]);
  return ub ? o > 0.0 : o < 0.0;
}

// is p inside? crossing parity
template <class Poly>
CPS_HD CPS_INLINE bool polygon_contains(const Poly& P, const Vec2& p) {
  bool in = false;
  for (int i = 0; i < P.size(); ++i)
    if (ray_crosses(P.edge(i), p)) in = !in;
  return in;
}

// the closest feature over the edges ids[0, count) (ascending edge indices; null: every
// edge, count = n) with the sign from the crossing parity over the same edges (sign < 0), or
// given (0 outside, 1 inside: a caller that knows it). polygon_sdf is this over every edge;
// a subset that holds every edge as near to p as the nearest and every edge the ray from p
// can cross gives the same hit, bit for bit (physics/polygon_grid.h's cells)
template <class Poly>
CPS_HD CPS_INLINE PolygonHit polygon_sdf_over(const Poly& P, const Vec2& p, const int* ids, int count, int sign) {
  const int n = P.size();
  float best = 1e30f;
  int bi = 0;
  float bt = 0.0f;
  bool in = sign > 0;
  for (int k = 0; k < count; ++k) {
    const int i = ids ? ids[k] : k;
    PolygonEdge g = P.edge(i);
    float dx = g.bx - g.ax, dy = g.by - g.ay;
    float px = p[0] - g.ax, py = p[1] - g.ay;
    float t = fclamp((px * dx + py * dy) * g.inv_len2, 0.0f, 1.0f);
    float ex = px - t * dx, ey = py - t * dy;
    float d2 = ex * ex + ey * ey;
    if (d2 < best) { best = d2; bi = i; bt = t; }
    if (sign < 0 && ray_crosses(g, p)) in = !in;
  }
  PolygonHit h;
  PolygonEdge g = P.edge(bi);
  float dist = fsqrt(best);
  h.distance = in ? -dist : dist;
  h.edge = bi;
  if (bt > 0.0f && bt < 1.0f) {
    h.vertex = -1;
    h.closest = Vec2{{g.ax + bt * (g.bx - g.ax), g.ay + bt * (g.by - g.ay)}};
    h.normal = Vec2{{g.nx, g.ny}};
    return h;
  }
  // a vertex: bt == 0 is the start of edge bi, bt == 1 its end
  int v = bt <= 0.0f ? bi : (bi + 1 == n ? 0 : bi + 1);
  h.vertex = v;
  h.closest = bt <= 0.0f ? Vec2{{g.ax, g.ay}} : Vec2{{g.bx, g.by}};
  // the distance to the vertex from p - v itself (the edge loop's (p - a) - t (b - a) loses
  // the low bits of a short distance to a far vertex)
  Vec2 d = p - h.closest;
  dist = norm(d);
  h.distance = in ? -dist : dist;
  float scale = fmax2(fmax2(h.closest[0] < 0.0f ? -h.closest[0] : h.closest[0],
                            h.closest[1] < 0.0f ? -h.closest[1] : h.closest[1]), 1e-30f);
  if (dist > 1e-6f * scale) {
    h.normal = d * ((in ? -1.0f : 1.0f) / dist);
    return h;
  }
  // at the vertex itself: the pseudo-normal of its two edges
  PolygonEdge e0 = P.edge(v == 0 ? n - 1 : v - 1), e1 = P.edge(v);
  Vec2 s{{e0.nx + e1.nx, e0.ny + e1.ny}};
  float sl = norm(s);
  h.normal = sl > 0.0f ? s * (1.0f / sl) : Vec2{{e1.nx, e1.ny}};
  return h;
}

// the signed distance, normal and closest point over every edge
template <class Poly>
CPS_HD CPS_INLINE PolygonHit polygon_sdf(const Poly& P, const Vec2& p) {
  return polygon_sdf_over(P, p, nullptr, P.size(), -1);
}

}  // namespace cps
