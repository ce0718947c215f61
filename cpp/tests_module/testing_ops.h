// corpuscle._testing: the engine's exec primitives and spatial indexes behind a small
// virtual interface, so pytest can run them on every backend. Each backend's translation
// unit includes its exec header and then this one, and instantiates PrimOpsImpl<Exec> and
// SpatialOpsImpl<Exec>: the same driver code (host vectors in, device buffers, host vectors
// out) runs on CpuExec (serial / OpenMP) and CudaExec.
#pragma once
#include <algorithm>
#include <cstdint>
#include <memory>
#include <string>
#include <type_traits>
#include <vector>

#include "corpuscle/core/atomics.h"
#include "corpuscle/core/error.h"
#include "corpuscle/core/lanes.h"
#include "corpuscle/spatial/lane_walks.h"
#include "corpuscle/spatial/allpairs.h"
#include "corpuscle/spatial/cell_grid.h"
#include "corpuscle/spatial/neighbor_list.h"
#include "corpuscle/dem/mesh_body.h"

namespace cps::testing {

// ---------------------------------------------------------------------------------------
// interfaces (what the bindings see)
// ---------------------------------------------------------------------------------------
enum ReduceOp { kSum = 0, kMin = 1, kMax = 2 };

struct AtomicsResult {
  int isum = 0, imax = 0, imin = 0, owner = -1, wins = 0;
  unsigned usum = 0;
  float fsum = 0.0f;
};

struct PrimOps {
  virtual ~PrimOps() = default;
  virtual std::string name() = 0;
  virtual std::vector<int32_t> scan_i32(const std::vector<int32_t>& in, int32_t& total) = 0;
  virtual std::vector<int64_t> scan_i32_i64(const std::vector<int32_t>& in, int64_t& total) = 0;
  virtual std::vector<uint32_t> scan_u32(const std::vector<uint32_t>& in, uint32_t& total) = 0;
  virtual std::vector<int64_t> scan_u32_i64(const std::vector<uint32_t>& in, int64_t& total) = 0;
  virtual std::vector<int> select_flagged(const std::vector<int>& flags) = 0;
  virtual std::vector<float> segreduce_f32(const std::vector<float>& items, const std::vector<int>& offsets, int op,
                                           float init) = 0;
  virtual std::vector<int> segreduce_i32(const std::vector<int>& items, const std::vector<int64_t>& offsets, int op,
                                         int init) = 0;
  virtual void sort_pairs64(const std::vector<uint64_t>& keys, const std::vector<int>& values, int bits,
                            std::vector<uint64_t>& kout, std::vector<int>& vout) = 0;
  // for_each_reduce_then over items[i] (returned by the item function) with op, and reduce over
  // the same stored items: {fused, the fused stage's follow-up (2 x fused), stored}
  virtual std::vector<float> fused_reduce(const std::vector<float>& items, int op, float init) = 0;
  virtual std::vector<float> tile_exercise(const std::vector<float>& x, int tile) = 0;
  virtual std::vector<int> for_each_if(int flag, int n) = 0;
  virtual AtomicsResult atomics(const std::vector<int>& v) = 0;
  // every point's neighbours within radius among all points (3-D), walked by `width`
  // cooperating lanes: (counts, sums of r^2)
  virtual std::vector<float> lanes_gather(const std::vector<float>& pos, float radius, int width,
                                          std::vector<int>& counts) = 0;
};

// index kinds
enum IndexKind { kAllPairs = 0, kAllPairsTiled = 1, kCellGrid = 2, kCsrGrid = 3, kCsrAllPairs = 4 };
// which tags a cell grid gathers from
enum TagMode { kAllTags = 0, kTagRange = 1, kOwnTag = 2 };

struct IndexQuery {
  int dim = 3;
  int kind = kCellGrid;
  std::vector<float> pos;  // n * dim
  int n = 0;
  float radius = 0.0f;       // the stages' query radius
  float list_radius = 0.0f;  // CSR kinds: list radius (>= radius); the grid is built for it
  std::vector<float> lo, hi; // grid domain
  std::vector<int> tags;     // empty: all tag 0
  int ntags = 1;
  int tag_mode = kAllTags, tag_a = 0, tag_b = 1;
  bool rows = false;  // grid kinds: the cells sorted in rows (CellOrder::Rows), not Morton
};

// neighbour sets in the input numbering: offsets (n + 1) and the neighbours of each input
// particle in the order the index visits them
struct Lists {
  std::vector<int64_t> offsets;
  std::vector<int> nbr;
  int64_t capacity = 0;  // CSR kinds: entries the list buffer holds
  int grows = 0;         // CSR kinds: builds that grew it
};

// a mesh's signed-distance queries through its triangle tree (dem/mesh_body.h)
struct MeshQuery {
  std::vector<float> distance, normal, closest;
  std::vector<int> triangle, feature;  // triangle: the mesh's numbering (-1: none)
  int overflow = 0;
};

struct SpatialOps {
  virtual ~SpatialOps() = default;
  // records: n triangle records (physics/triangle.h); exact: nearest(), else near()
  virtual MeshQuery mesh_tree(const std::vector<float>& records, int n, const std::vector<float>& box,
                              const std::vector<float>& points, float reach, bool exact) = 0;
  // mesh_contact_force then mesh_keep_out on each particle: (force, magnitude, moved, x, v)
  virtual std::vector<std::vector<float>> mesh_contact(const std::vector<float>& records, int n,
                                                       const std::vector<float>& box, std::vector<float> x,
                                                       std::vector<float> v, float r, float k, float c) = 0;
  virtual Lists gather(const IndexQuery& q) = 0;
  // each pair (i, j) that pairs() visits, in input numbering, in no particular order
  virtual std::vector<int> pairs(const IndexQuery& q) = 0;
  // rebuild one CSR list over several position sets (same n): the lists after each build
  virtual std::vector<Lists> csr_rebuilds(const IndexQuery& q, const std::vector<std::vector<float>>& positions) = 0;
  // the cell grid's sorted keys and order (sorted slot -> input slot)
  virtual void grid_sort(const IndexQuery& q, std::vector<uint64_t>& keys, std::vector<int>& order) = 0;
  // the candidates each input particle's cell walk reads (the slots of the cell ranges it visits)
  virtual std::vector<int> grid_walked(const IndexQuery& q) = 0;
};

// ---------------------------------------------------------------------------------------
// functors (CPS_HD: one definition for every backend)
// ---------------------------------------------------------------------------------------
// the body's contact and keep-out on each particle (dem/mesh_body.h): force, magnitude,
// and the moved position and velocity
struct MeshContactFn {
  MeshTreeView v;
  SpringDashpot law;
  float r;
  Vec3* x;
  Vec3* vel;
  Vec3* f;
  float* mag;
  int* moved;
  CPS_HD void operator()(int i) const {
    MeshHit h;
    float m;
    Vec3 fi;
    mesh_contact_force(law, v, x[i], vel[i], r, fi, m, h);
    f[i] = fi;
    mag[i] = m;
    moved[i] = mesh_keep_out(v, r, x[i], vel[i]) ? 1 : 0;
  }
};
struct MeshQueryFn {
  MeshTreeView v;
  const Vec3* p;
  float reach;
  int exact;
  float* dist;
  Vec3* nrm;
  Vec3* q;
  int* tri;
  int* feat;
  CPS_HD void operator()(int i) const {
    const MeshHit h = exact ? v.nearest(p[i], reach) : v.near(p[i], reach);
    dist[i] = h.distance;
    nrm[i] = h.normal;
    q[i] = h.closest;
    tri[i] = h.triangle;
    feat[i] = h.feature;
  }
};
struct SumOp {
  template <class T>
  CPS_HD T operator()(const T& a, const T& b) const { return a + b; }
};
struct MinOp {
  template <class T>
  CPS_HD T operator()(const T& a, const T& b) const { return b < a ? b : a; }
};
struct MaxOp {
  template <class T>
  CPS_HD T operator()(const T& a, const T& b) const { return a < b ? b : a; }
};
// the item function of a fused reduction, and a follow-up that reads its result
struct ItemOf {
  const float* p;
  CPS_HD float operator()(int i) const { return p[i]; }
};
struct TwiceOf {
  float* out;
  CPS_HD void operator()(int) const { out[1] = 2.0f * out[0]; }
};

// a tile program that needs its syncs: stage the tile's values in shared memory, read other
// lanes' values, keep a per-lane value across phases, and tree-reduce the tile in a second
// shared array; out[i] = sh[(l+1) % K] + sh[K-1-l] + 2 x[i] + (the tile's sum)
struct TileExerciseFn {
  const float* x;
  float* out;
  int n;
  template <class Tile>
  CPS_HD void operator()(int tile, Tile& t) const {
    constexpr int K = Tile::kSize;
    float* sh = t.template shared<float>(K);
    int* red = t.template shared<int>(K);
    typename Tile::template PerLane<float> twice;
    typename Tile::template PerLane<float> mine;
    t.lanes([&](int l) {
      const int i = tile * K + l;
      const float v = i < n ? x[i] : 0.0f;
      sh[l] = v;
      red[l] = int(v);
      twice[l] = 2.0f * v;
    });
    t.sync();
    t.lanes([&](int l) { mine[l] = sh[(l + 1) % K] + sh[K - 1 - l] + twice[l]; });
    t.sync();
    for (int s = K / 2; s > 0; s >>= 1) {
      t.lanes([&](int l) {
        if (l < s) red[l] += red[l + s];
      });
      t.sync();
    }
    t.lanes([&](int l) {
      const int i = tile * K + l;
      if (i < n) out[i] = mine[l] + float(red[0]);
    });
  }
};

struct MarkFn {
  int* out;
  CPS_HD void operator()(int i) const { out[i] = i + 1; }
};

// slots: 0 isum, 1 imax, 2 imin, 3 owner, 4 wins, 5 usum (as unsigned)
struct AtomicsFn {
  const int* v;
  int* ints;
  float* fsum;
  CPS_HD void operator()(int i) const {
    atomic_add(&ints[0], v[i]);
    atomic_max(&ints[1], v[i]);
    atomic_min(&ints[2], v[i]);
    if (atomic_cas(&ints[3], -1, i) == -1) atomic_add(&ints[4], 1);
    atomic_add(reinterpret_cast<unsigned*>(&ints[5]), unsigned(v[i] & 0xff));
    atomic_add(fsum, float(v[i]));
  }
};
struct AtomicsInitFn {
  int* ints;
  CPS_HD void operator()(int) const {
    ints[0] = 0;
    ints[1] = -2147483647 - 1;
    ints[2] = 2147483647;
    ints[3] = -1;
    ints[4] = 0;
    ints[5] = 0;
  }
};

// gather stages (begin / visit / end): count the neighbours, then list them
template <int D>
struct CountStage {
  using Acc = int;
  int* counts;
  CPS_HD Acc begin(int) const { return 0; }
  CPS_HD void visit(Acc& a, int, int, const Vec<D>&, float) const { ++a; }
  CPS_HD void end(int i, Acc& a) const { counts[i] = a; }
};
template <int D>
struct FillStage {
  using Acc = int64_t;
  const int64_t* offsets;
  int* nbr;
  CPS_HD Acc begin(int i) const { return offsets[i]; }
  CPS_HD void visit(Acc& a, int, int j, const Vec<D>&, float) const { nbr[a++] = j; }
  CPS_HD void end(int, Acc&) const {}
};

// the candidates of slot i's cell walk: the slots of the cell ranges it visits
template <int D>
struct WalkedFn {
  CellGridView<D> view;
  int* out;
  CPS_HD void operator()(int i) const {
    int c = 0;
    if (view.active(i)) view.for_each_cell_range(i, view.position(i), [&](uint32_t s, uint32_t e) { c += int(e - s); });
    out[i] = c;
  }
};

// every pair pairs() visits, claimed with an atomic counter (cap 0: count only)
template <class View>
struct PairsFn {
  View view;
  int* count;
  int* out;
  int cap;
  CPS_HD void operator()(int i) const {
    if (!view.active(i)) return;
    view.pairs(i, view.position(i), [&](int j, const Vec<View::kDim>&, float) {
      const int k = atomic_add(count, 1);
      if (k < cap) {
        out[2 * k] = i;
        out[2 * k + 1] = j;
      }
    });
  }
};

// the all-pairs walk of lanes cooperating on one point: count and sum of r^2 within the radius
struct LanesGather {
  const Vec3* pos;
  int n;
  float r2max;
  float* sums;
  int* counts;
  template <class Lanes>
  CPS_HD void operator()(int i, const Lanes& L) const {
    float s = 0.0f;
    auto visit = [&](int, const Vec3&, float r2) { s += r2; };
    int c = for_each_in_range(L, pos, 0, n, pos[i], r2max, visit);
    s = L.sum(s);
    if (!L.leader()) return;
    sums[i] = s;
    counts[i] = c;
  }
};

// ---------------------------------------------------------------------------------------
// drivers
// ---------------------------------------------------------------------------------------
template <class Exec>
struct Driver {
  template <class T>
  using Buffer = typename Exec::template Buffer<T>;
  Exec ex;

  explicit Driver(Exec&& e) : ex(std::move(e)) {}

  template <class T>
  Buffer<T> upload(const std::vector<T>& v) {
    Buffer<T> b;
    ex.resize(b, std::max<size_t>(v.size(), 1));
    if (!v.empty()) ex.to_device(b.data(), v.data(), v.size() * sizeof(T));
    return b;
  }
  template <class T>
  Buffer<T> alloc(size_t n) {
    Buffer<T> b;
    ex.resize(b, std::max<size_t>(n, 1));
    return b;
  }
  template <class T>
  std::vector<T> download(const T* p, size_t n) {
    std::vector<T> v(n);
    if (n) ex.to_host(v.data(), p, n * sizeof(T));
    return v;
  }
};

template <class Exec>
struct PrimOpsImpl final : PrimOps, Driver<Exec> {
  using Driver<Exec>::Driver;
  using Driver<Exec>::ex;

  std::string name() override { return ex.name(); }

  template <class T, class U>
  std::vector<U> scan(const std::vector<T>& in, U& total) {
    const int n = int(in.size());
    auto d_in = this->upload(in);
    auto d_out = this->template alloc<U>(size_t(n) + 1);
    ex.exclusive_scan(d_in.data(), d_out.data(), n, d_out.data() + n);
    auto out = this->download(d_out.data(), size_t(n) + 1);
    total = out[n];
    out.resize(n);
    return out;
  }
  std::vector<int32_t> scan_i32(const std::vector<int32_t>& in, int32_t& total) override { return scan(in, total); }
  std::vector<int64_t> scan_i32_i64(const std::vector<int32_t>& in, int64_t& total) override {
    return scan(in, total);
  }
  std::vector<uint32_t> scan_u32(const std::vector<uint32_t>& in, uint32_t& total) override {
    return scan(in, total);
  }
  std::vector<int64_t> scan_u32_i64(const std::vector<uint32_t>& in, int64_t& total) override {
    return scan(in, total);
  }

  std::vector<int> select_flagged(const std::vector<int>& flags) override {
    const int n = int(flags.size());
    auto d_flags = this->upload(flags);
    auto d_out = this->template alloc<int>(size_t(n));
    auto d_count = this->template alloc<int>(1);
    ex.select_flagged(d_flags.data(), n, d_out.data(), d_count.data());
    int count = this->download(d_count.data(), 1)[0];
    return this->download(d_out.data(), size_t(count));
  }

  template <class T, class O>
  std::vector<T> segreduce(const std::vector<T>& items, const std::vector<O>& offsets, int op, T init) {
    const int nseg = offsets.empty() ? 0 : int(offsets.size()) - 1;
    auto d_items = this->upload(items);
    auto d_off = this->upload(offsets);
    auto d_out = this->template alloc<T>(size_t(nseg));
    if (op == kSum)
      ex.segmented_reduce(d_items.data(), d_off.data(), nseg, d_out.data(), SumOp{}, init);
    else if (op == kMin)
      ex.segmented_reduce(d_items.data(), d_off.data(), nseg, d_out.data(), MinOp{}, init);
    else
      ex.segmented_reduce(d_items.data(), d_off.data(), nseg, d_out.data(), MaxOp{}, init);
    return this->download(d_out.data(), size_t(nseg));
  }
  std::vector<float> segreduce_f32(const std::vector<float>& items, const std::vector<int>& offsets, int op,
                                   float init) override {
    return segreduce(items, offsets, op, init);
  }
  std::vector<int> segreduce_i32(const std::vector<int>& items, const std::vector<int64_t>& offsets, int op,
                                 int init) override {
    return segreduce(items, offsets, op, init);
  }

  void sort_pairs64(const std::vector<uint64_t>& keys, const std::vector<int>& values, int bits,
                    std::vector<uint64_t>& kout, std::vector<int>& vout) override {
    const int n = int(keys.size());
    auto dk = this->upload(keys);
    auto dv = this->upload(values);
    auto dko = this->template alloc<uint64_t>(size_t(n));
    auto dvo = this->template alloc<int>(size_t(n));
    ex.sort_pairs(dk.data(), dko.data(), dv.data(), dvo.data(), n, bits);
    kout = this->download(dko.data(), size_t(n));
    vout = this->download(dvo.data(), size_t(n));
  }

  std::vector<float> fused_reduce(const std::vector<float>& items, int op, float init) override {
    const int n = int(items.size());
    auto d = this->upload(items);
    auto out = this->template alloc<float>(3);
    const float* p = d.data();
    float* o = out.data();
    auto run = [&](auto opf) {
      ex.for_each_reduce_then(n, ItemOf{p}, o, opf, init, TwiceOf{o});
      ex.reduce(p, n, o + 2, opf, init);
    };
    if (op == kSum) run(SumOp{});
    else if (op == kMin) run(MinOp{});
    else run(MaxOp{});
    return this->download(o, 3);
  }

  std::vector<float> tile_exercise(const std::vector<float>& x, int tile) override {
    const int n = int(x.size());
    auto dx = this->upload(x);
    auto dout = this->template alloc<float>(size_t(n));
    if (tile == 32) {
      ex.template for_each_tile<32>((n + 31) / 32, TileExerciseFn{dx.data(), dout.data(), n}, 32 * 8 + 16);
    } else if (tile == 128) {
      ex.template for_each_tile<128>((n + 127) / 128, TileExerciseFn{dx.data(), dout.data(), n}, 128 * 8 + 16);
    } else {
      throw Error("tile_exercise: tile must be 32 or 128");
    }
    return this->download(dout.data(), size_t(n));
  }

  std::vector<int> for_each_if(int flag, int n) override {
    auto dflag = this->upload(std::vector<int>{flag});
    auto dout = this->template alloc<int>(size_t(n));
    ex.for_each_if(dflag.data(), n, MarkFn{dout.data()});
    return this->download(dout.data(), size_t(n));
  }

  template <int W>
  void lanes_gather_w(const Vec3* pos, int n, float r2, float* sums, int* counts) {
    ex.template for_each_lanes_w<W>(n, LanesGather{pos, n, r2, sums, counts});
  }
  std::vector<float> lanes_gather(const std::vector<float>& pos, float radius, int width,
                                  std::vector<int>& counts) override {
    const int n = int(pos.size() / 3);
    auto d_pos = this->upload(pos);
    auto d_sums = this->template alloc<float>(n);
    auto d_counts = this->template alloc<int>(n);
    const Vec3* p = reinterpret_cast<const Vec3*>(d_pos.data());
    const float r2 = radius * radius;
    switch (width) {
      case 1: lanes_gather_w<1>(p, n, r2, d_sums.data(), d_counts.data()); break;
      case 2: lanes_gather_w<2>(p, n, r2, d_sums.data(), d_counts.data()); break;
      case 4: lanes_gather_w<4>(p, n, r2, d_sums.data(), d_counts.data()); break;
      case 8: lanes_gather_w<8>(p, n, r2, d_sums.data(), d_counts.data()); break;
      case 16: lanes_gather_w<16>(p, n, r2, d_sums.data(), d_counts.data()); break;
      case 32: lanes_gather_w<32>(p, n, r2, d_sums.data(), d_counts.data()); break;
      default: throw Error("lane width must be 1, 2, 4, 8, 16 or 32, got " + std::to_string(width));
    }
    ex.synchronize();
    counts = this->download(d_counts.data(), size_t(n));
    return this->download(d_sums.data(), size_t(n));
  }

  AtomicsResult atomics(const std::vector<int>& v) override {
    const int n = int(v.size());
    auto dv = this->upload(v);
    auto ints = this->template alloc<int>(8);
    auto fsum = this->template alloc<float>(1);
    ex.single(AtomicsInitFn{ints.data()});
    ex.for_each(n, AtomicsFn{dv.data(), ints.data(), fsum.data()});
    auto h = this->download(ints.data(), 6);
    AtomicsResult r;
    r.isum = h[0];
    r.imax = h[1];
    r.imin = h[2];
    r.owner = h[3];
    r.wins = h[4];
    r.usum = unsigned(h[5]);
    r.fsum = this->download(fsum.data(), 1)[0];
    return r;
  }
};

template <class Exec>
struct SpatialOpsImpl final : SpatialOps, Driver<Exec> {
  using Driver<Exec>::Driver;
  using Driver<Exec>::ex;
  template <class T>
  using Buffer = typename Exec::template Buffer<T>;

  MeshQuery mesh_tree(const std::vector<float>& records, int n, const std::vector<float>& box,
                      const std::vector<float>& points, float reach, bool exact) override {
    MeshTree<Exec> mesh(ex, records.data(), n, box.data(), box.data() + 3);
    const int m = int(points.size() / 3);
    auto p = this->template alloc<Vec3>(size_t(m));
    if (m) ex.to_device(p.data(), points.data(), size_t(m) * sizeof(Vec3));
    auto dist = this->template alloc<float>(size_t(m));
    auto nrm = this->template alloc<Vec3>(size_t(m));
    auto q = this->template alloc<Vec3>(size_t(m));
    auto tri = this->template alloc<int>(size_t(m));
    auto feat = this->template alloc<int>(size_t(m));
    ex.for_each(m, MeshQueryFn{mesh.view(), p.data(), reach, exact ? 1 : 0, dist.data(), nrm.data(), q.data(),
                               tri.data(), feat.data()});  // a plain launch: the mesh walk's stack is local
    MeshQuery r;
    r.distance = this->download(dist.data(), size_t(m));
    std::vector<Vec3> nv = this->download(nrm.data(), size_t(m)), qv = this->download(q.data(), size_t(m));
    for (int i = 0; i < m; ++i)
      for (int k = 0; k < 3; ++k) {
        r.normal.push_back(nv[i][k]);
        r.closest.push_back(qv[i][k]);
      }
    std::vector<int> sorted = this->download(tri.data(), size_t(m));
    std::vector<int> order = n > 0 ? this->download(mesh.order(), size_t(n)) : std::vector<int>();
    for (int t : sorted) r.triangle.push_back(t < 0 ? -1 : order[t]);
    r.feature = this->download(feat.data(), size_t(m));
    r.overflow = this->download(mesh.overflow(), 1)[0];
    return r;
  }

  std::vector<std::vector<float>> mesh_contact(const std::vector<float>& records, int n, const std::vector<float>& box,
                                               std::vector<float> x, std::vector<float> v, float r, float k,
                                               float c) override {
    MeshTree<Exec> mesh(ex, records.data(), n, box.data(), box.data() + 3);
    const int m = int(x.size() / 3);
    auto dx = this->template alloc<Vec3>(size_t(m));
    auto dv = this->template alloc<Vec3>(size_t(m));
    if (m) {
      ex.to_device(dx.data(), x.data(), size_t(m) * sizeof(Vec3));
      ex.to_device(dv.data(), v.data(), size_t(m) * sizeof(Vec3));
    }
    auto f = this->template alloc<Vec3>(size_t(m));
    auto mag = this->template alloc<float>(size_t(m));
    auto moved = this->template alloc<int>(size_t(m));
    ex.for_each(m, MeshContactFn{mesh.view(), SpringDashpot{k, c}, r, dx.data(), dv.data(), f.data(), mag.data(),
                                 moved.data()});
    auto flat = [&](const Vec3* p) {
      std::vector<Vec3> h = this->download(p, size_t(m));
      std::vector<float> out;
      for (const Vec3& a : h) out.insert(out.end(), {a[0], a[1], a[2]});
      return out;
    };
    std::vector<int> mv = this->download(moved.data(), size_t(m));
    std::vector<float> mvf(mv.begin(), mv.end());
    return {flat(f.data()), this->download(mag.data(), size_t(m)), mvf, flat(dx.data()), flat(dv.data())};
  }

  Lists gather(const IndexQuery& q) override {
    if (q.dim == 2) return gather_d<2>(q);
    if (q.dim == 3) return gather_d<3>(q);
    throw Error("dim must be 2 or 3");
  }
  std::vector<int> pairs(const IndexQuery& q) override {
    if (q.dim == 2) return pairs_d<2>(q);
    if (q.dim == 3) return pairs_d<3>(q);
    throw Error("dim must be 2 or 3");
  }
  std::vector<Lists> csr_rebuilds(const IndexQuery& q, const std::vector<std::vector<float>>& positions) override {
    if (q.dim == 2) return rebuilds_d<2>(q, positions);
    if (q.dim == 3) return rebuilds_d<3>(q, positions);
    throw Error("dim must be 2 or 3");
  }
  void grid_sort(const IndexQuery& q, std::vector<uint64_t>& keys, std::vector<int>& order) override {
    if (q.dim == 2) return grid_sort_d<2>(q, keys, order);
    if (q.dim == 3) return grid_sort_d<3>(q, keys, order);
    throw Error("dim must be 2 or 3");
  }
  std::vector<int> grid_walked(const IndexQuery& q) override {
    if (q.dim == 2) return grid_walked_d<2>(q);
    if (q.dim == 3) return grid_walked_d<3>(q);
    throw Error("dim must be 2 or 3");
  }

 private:
  template <int D>
  static CellGridSpec<D> spec_of(const IndexQuery& q, float radius) {
    Vec<D> lo, hi;
    for (int k = 0; k < D; ++k) {
      lo[k] = q.lo.at(k);
      hi[k] = q.hi.at(k);
    }
    return make_cell_grid<D>(lo, hi, radius, q.ntags, kCellGridMaxCells, q.rows ? CellOrder::Rows : CellOrder::Morton);
  }
  template <int D>
  CellGridView<D> tagged(const IndexQuery& q, CellGridView<D> v) {
    if (q.tag_mode == kTagRange) return v.tags(q.tag_a, q.tag_b);
    if (q.tag_mode == kOwnTag) return v.own_tags();
    return v;
  }

  // count -> scan -> fill through a gather stage (tiled for kAllPairsTiled), in the view's
  // numbering; `in_of` maps a view slot to the input numbering (null: identity)
  template <class View>
  Lists lists_of(const View& v, bool tiled, const int* order_dev, int n) {
    const int slots = v.size();
    auto counts = this->template alloc<int>(size_t(slots));
    auto offsets = this->template alloc<int64_t>(size_t(slots) + 1);
    constexpr int D = View::kDim;
    if constexpr (std::is_same_v<View, AllPairsView<D>>) {
      if (tiled) {
        gather_stage_tiled<64>(ex, v, CountStage<D>{counts.data()});
      } else {
        gather_stage(ex, v, CountStage<D>{counts.data()});
      }
    } else {
      gather_stage(ex, v, CountStage<D>{counts.data()});
    }
    ex.exclusive_scan(counts.data(), offsets.data(), slots, offsets.data() + slots);
    auto hoff = this->download(offsets.data(), size_t(slots) + 1);
    auto nbr = this->template alloc<int>(size_t(hoff[slots]));
    if constexpr (std::is_same_v<View, AllPairsView<D>>) {
      if (tiled) {
        gather_stage_tiled<64>(ex, v, FillStage<D>{offsets.data(), nbr.data()});
      } else {
        gather_stage(ex, v, FillStage<D>{offsets.data(), nbr.data()});
      }
    } else {
      gather_stage(ex, v, FillStage<D>{offsets.data(), nbr.data()});
    }
    auto hnbr = this->download(nbr.data(), size_t(hoff[slots]));
    std::vector<int> order;
    if (order_dev) order = this->download(order_dev, size_t(slots));
    return renumber(hoff, hnbr, order, n);
  }

  // lists in slot numbering -> lists in input numbering (order: slot -> input; empty: identity)
  static Lists renumber(const std::vector<int64_t>& off, const std::vector<int>& nbr, const std::vector<int>& order,
                        int n) {
    const int slots = int(off.size()) - 1;
    std::vector<int> slot_of(n, -1);
    for (int s = 0; s < slots; ++s) slot_of[order.empty() ? s : order[s]] = s;
    Lists out;
    out.offsets.assign(size_t(n) + 1, 0);
    for (int i = 0; i < n; ++i) {
      const int s = slot_of[i];
      out.offsets[i + 1] = out.offsets[i] + (s < 0 ? 0 : off[s + 1] - off[s]);
    }
    out.nbr.reserve(size_t(out.offsets[n]));
    for (int i = 0; i < n; ++i) {
      const int s = slot_of[i];
      if (s < 0) continue;
      for (int64_t k = off[s]; k < off[s + 1]; ++k) out.nbr.push_back(order.empty() ? nbr[k] : order[nbr[k]]);
    }
    return out;
  }

  template <int D>
  Lists gather_d(const IndexQuery& q) {
    const int n = q.n;
    auto pos = this->template alloc<Vec<D>>(size_t(n));
    if (n) ex.to_device(pos.data(), q.pos.data(), size_t(n) * sizeof(Vec<D>));
    auto tags = this->upload(q.tags);
    const int* tags_p = q.tags.empty() ? nullptr : tags.data();
    switch (q.kind) {
      case kAllPairs:
      case kAllPairsTiled: {
        AllPairs<D> ap;
        ap.build(ex, pos.data(), n, q.radius);
        return lists_of(ap.view(), q.kind == kAllPairsTiled, nullptr, n);
      }
      case kCellGrid: {
        CellGrid<D, Exec> grid(spec_of<D>(q, q.radius));
        grid.build(ex, pos.data(), tags_p, n);
        return lists_of(tagged<D>(q, grid.view()).with_radius(q.radius), false, grid.order(), n);
      }
      case kCsrGrid: {
        CellGrid<D, Exec> grid(spec_of<D>(q, q.list_radius));
        grid.build(ex, pos.data(), tags_p, n);
        NeighborList<D, Exec> list;
        list.build(ex, tagged<D>(q, grid.view()), q.list_radius);
        Lists r = lists_of(list.view(grid.sorted_positions(), q.radius), false, grid.order(), n);
        r.capacity = int64_t(list.capacity());
        r.grows = list.grows();
        return r;
      }
      case kCsrAllPairs: {
        AllPairs<D> ap;
        ap.build(ex, pos.data(), n, q.list_radius);
        NeighborList<D, Exec> list;
        list.build(ex, ap.view(), q.list_radius);
        Lists r = lists_of(list.view(pos.data(), q.radius), false, nullptr, n);
        r.capacity = int64_t(list.capacity());
        r.grows = list.grows();
        return r;
      }
      default:
        throw Error("unknown index kind " + std::to_string(q.kind));
    }
  }

  template <class View>
  std::vector<int> pairs_of(const View& v, const int* order_dev) {
    auto count = this->template alloc<int>(1);
    auto none = this->template alloc<int>(2);
    ex.zero(count.data(), sizeof(int));
    ex.for_each(v.size(), PairsFn<View>{v, count.data(), none.data(), 0});
    const int total = this->download(count.data(), 1)[0];
    auto out = this->template alloc<int>(2 * size_t(total));
    ex.zero(count.data(), sizeof(int));
    ex.for_each(v.size(), PairsFn<View>{v, count.data(), out.data(), total});
    auto h = this->download(out.data(), 2 * size_t(total));
    if (order_dev) {
      auto order = this->download(order_dev, size_t(v.size()));
      for (auto& s : h) s = order[s];
    }
    return h;
  }

  template <int D>
  std::vector<int> pairs_d(const IndexQuery& q) {
    const int n = q.n;
    auto pos = this->template alloc<Vec<D>>(size_t(n));
    if (n) ex.to_device(pos.data(), q.pos.data(), size_t(n) * sizeof(Vec<D>));
    auto tags = this->upload(q.tags);
    const int* tags_p = q.tags.empty() ? nullptr : tags.data();
    switch (q.kind) {
      case kAllPairs:
      case kAllPairsTiled: {
        AllPairs<D> ap;
        ap.build(ex, pos.data(), n, q.radius);
        return pairs_of(ap.view(), nullptr);
      }
      case kCellGrid: {
        CellGrid<D, Exec> grid(spec_of<D>(q, q.radius));
        grid.build(ex, pos.data(), tags_p, n);
        return pairs_of(tagged<D>(q, grid.view()), grid.order());
      }
      case kCsrGrid: {
        CellGrid<D, Exec> grid(spec_of<D>(q, q.list_radius));
        grid.build(ex, pos.data(), tags_p, n);
        NeighborList<D, Exec> list;
        list.build(ex, tagged<D>(q, grid.view()), q.list_radius);
        return pairs_of(list.view(grid.sorted_positions(), q.radius), grid.order());
      }
      case kCsrAllPairs: {
        AllPairs<D> ap;
        ap.build(ex, pos.data(), n, q.list_radius);
        NeighborList<D, Exec> list;
        list.build(ex, ap.view(), q.list_radius);
        return pairs_of(list.view(pos.data(), q.radius), nullptr);
      }
      default:
        throw Error("unknown index kind " + std::to_string(q.kind));
    }
  }

  // one list (and, for the grid source, one grid) rebuilt over every position set
  template <int D>
  std::vector<Lists> rebuilds_d(const IndexQuery& q, const std::vector<std::vector<float>>& positions) {
    const int n = q.n;
    auto pos = this->template alloc<Vec<D>>(size_t(n));
    std::vector<Lists> out;
    NeighborList<D, Exec> list;
    const bool grid_source = q.kind == kCsrGrid;
    if (!grid_source && q.kind != kCsrAllPairs) throw Error("csr_rebuilds: the kind must be a CSR kind");
    std::unique_ptr<CellGrid<D, Exec>> grid;
    if (grid_source) grid = std::make_unique<CellGrid<D, Exec>>(spec_of<D>(q, q.list_radius));
    for (const auto& p : positions) {
      if (p.size() != size_t(n) * D) throw Error("csr_rebuilds: every position set needs n * dim values");
      if (n) ex.to_device(pos.data(), p.data(), size_t(n) * sizeof(Vec<D>));
      Lists r;
      if (grid_source) {
        grid->build(ex, pos.data(), nullptr, n);
        list.build(ex, grid->view(), q.list_radius);
        r = copy_list(list, grid->order(), n);
      } else {
        AllPairs<D> ap;
        ap.build(ex, pos.data(), n, q.list_radius);
        list.build(ex, ap.view(), q.list_radius);
        r = copy_list(list, nullptr, n);
      }
      r.capacity = int64_t(list.capacity());
      r.grows = list.grows();
      out.push_back(std::move(r));
    }
    return out;
  }

  // the list's own arrays (every entry within the list radius), renumbered
  template <int D>
  Lists copy_list(const NeighborList<D, Exec>& list, const int* order_dev, int n) {
    auto off = this->download(list.offsets(), size_t(list.size()) + 1);
    auto nbr = this->download(list.neighbors(), size_t(off.back()));
    std::vector<int> order;
    if (order_dev) order = this->download(order_dev, size_t(list.size()));
    return renumber(off, nbr, order, n);
  }

  template <int D>
  void grid_sort_d(const IndexQuery& q, std::vector<uint64_t>& keys, std::vector<int>& order) {
    const int n = q.n;
    auto pos = this->template alloc<Vec<D>>(size_t(n));
    if (n) ex.to_device(pos.data(), q.pos.data(), size_t(n) * sizeof(Vec<D>));
    auto tags = this->upload(q.tags);
    CellGrid<D, Exec> grid(spec_of<D>(q, q.radius));
    grid.sort(ex, pos.data(), q.tags.empty() ? nullptr : tags.data(), n);
    keys = grid.sorted_keys_host(ex);
    order = this->download(grid.order(), size_t(n));
  }
  template <int D>
  std::vector<int> grid_walked_d(const IndexQuery& q) {
    const int n = q.n;
    auto pos = this->template alloc<Vec<D>>(size_t(n));
    if (n) ex.to_device(pos.data(), q.pos.data(), size_t(n) * sizeof(Vec<D>));
    auto tags = this->upload(q.tags);
    CellGrid<D, Exec> grid(spec_of<D>(q, q.list_radius));
    grid.build(ex, pos.data(), q.tags.empty() ? nullptr : tags.data(), n);
    auto walked = this->template alloc<int>(size_t(n));
    ex.for_each(n, WalkedFn<D>{tagged<D>(q, grid.view()).with_radius(q.radius), walked.data()});
    std::vector<int> sorted = this->download(walked.data(), size_t(n));
    const std::vector<int> order = this->download(grid.order(), size_t(n));
    std::vector<int> out(static_cast<size_t>(n));
    for (int s = 0; s < n; ++s) out[order[s]] = sorted[s];
    return out;
  }
};

// the backends (cuda: testing_cuda.cu, or its stub without the CUDA backend)
std::unique_ptr<PrimOps> make_cuda_prim_ops(int device);
std::unique_ptr<SpatialOps> make_cuda_spatial_ops(int device);
bool cuda_usable(std::string& why);

}  // namespace cps::testing
