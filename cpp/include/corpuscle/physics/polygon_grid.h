// A uniform grid over a static polygon (the airfoil's segments), built once on the host, so
// that a contact query reads the few edges of its cell instead of every edge.
//
// The grid covers the polygon's bounding box grown by the contact reach (plus a margin);
// a point outside it is farther than the reach from the polygon and outside it. Each cell
// (box B, centre c, half-diagonal h, all widened by a margin so that every point the
// float cell lookup puts in the cell lies in B) is one of:
// - far (kPolyCellFar): the boundary is farther than h + reach from c, and c is outside:
//   every point of the cell is outside and farther than the reach (no contact); no edges;
// - outside / inside (kPolyCellOutside / kPolyCellInside): no edge comes within h of c, so
//   the whole cell lies on the side of c (its crossing parity, from the exact predicates of
//   polygon.h); the cell lists the edges that can be nearest to one of its points;
// - straddling (kPolyCellStraddle): the boundary passes within h of c; the cell lists those
//   edges and every edge the ray from one of its points towards +x can cross (the edges
//   whose y-range meets B's and that reach B's left side or beyond), so the parity over the
//   list is the parity over every edge.
// "Can be nearest": for p in the cell, the distance d(p) to the boundary is at most
// d(c) + h, and the nearest edge e of p has d(c, e) <= d(p) + h <= d(c) + 2h; the cell lists
// every edge with d(c, e) <= d(c) + 2h (+ a margin for float rounding), in ascending order.
//
// polygon_sdf over such a list (polygon_sdf_over in polygon.h: the same loop, the same float
// operations, the same tie-break by the lowest edge index) therefore gives the hit of
// polygon_sdf over every edge, bit for bit, for every point of a listed cell: distance,
// normal, closest point, edge, vertex and sign. For a far cell or a point off the grid the
// hit says "farther than the reach, outside" (distance 1e30), which no contact law touches.
//
// The tables (cell offsets, edge indices, flags) are plain arrays: the caller uploads them
// to its backend once and hands the view their pointers; the queries are CPS_HD.
#pragma once
#include <algorithm>
#include <cmath>
#include <vector>

#include "corpuscle/physics/polygon.h"

namespace cps {

constexpr unsigned char kPolyCellFar = 0;       // outside, farther than the reach: nothing listed
constexpr unsigned char kPolyCellOutside = 1;   // outside, edges near it listed
constexpr unsigned char kPolyCellInside = 2;    // inside, edges near it listed
constexpr unsigned char kPolyCellStraddle = 3;  // the boundary crosses it: near and crossing edges listed

// the grid's cells: origin, cell edge, dims, and the tables (backend pointers)
struct PolygonGridCells {
  Vec2 origin;
  float inv_cell;
  int dims[2];
  const int* start = nullptr;            // dims[0] * dims[1] + 1 offsets into refs
  const int* refs = nullptr;             // edge indices, ascending within a cell
  const unsigned char* flag = nullptr;   // kPolyCell*

  // the cell of p, or -1 off the grid (also for a non-finite p)
  CPS_HD CPS_INLINE int cell_of(const Vec2& p) const {
    const float fx = (p[0] - origin[0]) * inv_cell, fy = (p[1] - origin[1]) * inv_cell;
    if (!(fx >= 0.0f && fy >= 0.0f && fx < float(dims[0]) && fy < float(dims[1]))) return -1;
    return int(fy) * dims[0] + int(fx);
  }
};

// a polygon's edge records and its grid: what the queries below take
struct PolygonGrid {
  PolygonEdges edges;
  PolygonGridCells cells;
  CPS_HD CPS_INLINE int size() const { return edges.size(); }
  CPS_HD CPS_INLINE PolygonEdge edge(int i) const { return edges.edge(i); }
};

// the signed distance through the grid: polygon_sdf(G.edges, p) for every p of a listed
// cell (every p within the reach of the boundary, every p inside), bit for bit; else a hit
// 1e30 away outside (edge and vertex -1)
CPS_HD CPS_INLINE PolygonHit polygon_sdf(const PolygonGrid& G, const Vec2& p) {
  const int c = G.cells.cell_of(p);
  const unsigned char f = c < 0 ? kPolyCellFar : G.cells.flag[c];
  if (f == kPolyCellFar) {
    PolygonHit h;
    h.distance = 1e30f;
    h.normal = Vec2::zero();
    h.closest = p;
    h.edge = -1;
    h.vertex = -1;
    return h;
  }
  const int b = G.cells.start[c], e = G.cells.start[c + 1];
  const int sign = f == kPolyCellStraddle ? -1 : (f == kPolyCellInside ? 1 : 0);
  return polygon_sdf_over(G.edges, p, G.cells.refs + b, e - b, sign);
}

// is p inside? the same answer as the crossing parity over every edge
CPS_HD CPS_INLINE bool polygon_contains(const PolygonGrid& G, const Vec2& p) {
  const int c = G.cells.cell_of(p);
  const unsigned char f = c < 0 ? kPolyCellFar : G.cells.flag[c];
  if (f != kPolyCellStraddle) return f == kPolyCellInside;
  bool in = false;
  for (int k = G.cells.start[c]; k < G.cells.start[c + 1]; ++k)
    if (ray_crosses(G.edges.edge(G.cells.refs[k]), p)) in = !in;
  return in;
}

// ---- the build (host) ----

// the tables of a grid; view() gives the cells with the pointers of the caller's copies
struct PolygonGridTables {
  Vec2 origin;
  float cell = 0.0f;
  int dims[2] = {0, 0};
  std::vector<int> start, refs;
  std::vector<unsigned char> flag;
  PolygonGridCells view(const int* start_p, const int* refs_p, const unsigned char* flag_p) const {
    PolygonGridCells c;
    c.origin = origin;
    c.inv_cell = 1.0f / cell;
    c.dims[0] = dims[0];
    c.dims[1] = dims[1];
    c.start = start_p;
    c.refs = refs_p;
    c.flag = flag_p;
    return c;
  }
};

// distance (double) from q to the segment a b
inline double segment_distance(double qx, double qy, const PolygonEdge& g) {
  const double ax = g.ax, ay = g.ay, dx = double(g.bx) - ax, dy = double(g.by) - ay;
  const double l2 = dx * dx + dy * dy;
  double t = l2 > 0.0 ? ((qx - ax) * dx + (qy - ay) * dy) / l2 : 0.0;
  t = t < 0.0 ? 0.0 : (t > 1.0 ? 1.0 : t);
  return std::hypot(qx - (ax + t * dx), qy - (ay + t * dy));
}

// the grid over polygon E for contacts within `reach` of its boundary, with about
// `resolution` cells along the longer side of its bounding box
template <class Poly>
PolygonGridTables build_polygon_grid(const Poly& E, float reach, int resolution = 256) {
  PolygonGridTables T;
  const int n = E.size();
  Box2 bb = polygon_bbox(E);
  double scale = 1.0;
  for (int k = 0; k < 2; ++k) scale = std::max({scale, std::fabs(double(bb.lo[k])), std::fabs(double(bb.hi[k]))});
  // float rounding allowances: of a distance (the queries' d2 in float), of a cell lookup
  const double dmargin = 1e-5 * scale;
  const double grow = double(reach) + 2.0 * dmargin;
  double lo[2], ext[2];
  for (int k = 0; k < 2; ++k) {
    lo[k] = double(bb.lo[k]) - grow;
    ext[k] = double(bb.hi[k]) - double(bb.lo[k]) + 2.0 * grow;
  }
  resolution = std::max(1, std::min(resolution, 4096));
  const double cell = std::max(std::max(ext[0], ext[1]) / resolution, 1e-6 * scale);
  for (int k = 0; k < 2; ++k) T.dims[k] = std::max(1, int(std::ceil(ext[k] / cell)));
  T.cell = float(cell);
  T.origin = Vec2{{float(lo[0]), float(lo[1])}};
  const double cmargin = 1e-3 * cell + dmargin;
  const double ox = T.origin[0], oy = T.origin[1], cf = T.cell;  // the float grid the lookup uses
  const int ncells = T.dims[0] * T.dims[1];
  T.start.assign(size_t(ncells) + 1, 0);
  T.flag.assign(size_t(ncells), kPolyCellFar);
  std::vector<double> dist(static_cast<size_t>(n));
  for (int cy = 0; cy < T.dims[1]; ++cy) {
    for (int cx = 0; cx < T.dims[0]; ++cx) {
      const int c = cy * T.dims[0] + cx;
      // the cell's box, widened by the lookup's rounding allowance
      const double bx0 = ox + cx * cf - cmargin, bx1 = ox + (cx + 1) * cf + cmargin;
      const double by0 = oy + cy * cf - cmargin, by1 = oy + (cy + 1) * cf + cmargin;
      const double qx = 0.5 * (bx0 + bx1), qy = 0.5 * (by0 + by1);
      const double h = 0.5 * std::hypot(bx1 - bx0, by1 - by0);
      double dmin = 1e300;
      for (int i = 0; i < n; ++i) {
        dist[size_t(i)] = segment_distance(qx, qy, E.edge(i));
        dmin = std::min(dmin, dist[size_t(i)]);
      }
      T.start[size_t(c) + 1] = int(T.refs.size());
      if (dmin > h + double(reach) + dmargin && !polygon_contains(E, Vec2{{float(qx), float(qy)}})) continue;  // far
      const bool straddle = dmin <= h + dmargin;
      unsigned char f = straddle ? kPolyCellStraddle
                                 : (polygon_contains(E, Vec2{{float(qx), float(qy)}}) ? kPolyCellInside
                                                                                       : kPolyCellOutside);
      const double near = dmin + 2.0 * h + 2.0 * dmargin;
      for (int i = 0; i < n; ++i) {
        bool take = dist[size_t(i)] <= near;
        if (!take && straddle) {  // an edge the ray from a point of the box towards +x can cross
          const PolygonEdge g = E.edge(i);
          const double ylo = std::min(g.ay, g.by), yhi = std::max(g.ay, g.by), xhi = std::max(g.ax, g.bx);
          take = ylo <= by1 && yhi >= by0 && xhi >= bx0;
        }
        if (take) T.refs.push_back(i);
      }
      T.flag[size_t(c)] = f;
      T.start[size_t(c) + 1] = int(T.refs.size());
    }
  }
  if (T.refs.empty()) T.refs.push_back(0);  // (never read: a buffer of at least one)
  return T;
}

}  // namespace cps
