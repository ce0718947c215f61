// A fixed body given as a closed triangle mesh, its triangles held in the engine's LBVH
// (spatial/lbvh.h over the triangles' boxes: leaves with extent), and the signed-distance
// queries a contact needs (physics/triangle.h for the geometry, sign and normal):
//
// - near(p, reach): the nearest triangle among those whose box overlaps the cube p +- reach.
//   Every triangle within distance reach of p overlaps that cube, so a hit no farther than
//   reach is the mesh's nearest point (a contact query: reach = the particle radius);
// - nearest(p, reach): the exact nearest point however far p is (a particle that ended deep
//   inside, for the push-out): the cube grows 4-fold from reach until it meets a triangle
//   (at the latest when it holds the whole mesh), then one more query of the found distance
//   makes the answer exact.
//
// The tree is built once (a fixed body) by the Exec that runs the scene: triangle centroids
// keyed along the Morton curve and sorted, the records and boxes reordered along it, the
// Karras hierarchy built and fitted bottom-up over the boxes. Triangle numbers in hits are
// the sorted ones; MeshTree::order() maps them back to the mesh's.
#pragma once
#include "corpuscle/physics/dem.h"
#include "corpuscle/physics/triangle.h"
#include "corpuscle/spatial/lbvh.h"

namespace cps {

// the centroid of each triangle (its key along the curve) and its box
struct TriangleLeavesFn {
  const float* rec;  // n records (physics/triangle.h)
  Vec3* centroid;
  float* box;        // 6 floats per triangle (lo, hi)
  CPS_HD void operator()(int i) const {
    const float* r = rec + size_t(kTriStride) * i;
    for (int k = 0; k < 3; ++k) {
      const float a = r[k], b = r[3 + k], c = r[6 + k];
      centroid[i][k] = (a + b + c) * (1.0f / 3.0f);
      box[6 * i + k] = fmin2(a, fmin2(b, c));
      box[6 * i + 3 + k] = fmax2(a, fmax2(b, c));
    }
  }
};

// sorted slot s takes triangle order[s]: its record, box and centroid
struct TriangleReorderFn {
  const int* order;
  const float* rec_in;
  const float* box_in;
  const Vec3* cen_in;
  float* rec_out;
  float* box_out;
  Vec3* cen_out;
  CPS_HD void operator()(int s) const {
    const int i = order[s];
    for (int k = 0; k < kTriStride; ++k) rec_out[size_t(kTriStride) * s + k] = rec_in[size_t(kTriStride) * i + k];
    for (int k = 0; k < 6; ++k) box_out[6 * s + k] = box_in[6 * i + k];
    cen_out[s] = cen_in[i];
  }
};

// traversal stack entries of a mesh query: a query box of a contact reach straddles few splits
// (a push onto a full stack raises the view's overflow flag: the caller stops the run)
constexpr int kMeshStack = 32;

// the queries (a plain view: copy it into a functor)
struct MeshTreeView {
  MeshTriangles tris;  // sorted along the curve
  LbvhView<3> tree;    // leaves: the triangles' boxes
  float lo[3], hi[3];  // the whole mesh's box

  // the nearest triangle among those overlapping the cube p +- reach (triangle -1: none)
  CPS_HD CPS_INLINE MeshHit near(const Vec3& p, float reach) const {
    MeshNearest s{&tris, p};
    float qlo[3], qhi[3];
    for (int k = 0; k < 3; ++k) {
      qlo[k] = p[k] - reach;
      qhi[k] = p[k] + reach;
    }
    // the walk's stack is a local array on every backend (not the particle tree's shared
    // memory): the query runs inside any stage, a fused grid pass included, whatever its launch
    int stack[kMeshStack];
    auto visit = [&](int j) { s.offer(j); };
    tree.template walk<false>(LbvhStack{stack, 1, kMeshStack}, -1, qlo, qhi, visit);
    return s.hit();
  }
  // the largest distance from p to the mesh's box: a cube of this half-size holds every triangle
  CPS_HD CPS_INLINE float far_reach(const Vec3& p) const {
    float r = 0.0f;
    for (int k = 0; k < 3; ++k) r = fmax2(r, fmax2(p[k] - lo[k], hi[k] - p[k]));
    return r;
  }
  // the exact nearest point of the mesh, however far p is (see the header)
  CPS_HD CPS_INLINE MeshHit nearest(const Vec3& p, float reach) const {
    const float rmax = far_reach(p) * 1.0001f + 1e-30f;
    float r = fmin2(fmax2(reach, 1e-30f), rmax);
    MeshHit h = near(p, r);
    while (h.triangle < 0 && r < rmax) {
      r = fmin2(4.0f * r, rmax);
      h = near(p, r);
    }
    const float d = h.distance < 0.0f ? -h.distance : h.distance;
    if (h.triangle >= 0 && d > r) h = near(p, fmin2(d * 1.0001f, rmax));
    return h;
  }
};

// squared distance from p to the mesh's box (0 inside it): the early-out before any walk
CPS_HD CPS_INLINE float mesh_box_distance2(const MeshTreeView& M, const Vec3& p) {
  float d2 = 0.0f;
  for (int k = 0; k < 3; ++k) {
    const float e = p[k] < M.lo[k] ? M.lo[k] - p[k] : (p[k] > M.hi[k] ? p[k] - M.hi[k] : 0.0f);
    d2 += e * e;
  }
  return d2;
}

// A particle (centre x, velocity v, radius r) against the resting mesh body with the body's
// law (physics/dem.h's wall law along the signed distance's normal: the overlap r - d, d < 0
// for a centre inside): the force on the particle and its magnitude; hit: the closest feature
// (the reaction on the body, -f, acts at hit.closest). No contact beyond r of the surface; a
// centre deeper inside than r is the push-out's (mesh_keep_out)
CPS_HD CPS_INLINE bool mesh_contact_force(const SpringDashpot& law, const MeshTreeView& M, const Vec3& x,
                                          const Vec3& v, float r, Vec3& f_on_particle, float& magnitude,
                                          MeshHit& hit) {
  f_on_particle = Vec3::zero();
  magnitude = 0.0f;
  hit.triangle = -1;
  if (M.tris.n == 0 || !(mesh_box_distance2(M, x) < r * r)) return false;
  hit = M.near(x, r);
  if (hit.triangle < 0) return false;
  return wall_contact_force<3>(law, hit.distance, hit.normal, v, r, Vec3::zero(), f_on_particle, magnitude);
}

// no centre ends a step inside the body: one that got in is put back on the surface, a
// twentieth of a radius outside along the normal (doubling the step until it is outside, as
// the airfoil's keep_out), its normal velocity reflected; returns whether it moved
CPS_HD CPS_INLINE bool mesh_keep_out(const MeshTreeView& M, float r, Vec3& x, Vec3& v) {
  if (M.tris.n == 0 || mesh_box_distance2(M, x) > 0.0f) return false;
  MeshHit hit = M.nearest(x, r);
  if (!(hit.distance < 0.0f)) return false;
  float step = 0.05f * r;
  Vec3 y = x;
  for (int k = 0; k < 8; ++k) {
    y = hit.closest + hit.normal * step;
    if (!(M.nearest(y, r).distance < 0.0f)) break;
    step *= 2.0f;
  }
  x = y;
  const float vn = dot(v, hit.normal);
  if (vn < 0.0f) v -= hit.normal * (2.0f * vn);
  return true;
}

// the tree's buffers and its build on an Exec
template <class Exec>
class MeshTree {
 public:
  template <class T> using Buf = typename Exec::template Buffer<T>;
  // records: n triangle records on the host (triangle_mesh.h), lo/hi: their box
  MeshTree(Exec& ex, const float* records, int n, const float* lo, const float* hi)
      : tree_(Vec3{{lo[0], lo[1], lo[2]}}, Vec3{{hi[0], hi[1], hi[2]}}, 0.0f), n_(n) {
    for (int k = 0; k < 3; ++k) {
      lo_[k] = lo[k];
      hi_[k] = hi[k];
    }
    const size_t m = size_t(n > 0 ? n : 1);
    Buf<float> rec_in;
    Buf<float> box_in;
    Buf<Vec3> cen_in;
    ex.resize(rec_in, m * kTriStride);
    ex.resize(box_in, m * 6);
    ex.resize(cen_in, m);
    ex.resize(rec_, m * kTriStride);
    ex.resize(box_, m * 6);
    ex.resize(cen_, m);
    ex.resize(overflow_, 1);
    if (n > 0) ex.to_device(rec_in.data(), records, size_t(n) * kTriStride * sizeof(float));
    const int zero = 0;
    ex.to_device(overflow_.data(), &zero, sizeof(int));
    if (n == 0) return;
    ex.for_each(n, TriangleLeavesFn{rec_in.data(), cen_in.data(), box_in.data()});
    tree_.resize(n);
    tree_.sort(ex, cen_in.data(), n);
    ex.for_each(n, TriangleReorderFn{tree_.order(), rec_in.data(), box_in.data(), cen_in.data(), rec_.data(),
                                     box_.data(), cen_.data()});
    tree_.build(ex, cen_.data(), box_.data());
    ex.synchronize();
  }
  // the queries; a traversal that would overflow its stack raises *overflow to code (null: the
  // tree's own flag, overflow(); a scene passes its clock's bad flag, as the particle tree does)
  MeshTreeView view(int* overflow = nullptr, int code = 1) {
    MeshTreeView v;
    v.tris = MeshTriangles{rec_.data(), n_};
    v.tree = tree_.view(cen_.data(), overflow ? overflow : overflow_.data(), code, kMeshStack);
    v.tree.leaf_boxes = box_.data();
    for (int k = 0; k < 3; ++k) {
      v.lo[k] = lo_[k];
      v.hi[k] = hi_[k];
    }
    return v;
  }
  const int* order() const { return tree_.order(); }  // sorted slot -> the mesh's triangle
  int* overflow() { return overflow_.data(); }
  int size() const { return n_; }

 private:
  Lbvh<3, Exec> tree_;
  int n_;
  float lo_[3], hi_[3];
  Buf<float> rec_, box_;
  Buf<Vec3> cen_;
  Buf<int> overflow_;
};

}  // namespace cps
