// nanobind module corpuscle._testing: the engine's lower layers (exec primitives, Morton
// codes, spatial indexes) exposed to pytest on every backend ("serial", "cpu" and, where the
// CUDA backend is built and a device is usable, "cuda" / "cuda:N"). Test-only: nothing in
// the package imports it.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <cstring>
#include <optional>
#include <tuple>

#include "corpuscle/physics/dem.h"
#include "corpuscle/physics/polygon.h"
#include "corpuscle/physics/polygon_grid.h"
#include "corpuscle/spatial/lbvh.h"
#include "corpuscle/physics/triangle_mesh.h"
#include "cpu/exec_cpu.h"
#include "testing_ops.h"

namespace nb = nanobind;
using namespace cps;
using namespace cps::testing;

namespace {

using Array = nb::ndarray<nb::ro, nb::c_contig, nb::device::cpu>;

// ---- backends ----
CpuExec cpu_exec(bool parallel) {
  CpuExec e;
  e.parallel = parallel;
  return e;
}
int cuda_device_of(const std::string& b) {
  if (b == "cuda") return 0;
  if (b.rfind("cuda:", 0) == 0) return std::stoi(b.substr(5));
  return -1;
}
std::unique_ptr<PrimOps> prim_ops(const std::string& b) {
  if (b == "serial") return std::make_unique<PrimOpsImpl<CpuExec>>(cpu_exec(false));
  if (b == "cpu") return std::make_unique<PrimOpsImpl<CpuExec>>(cpu_exec(true));
  if (cuda_device_of(b) >= 0) return make_cuda_prim_ops(cuda_device_of(b));
  throw nb::value_error(("unknown backend '" + b + "' (serial, cpu, cuda, cuda:N)").c_str());
}
std::unique_ptr<SpatialOps> spatial_ops(const std::string& b) {
  if (b == "serial") return std::make_unique<SpatialOpsImpl<CpuExec>>(cpu_exec(false));
  if (b == "cpu") return std::make_unique<SpatialOpsImpl<CpuExec>>(cpu_exec(true));
  if (cuda_device_of(b) >= 0) return make_cuda_spatial_ops(cuda_device_of(b));
  throw nb::value_error(("unknown backend '" + b + "' (serial, cpu, cuda, cuda:N)").c_str());
}

// ---- arrays ----
template <class T>
bool is(const Array& a) {
  return a.dtype() == nb::dtype<T>();
}
template <class T>
std::vector<T> vec(const Array& a, const char* what) {
  if (!is<T>(a)) throw nb::type_error((std::string(what) + ": wrong dtype").c_str());
  std::vector<T> v(a.size());
  if (a.size()) std::memcpy(v.data(), a.data(), a.size() * sizeof(T));
  return v;
}
template <class T>
nb::ndarray<nb::numpy> np(const std::vector<T>& v, size_t cols = 0) {
  auto* buf = new T[v.size() > 0 ? v.size() : 1];
  if (!v.empty()) std::memcpy(buf, v.data(), v.size() * sizeof(T));
  nb::capsule owner(buf, [](void* p) noexcept { delete[] static_cast<T*>(p); });
  size_t shape[2] = {cols ? v.size() / cols : v.size(), cols};
  return nb::ndarray<nb::numpy>(buf, cols ? 2 : 1, shape, owner, nullptr, nb::dtype<T>());
}

int index_kind(const std::string& s) {
  if (s == "allpairs") return kAllPairs;
  if (s == "allpairs_tiled") return kAllPairsTiled;
  if (s == "grid") return kCellGrid;
  if (s == "csr_grid") return kCsrGrid;
  if (s == "csr_allpairs") return kCsrAllPairs;
  throw nb::value_error(
      ("unknown index '" + s + "' (allpairs, allpairs_tiled, grid, csr_grid, csr_allpairs; grid_rows, csr_grid_rows)").c_str());
}
bool rows_order(const std::string& s) {  // a grid's cell order: true for rows, false for Morton
  if (s == "rows") return true;
  if (s == "morton") return false;
  throw nb::value_error("order must be morton or rows");
}
int reduce_op(const std::string& s) {
  if (s == "sum") return kSum;
  if (s == "min") return kMin;
  if (s == "max") return kMax;
  throw nb::value_error("op must be sum, min or max");
}

IndexQuery query(const std::string& index, const Array& pos, float radius, std::optional<std::vector<float>> lo,
                 std::optional<std::vector<float>> hi, std::optional<Array> tags, int ntags, const std::string& tag_mode,
                 std::pair<int, int> tag_range, std::optional<float> list_radius) {
  IndexQuery q;
  // "<grid kind>_rows": the same index with its cells sorted in rows
  const std::string suffix = "_rows";
  const bool rows = index.size() > suffix.size() && index.compare(index.size() - suffix.size(), suffix.size(), suffix) == 0;
  q.kind = index_kind(rows ? index.substr(0, index.size() - suffix.size()) : index);
  if (rows && q.kind != kCellGrid && q.kind != kCsrGrid) throw nb::value_error("only the grid kinds take _rows");
  q.rows = rows;
  if (pos.ndim() != 2 || (pos.shape(1) != 2 && pos.shape(1) != 3))
    throw nb::value_error("positions must have shape (n, 2) or (n, 3)");
  q.dim = int(pos.shape(1));
  q.n = int(pos.shape(0));
  q.pos = vec<float>(pos, "positions");
  q.radius = radius;
  q.list_radius = list_radius ? *list_radius : radius;
  if (q.kind == kCellGrid || q.kind == kCsrGrid) {
    if (!lo || !hi || lo->size() != size_t(q.dim) || hi->size() != size_t(q.dim))
      throw nb::value_error("a grid index needs lo and hi with one value per axis");
  }
  if (lo) q.lo = *lo;
  if (hi) q.hi = *hi;
  if (tags) {
    q.tags = vec<int32_t>(*tags, "tags");
    if (q.tags.size() != size_t(q.n)) throw nb::value_error("tags: one per particle");
  }
  q.ntags = ntags;
  if (tag_mode == "all")
    q.tag_mode = kAllTags;
  else if (tag_mode == "range")
    q.tag_mode = kTagRange;
  else if (tag_mode == "own")
    q.tag_mode = kOwnTag;
  else
    throw nb::value_error("tag_mode must be all, range or own");
  q.tag_a = tag_range.first;
  q.tag_b = tag_range.second;
  return q;
}

nb::dict lists_dict(const Lists& l) {
  nb::dict d;
  d["offsets"] = np(l.offsets);
  d["neighbors"] = np(l.nbr);
  d["capacity"] = l.capacity;
  d["grows"] = l.grows;
  return d;
}

template <int D>
nb::dict spec_dict(const std::vector<float>& lo, const std::vector<float>& hi, float radius, int ntags,
                   uint64_t max_cells, bool rows) {
  Vec<D> l, h;
  for (int k = 0; k < D; ++k) {
    l[k] = lo.at(k);
    h[k] = hi.at(k);
  }
  CellGridSpec<D> g = make_cell_grid<D>(l, h, radius, ntags, max_cells, rows ? CellOrder::Rows : CellOrder::Morton);
  nb::dict d;
  std::vector<int> dims(g.dims, g.dims + D);
  d["dims"] = dims;
  d["ncells"] = g.ncells;
  d["table_entries"] = g.table_size();
  d["cell"] = g.cell;
  d["radius"] = g.radius;
  d["bits"] = g.bits;
  d["tag_shift"] = g.tag_shift();
  d["cell_bits"] = g.cell_bits;
  d["key_bits"] = g.key_bits;
  d["ntags"] = g.ntags;
  d["sentinel"] = CellGridSpec<D>::kSentinel;
  return d;
}


// ---- polygon and DEM contact (physics/polygon.h, physics/dem.h), host only ----
std::vector<float> points2(const Array& a, const char* what) {
  if (a.ndim() != 2 || a.shape(1) != 2) throw nb::value_error((std::string(what) + " must have shape (n, 2)").c_str());
  return vec<float>(a, what);
}
template <int D>
Vec<D> row(const std::vector<float>& a, size_t i) {
  Vec<D> r;
  for (int k = 0; k < D; ++k) r[k] = a[D * i + k];
  return r;
}
template <int D>
nb::tuple pair_forces_d(float k, float c, const std::vector<float>& xi, const std::vector<float>& vi,
                        const std::vector<float>& ri, const std::vector<float>& xj, const std::vector<float>& vj,
                        const std::vector<float>& rj) {
  size_t m = ri.size();
  std::vector<float> fi(D * m), fj(D * m), mag(m), magj(m);
  std::vector<uint8_t> touch(m);
  SpringDashpot law{k, c};
  for (size_t i = 0; i < m; ++i) {
    Vec<D> f, g;
    float a, b;
    bool t = pair_contact_force<D>(law, row<D>(xi, i), row<D>(vi, i), ri[i], row<D>(xj, i), row<D>(vj, i), rj[i], f, a);
    bool u = pair_contact_force<D>(law, row<D>(xj, i), row<D>(vj, i), rj[i], row<D>(xi, i), row<D>(vi, i), ri[i], g, b);
    for (int q = 0; q < D; ++q) {
      fi[D * i + q] = f[q];
      fj[D * i + q] = g[q];
    }
    mag[i] = a;
    magj[i] = b;
    touch[i] = uint8_t(t) | uint8_t(u) << 1;
  }
  return nb::make_tuple(np(fi, D), np(fj, D), np(mag), np(magj), np(touch));
}
}  // namespace

void bind_sph(nb::module_& m);  // testing_sph.cpp: SPH kernel families and pair terms

NB_MODULE(_testing, m) {
  m.doc() = "corpuscle engine internals for the tests: exec primitives and spatial indexes on each backend";
  // cps::Error (bad arguments, a grid past its cell limit, a missing device) is a ValueError,
  // as in corpuscle._core (whose translator would otherwise apply once _core is loaded)
  nb::register_exception_translator([](const std::exception_ptr& p, void*) {
    try {
      std::rethrow_exception(p);
    } catch (const cps::Error& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    }
  });

  m.def("cuda_available", []() {
    std::string why;
    bool ok = cuda_usable(why);
    return std::make_pair(ok, why);
  });
  m.def("backends", []() {
    std::vector<std::string> b{"serial", "cpu"};
    std::string why;
    if (cuda_usable(why)) b.push_back("cuda");
    return b;
  });
  m.def("openmp", []() {
#ifdef CPS_WITH_OPENMP
    return true;
#else
    return false;
#endif
  });

  // ---- Morton codes (host) ----
  m.def(
      "morton_encode",
      [](const Array& coords, bool wide) {
        if (coords.ndim() != 2 || (coords.shape(1) != 2 && coords.shape(1) != 3))
          throw nb::value_error("coords must have shape (n, 2) or (n, 3)");
        const int D = int(coords.shape(1));
        auto c = vec<int32_t>(coords, "coords");
        const size_t n = coords.shape(0);
        std::vector<uint64_t> out(n);
        for (size_t i = 0; i < n; ++i) {
          const int* p = c.data() + i * D;
          if (wide)
            out[i] = D == 3 ? morton_encode64<3>(p) : morton_encode64<2>(p);
          else
            out[i] = D == 3 ? morton_encode<3>(p) : morton_encode<2>(p);
        }
        return np(out);
      },
      nb::arg("coords"), nb::arg("wide"));
  m.def(
      "morton_decode",
      [](const Array& codes, int dim, bool wide) {
        auto c = vec<uint64_t>(codes, "codes");
        if (dim != 2 && dim != 3) throw nb::value_error("dim must be 2 or 3");
        std::vector<int32_t> out(c.size() * dim);
        for (size_t i = 0; i < c.size(); ++i) {
          int* p = out.data() + i * dim;
          if (wide) {
            if (dim == 3) morton_decode64<3>(c[i], p); else morton_decode64<2>(c[i], p);
          } else {
            if (dim == 3) morton_decode<3>(uint32_t(c[i]), p); else morton_decode<2>(uint32_t(c[i]), p);
          }
        }
        return np(out, size_t(dim));
      },
      nb::arg("codes"), nb::arg("dim"), nb::arg("wide"));
  // ---- the LBVH walk over a given hierarchy ----
  m.def(
      "lbvh_walk",
      [](const Array& pos, const Array& left, const Array& right, const Array& rightmost, const Array& boxes,
         const Array& qlo, const Array& qhi, int stack_depth, bool after) {
        // the walk of spatial/lbvh.h (LbvhView::walk with the CPU's stack, as the backends run
        // it on the host) over a hierarchy the caller built: n leaves (slots) at pos (n x 2),
        // n - 1 internal nodes (children >= n - 1 are leaves; boxes: lo x, lo y, hi x, hi y);
        // query q visits the slots in [qlo[q], qhi[q]] (after: only slots > q, the reflexive
        // walk). Returns (per query: the visited slots in walk order) and the overflow flag.
        auto p = vec<float>(pos, "pos");
        const int n = int(p.size() / 2);
        auto l = vec<int32_t>(left, "left"), r = vec<int32_t>(right, "right"), rm = vec<int32_t>(rightmost, "rightmost");
        auto b = vec<float>(boxes, "boxes"), lo = vec<float>(qlo, "qlo"), hi = vec<float>(qhi, "qhi");
        if (n < 1 || p.size() != size_t(2 * n) || l.size() != size_t(n - 1) || r.size() != size_t(n - 1) ||
            rm.size() != size_t(n - 1) || b.size() != size_t(4 * (n - 1)) || lo.size() != hi.size() || lo.size() % 2)
          throw nb::value_error("lbvh_walk: pos n x 2, left/right/rightmost n - 1, boxes (n - 1) x 4, qlo = qhi q x 2");
        for (int c = 0; c < n - 1; ++c)
          if (l[c] < 1 || l[c] > 2 * n - 2 || r[c] < 1 || r[c] > 2 * n - 2)
            throw nb::value_error("lbvh_walk: a child index outside 1 .. 2n - 2");
        int overflow = 0;
        LbvhView<2> v{reinterpret_cast<const Vec<2>*>(p.data()), l.data(), r.data(), rm.data(), b.data(), n, 0.0f,
                      &overflow, 7, stack_depth};
        nb::list out;
        const int nq = int(lo.size() / 2);
        for (int q = 0; q < nq; ++q) {
          std::vector<int> seen;
          auto visit = [&](int j) {
            if (seen.size() < size_t(4 * n)) seen.push_back(j);  // (a loop would repeat: bounded)
          };
          if (after) v.query_box_after(q, &lo[2 * q], &hi[2 * q], visit);
          else v.query_box(&lo[2 * q], &hi[2 * q], visit);
          out.append(np(seen));
        }
        return nb::make_tuple(out, overflow);
      },
      nb::arg("pos"), nb::arg("left"), nb::arg("right"), nb::arg("rightmost"), nb::arg("boxes"), nb::arg("qlo"),
      nb::arg("qhi"), nb::arg("stack_depth"), nb::arg("after") = false);
  m.def("lbvh_stack_sizes", []() { return nb::make_tuple(kLbvhStack, kLbvhMaxStack); });

  m.def("morton_max_bits", [](int dim, bool wide) {
    if (wide) return dim == 3 ? morton_max_bits64<3>() : morton_max_bits64<2>();
    return dim == 3 ? morton_max_bits<3>() : morton_max_bits<2>();
  });

  // ---- exec primitives ----
  m.def(
      "exclusive_scan",
      [](const std::string& backend, const Array& values, bool wide) -> nb::tuple {
        auto ops = prim_ops(backend);
        if (is<int32_t>(values)) {
          auto in = vec<int32_t>(values, "values");
          if (wide) {
            int64_t t;
            auto o = ops->scan_i32_i64(in, t);
            return nb::make_tuple(np(o), t);
          }
          int32_t t;
          auto o = ops->scan_i32(in, t);
          return nb::make_tuple(np(o), t);
        }
        auto in = vec<uint32_t>(values, "values (int32 or uint32)");
        if (wide) {
          int64_t t;
          auto o = ops->scan_u32_i64(in, t);
          return nb::make_tuple(np(o), t);
        }
        uint32_t t;
        auto o = ops->scan_u32(in, t);
        return nb::make_tuple(np(o), t);
      },
      nb::arg("backend"), nb::arg("values"), nb::arg("wide") = false);
  m.def(
      "select_flagged",
      [](const std::string& backend, const Array& flags) {
        return np(prim_ops(backend)->select_flagged(vec<int32_t>(flags, "flags")));
      },
      nb::arg("backend"), nb::arg("flags"));
  m.def(
      "segmented_reduce",
      [](const std::string& backend, const Array& items, const Array& offsets, const std::string& op,
         double init) -> nb::object {
        auto ops = prim_ops(backend);
        if (is<float>(items)) {
          auto o = ops->segreduce_f32(vec<float>(items, "items"), vec<int32_t>(offsets, "offsets (int32 for float items)"),
                                      reduce_op(op), float(init));
          return nb::cast(np(o));
        }
        auto o = ops->segreduce_i32(vec<int32_t>(items, "items (float32 or int32)"),
                                    vec<int64_t>(offsets, "offsets (int64 for int32 items)"), reduce_op(op), int(init));
        return nb::cast(np(o));
      },
      nb::arg("backend"), nb::arg("items"), nb::arg("offsets"), nb::arg("op"), nb::arg("init"));
  m.def(
      "fused_reduce",
      [](const std::string& backend, const Array& items, const std::string& op, double init) {
        return np(prim_ops(backend)->fused_reduce(vec<float>(items, "items"), reduce_op(op), float(init)));
      },
      nb::arg("backend"), nb::arg("items"), nb::arg("op"), nb::arg("init"));
  m.def(
      "sort_pairs64",
      [](const std::string& backend, const Array& keys, const Array& values, int bits) {
        std::vector<uint64_t> ko;
        std::vector<int> vo;
        prim_ops(backend)->sort_pairs64(vec<uint64_t>(keys, "keys"), vec<int32_t>(values, "values"), bits, ko, vo);
        return nb::make_tuple(np(ko), np(vo));
      },
      nb::arg("backend"), nb::arg("keys"), nb::arg("values"), nb::arg("bits") = 64);
  m.def(
      "tile_exercise",
      [](const std::string& backend, const Array& x, int tile) {
        return np(prim_ops(backend)->tile_exercise(vec<float>(x, "x"), tile));
      },
      nb::arg("backend"), nb::arg("x"), nb::arg("tile"));
  m.def(
      "lanes_gather",
      [](const std::string& backend, const Array& pos, float radius, int width) {
        std::vector<int> counts;
        auto sums = prim_ops(backend)->lanes_gather(vec<float>(pos, "pos"), radius, width, counts);
        return nb::make_tuple(np(counts), np(sums));
      },
      nb::arg("backend"), nb::arg("pos"), nb::arg("radius"), nb::arg("width"),
      "Counts and sums of r^2 of every point's neighbours within radius (3-D), walked by `width` lanes.");
  m.def(
      "for_each_if",
      [](const std::string& backend, int flag, int n) { return np(prim_ops(backend)->for_each_if(flag, n)); },
      nb::arg("backend"), nb::arg("flag"), nb::arg("n"));
  m.def(
      "atomics",
      [](const std::string& backend, const Array& v) {
        AtomicsResult r = prim_ops(backend)->atomics(vec<int32_t>(v, "values"));
        nb::dict d;
        d["isum"] = r.isum;
        d["imax"] = r.imax;
        d["imin"] = r.imin;
        d["owner"] = r.owner;
        d["wins"] = r.wins;
        d["usum"] = r.usum;
        d["fsum"] = r.fsum;
        return d;
      },
      nb::arg("backend"), nb::arg("values"));

  // ---- spatial indexes ----
  m.def(
      "cell_grid_spec",
      [](int dim, std::vector<float> lo, std::vector<float> hi, float radius, int ntags, uint64_t max_cells,
         const std::string& order) {
        if (dim == 2) return spec_dict<2>(lo, hi, radius, ntags, max_cells, rows_order(order));
        if (dim == 3) return spec_dict<3>(lo, hi, radius, ntags, max_cells, rows_order(order));
        throw nb::value_error("dim must be 2 or 3");
      },
      nb::arg("dim"), nb::arg("lo"), nb::arg("hi"), nb::arg("radius"), nb::arg("ntags") = 1,
      nb::arg("max_cells") = kCellGridMaxCells, nb::arg("order") = "morton");

  m.def(
      "gather",
      [](const std::string& backend, const std::string& index, const Array& pos, float radius,
         std::optional<std::vector<float>> lo, std::optional<std::vector<float>> hi, std::optional<Array> tags,
         int ntags, const std::string& tag_mode, std::pair<int, int> tag_range, std::optional<float> list_radius) {
        IndexQuery q = query(index, pos, radius, lo, hi, tags, ntags, tag_mode, tag_range, list_radius);
        return lists_dict(spatial_ops(backend)->gather(q));
      },
      nb::arg("backend"), nb::arg("index"), nb::arg("positions"), nb::arg("radius"), nb::arg("lo") = nb::none(),
      nb::arg("hi") = nb::none(), nb::arg("tags") = nb::none(), nb::arg("ntags") = 1, nb::arg("tag_mode") = "all",
      nb::arg("tag_range") = std::make_pair(0, 1), nb::arg("list_radius") = nb::none());
  m.def(
      "pairs",
      [](const std::string& backend, const std::string& index, const Array& pos, float radius,
         std::optional<std::vector<float>> lo, std::optional<std::vector<float>> hi, std::optional<Array> tags,
         int ntags, const std::string& tag_mode, std::pair<int, int> tag_range, std::optional<float> list_radius) {
        IndexQuery q = query(index, pos, radius, lo, hi, tags, ntags, tag_mode, tag_range, list_radius);
        return np(spatial_ops(backend)->pairs(q), 2);
      },
      nb::arg("backend"), nb::arg("index"), nb::arg("positions"), nb::arg("radius"), nb::arg("lo") = nb::none(),
      nb::arg("hi") = nb::none(), nb::arg("tags") = nb::none(), nb::arg("ntags") = 1, nb::arg("tag_mode") = "all",
      nb::arg("tag_range") = std::make_pair(0, 1), nb::arg("list_radius") = nb::none());
  m.def(
      "csr_rebuilds",
      [](const std::string& backend, const std::string& index, std::vector<Array> positions, float radius,
         std::optional<std::vector<float>> lo, std::optional<std::vector<float>> hi, std::optional<float> list_radius) {
        if (positions.empty()) throw nb::value_error("csr_rebuilds: no position sets");
        IndexQuery q = query(index, positions[0], radius, lo, hi, std::nullopt, 1, "all", {0, 1}, list_radius);
        std::vector<std::vector<float>> sets;
        for (const auto& p : positions) sets.push_back(vec<float>(p, "positions"));
        nb::list out;
        for (const auto& l : spatial_ops(backend)->csr_rebuilds(q, sets)) out.append(lists_dict(l));
        return out;
      },
      nb::arg("backend"), nb::arg("index"), nb::arg("positions"), nb::arg("radius"), nb::arg("lo") = nb::none(),
      nb::arg("hi") = nb::none(), nb::arg("list_radius") = nb::none());
  m.def(
      "grid_sort",
      [](const std::string& backend, const Array& pos, float radius, std::vector<float> lo, std::vector<float> hi,
         std::optional<Array> tags, int ntags, const std::string& cells) {
        IndexQuery q = query("grid", pos, radius, lo, hi, tags, ntags, "all", {0, 1}, std::nullopt);
        q.rows = rows_order(cells);
        std::vector<uint64_t> keys;
        std::vector<int> order;
        spatial_ops(backend)->grid_sort(q, keys, order);
        return nb::make_tuple(np(keys), np(order));
      },
      nb::arg("backend"), nb::arg("positions"), nb::arg("radius"), nb::arg("lo"), nb::arg("hi"),
      nb::arg("tags") = nb::none(), nb::arg("ntags") = 1, nb::arg("order") = "morton");
  m.def(
      "grid_walked",
      [](const std::string& backend, const Array& pos, float radius, std::vector<float> lo, std::vector<float> hi,
         std::optional<float> query_radius, const std::string& order) {
        // (cells of the list radius, queried within the radius: as a `lists` build's view)
        IndexQuery q = query("grid", pos, query_radius ? *query_radius : radius, lo, hi, std::nullopt, 1, "all", {0, 1},
                             radius);
        q.rows = rows_order(order);
        return np(spatial_ops(backend)->grid_walked(q));
      },
      nb::arg("backend"), nb::arg("positions"), nb::arg("radius"), nb::arg("lo"), nb::arg("hi"),
      nb::arg("query_radius") = nb::none(), nb::arg("order") = "morton",
      "the candidates each particle's cell walk reads (the slots of the cells it visits) in a grid of cells of "
      "`radius`, queried within `query_radius` (default: the radius)");
  // ---- polygon signed distance and DEM contacts ----
  m.def(
      "polygon_sdf",
      [](const Array& vertices, const Array& points, const std::string& layout) {
        std::vector<float> xy = points2(vertices, "vertices"), p = points2(points, "points");
        int n = int(xy.size() / 2);
        if (n < 3) throw nb::value_error("a polygon needs at least 3 vertices");
        PolygonVertices V{xy.data(), n};
        std::vector<float> edges(size_t(kEdgeStride) * n);
        polygon_write_edges(V, edges.data());
        PolygonEdges E{edges.data(), n};
        if (layout != "vertices" && layout != "edges") throw nb::value_error("layout must be vertices or edges");
        size_t m = p.size() / 2;
        std::vector<float> d(m), nrm(2 * m), q(2 * m);
        std::vector<int32_t> edge(m), vertex(m);
        std::vector<uint8_t> inside(m);
        for (size_t i = 0; i < m; ++i) {
          Vec2 x{{p[2 * i], p[2 * i + 1]}};
          PolygonHit h = layout == "edges" ? polygon_sdf(E, x) : polygon_sdf(V, x);
          d[i] = h.distance;
          nrm[2 * i] = h.normal[0];
          nrm[2 * i + 1] = h.normal[1];
          q[2 * i] = h.closest[0];
          q[2 * i + 1] = h.closest[1];
          edge[i] = h.edge;
          vertex[i] = h.vertex;
          inside[i] = layout == "edges" ? polygon_contains(E, x) : polygon_contains(V, x);
        }
        nb::dict r;
        r["distance"] = np(d);
        r["normal"] = np(nrm, 2);
        r["closest"] = np(q, 2);
        r["edge"] = np(edge);
        r["vertex"] = np(vertex);
        r["inside"] = np(inside);
        return r;
      },
      nb::arg("vertices"), nb::arg("points"), nb::arg("layout") = "vertices",
      "Signed distance (negative inside), outward normal, closest point and feature of each point "
      "(float32 (m, 2)) against the counter-clockwise polygon (float32 (n, 2)).");
  // ---- triangles and triangle meshes (physics/triangle.h, triangle_mesh.h), host only ----
  m.def(
      "triangle_closest",
      [](const Array& points, const Array& a, const Array& b, const Array& c) {
        auto rows3 = [](const Array& x, const char* what) {
          if (x.ndim() != 2 || x.shape(1) != 3) throw nb::value_error((std::string(what) + " must have shape (n, 3)").c_str());
          return vec<float>(x, what);
        };
        std::vector<float> p = rows3(points, "points"), A = rows3(a, "a"), B = rows3(b, "b"), C = rows3(c, "c");
        size_t m = p.size() / 3;
        if (A.size() != p.size() || B.size() != p.size() || C.size() != p.size())
          throw nb::value_error("points, a, b and c must have the same shape");
        std::vector<float> q(3 * m);
        std::vector<int32_t> feature(m);
        for (size_t i = 0; i < m; ++i) {
          TriClosest t = closest_point_on_triangle(row<3>(p, i), row<3>(A, i), row<3>(B, i), row<3>(C, i));
          for (int k = 0; k < 3; ++k) q[3 * i + k] = t.q[k];
          feature[i] = t.feature;
        }
        return nb::make_tuple(np(q, 3), np(feature));
      },
      nb::arg("points"), nb::arg("a"), nb::arg("b"), nb::arg("c"),
      "The closest point of triangle (a[i], b[i], c[i]) to points[i] (float32 (n, 3) each) and its feature "
      "(0 face, 1 ab, 2 bc, 3 ca, 4 a, 5 b, 6 c).");
  m.def(
      "mesh_sdf",
      [](const Array& vertices, const Array& faces, const Array& points) {
        if (vertices.ndim() != 2 || vertices.shape(1) != 3) throw nb::value_error("vertices must have shape (n, 3)");
        if (faces.ndim() != 2 || faces.shape(1) != 3) throw nb::value_error("faces must have shape (m, 3)");
        if (points.ndim() != 2 || points.shape(1) != 3) throw nb::value_error("points must have shape (k, 3)");
        std::vector<double> V = vec<double>(vertices, "vertices");
        std::vector<int64_t> F = vec<int64_t>(faces, "faces");
        std::vector<float> p = vec<float>(points, "points");
        std::vector<float> rec;
        std::string bad = write_triangle_records(V.data(), int64_t(V.size() / 3), F.data(), int64_t(F.size() / 3), rec);
        if (!bad.empty()) throw nb::value_error(bad.c_str());
        MeshTriangles M{rec.data(), int(F.size() / 3)};
        size_t m = p.size() / 3;
        std::vector<float> d(m), nrm(3 * m), q(3 * m);
        std::vector<int32_t> tri(m), feature(m);
        for (size_t i = 0; i < m; ++i) {
          MeshHit h = mesh_sdf(M, row<3>(p, i));
          d[i] = h.distance;
          for (int k = 0; k < 3; ++k) {
            nrm[3 * i + k] = h.normal[k];
            q[3 * i + k] = h.closest[k];
          }
          tri[i] = h.triangle;
          feature[i] = h.feature;
        }
        nb::dict r;
        r["distance"] = np(d);
        r["normal"] = np(nrm, 3);
        r["closest"] = np(q, 3);
        r["triangle"] = np(tri);
        r["feature"] = np(feature);
        r["records"] = np(rec, kTriStride);
        return r;
      },
      nb::arg("vertices"), nb::arg("faces"), nb::arg("points"),
      "Signed distance (negative inside), outward normal, closest point, triangle and feature of each point "
      "(float32 (k, 3)) against the closed mesh (vertices float64 (n, 3), faces int64 (m, 3), outward winding); "
      "its triangle records too. A mesh that is not closed and consistently wound is a ValueError.");
  m.def(
      "mesh_tree_sdf",
      [](const std::string& backend, const Array& vertices, const Array& faces, const Array& points, float reach,
         bool exact) {
        if (vertices.ndim() != 2 || vertices.shape(1) != 3) throw nb::value_error("vertices must have shape (n, 3)");
        if (faces.ndim() != 2 || faces.shape(1) != 3) throw nb::value_error("faces must have shape (m, 3)");
        if (points.ndim() != 2 || points.shape(1) != 3) throw nb::value_error("points must have shape (k, 3)");
        std::vector<double> V = vec<double>(vertices, "vertices");
        std::vector<int64_t> F = vec<int64_t>(faces, "faces");
        std::vector<float> rec;
        std::string bad = write_triangle_records(V.data(), int64_t(V.size() / 3), F.data(), int64_t(F.size() / 3), rec);
        if (!bad.empty()) throw nb::value_error(bad.c_str());
        std::vector<float> box = {3e38f, 3e38f, 3e38f, -3e38f, -3e38f, -3e38f};
        for (size_t i = 0; i < V.size(); ++i) {
          box[i % 3] = std::min(box[i % 3], float(V[i]));
          box[3 + i % 3] = std::max(box[3 + i % 3], float(V[i]));
        }
        MeshQuery r = spatial_ops(backend)->mesh_tree(rec, int(F.size() / 3), box, vec<float>(points, "points"), reach,
                                                      exact);
        nb::dict d;
        d["distance"] = np(r.distance);
        d["normal"] = np(r.normal, 3);
        d["closest"] = np(r.closest, 3);
        d["triangle"] = np(r.triangle);
        d["feature"] = np(r.feature);
        d["overflow"] = r.overflow;
        return d;
      },
      nb::arg("backend"), nb::arg("vertices"), nb::arg("faces"), nb::arg("points"), nb::arg("reach"),
      nb::arg("exact") = true,
      "mesh_sdf through the triangle LBVH (dem/mesh_body.h) on a backend: exact (nearest) or within the cube "
      "of half-size reach (near; triangle -1 where none overlaps it).");
  m.def(
      "mesh_contact",
      [](const std::string& backend, const Array& vertices, const Array& faces, const Array& x, const Array& v,
         float radius, float k, float c) {
        if (vertices.ndim() != 2 || vertices.shape(1) != 3) throw nb::value_error("vertices must have shape (n, 3)");
        if (faces.ndim() != 2 || faces.shape(1) != 3) throw nb::value_error("faces must have shape (m, 3)");
        if (x.ndim() != 2 || x.shape(1) != 3 || v.ndim() != 2 || v.shape(1) != 3 || x.shape(0) != v.shape(0))
          throw nb::value_error("x and v must have the same shape (k, 3)");
        std::vector<double> V = vec<double>(vertices, "vertices");
        std::vector<int64_t> F = vec<int64_t>(faces, "faces");
        std::vector<float> rec;
        std::string bad = write_triangle_records(V.data(), int64_t(V.size() / 3), F.data(), int64_t(F.size() / 3), rec);
        if (!bad.empty()) throw nb::value_error(bad.c_str());
        std::vector<float> box = {3e38f, 3e38f, 3e38f, -3e38f, -3e38f, -3e38f};
        for (size_t i = 0; i < V.size(); ++i) {
          box[i % 3] = std::min(box[i % 3], float(V[i]));
          box[3 + i % 3] = std::max(box[3 + i % 3], float(V[i]));
        }
        auto r = spatial_ops(backend)->mesh_contact(rec, int(F.size() / 3), box, vec<float>(x, "x"), vec<float>(v, "v"),
                                                    radius, k, c);
        nb::dict d;
        d["force"] = np(r[0], 3);
        d["magnitude"] = np(r[1]);
        d["moved"] = np(r[2]);
        d["x"] = np(r[3], 3);
        d["v"] = np(r[4], 3);
        return d;
      },
      nb::arg("backend"), nb::arg("vertices"), nb::arg("faces"), nb::arg("x"), nb::arg("v"), nb::arg("radius"),
      nb::arg("k"), nb::arg("c"),
      "dem/mesh_body.h's mesh_contact_force then mesh_keep_out on each particle (float32 (k, 3) x, v) on a "
      "backend: force on the particle, its magnitude, whether keep_out moved it, and x, v after it.");
  m.def(
      "polygon_grid_sdf",
      [](const Array& vertices, const Array& points, float reach, int resolution) {
        std::vector<float> xy = points2(vertices, "vertices"), p = points2(points, "points");
        int n = int(xy.size() / 2);
        if (n < 3) throw nb::value_error("a polygon needs at least 3 vertices");
        if (!(reach >= 0.0f)) throw nb::value_error("reach must not be negative");
        std::vector<float> edges(size_t(kEdgeStride) * n);
        polygon_write_edges(PolygonVertices{xy.data(), n}, edges.data());
        PolygonEdges E{edges.data(), n};
        const PolygonGridTables t = build_polygon_grid(E, reach, resolution);
        const PolygonGrid G{E, t.view(t.start.data(), t.refs.data(), t.flag.data())};
        size_t m = p.size() / 2;
        std::vector<float> d(m), nrm(2 * m), q(2 * m);
        std::vector<int32_t> edge(m), vertex(m), listed(m);
        std::vector<uint8_t> inside(m), flag(m);
        for (size_t i = 0; i < m; ++i) {
          Vec2 x{{p[2 * i], p[2 * i + 1]}};
          PolygonHit h = polygon_sdf(G, x);
          d[i] = h.distance;
          nrm[2 * i] = h.normal[0];
          nrm[2 * i + 1] = h.normal[1];
          q[2 * i] = h.closest[0];
          q[2 * i + 1] = h.closest[1];
          edge[i] = h.edge;
          vertex[i] = h.vertex;
          inside[i] = polygon_contains(G, x);
          const int c = G.cells.cell_of(x);
          flag[i] = c < 0 ? 255 : t.flag[size_t(c)];
          listed[i] = c < 0 ? 0 : t.start[size_t(c) + 1] - t.start[size_t(c)];
        }
        nb::dict r;
        r["distance"] = np(d);
        r["normal"] = np(nrm, 2);
        r["closest"] = np(q, 2);
        r["edge"] = np(edge);
        r["vertex"] = np(vertex);
        r["inside"] = np(inside);
        r["flag"] = np(flag);
        r["listed"] = np(listed);
        r["dims"] = nb::make_tuple(t.dims[0], t.dims[1]);
        r["cell"] = t.cell;
        r["origin"] = nb::make_tuple(t.origin[0], t.origin[1]);
        r["refs"] = int(t.start.back());
        return r;
      },
      nb::arg("vertices"), nb::arg("points"), nb::arg("reach"), nb::arg("resolution") = 256,
      "polygon_sdf through physics/polygon_grid.h's grid for contacts within reach: the same dict, plus "
      "each point's cell flag (0 far, 1 outside, 2 inside, 3 straddling, 255 off the grid), the edges its "
      "cell lists, and the grid's dims, cell edge, origin and list length.");
  m.def(
      "polygon_edges",
      [](const Array& vertices) {
        std::vector<float> xy = points2(vertices, "vertices");
        int n = int(xy.size() / 2);
        std::vector<float> edges(size_t(kEdgeStride) * n);
        polygon_write_edges(PolygonVertices{xy.data(), n}, edges.data());
        Box2 b = polygon_bbox(PolygonVertices{xy.data(), n});
        return nb::make_tuple(np(edges, kEdgeStride), nb::make_tuple(b.lo[0], b.lo[1], b.hi[0], b.hi[1]));
      },
      nb::arg("vertices"), "The flat edge records (n, kEdgeStride) and the bounding box (xlo, ylo, xhi, yhi).");
  m.def(
      "dem_law",
      [](float k, float c, float m1, float m2) {
        SpringDashpot law{k, c};
        float me = effective_mass(m1, m2);
        nb::dict r;
        r["m_eff"] = me;
        r["zeta"] = damping_ratio(law, me);
        r["restitution"] = restitution_from_damping(law, me);
        r["contact_time"] = contact_time(law, me);
        return r;
      },
      nb::arg("k"), nb::arg("c"), nb::arg("m1"), nb::arg("m2") = 0.0f,
      "Effective mass, damping ratio, restitution and contact time of the spring-dashpot law (m2 <= 0: a wall).");
  m.def(
      "dem_damping",
      [](float k, float e, float m1, float m2) { return damping_from_restitution(k, e, effective_mass(m1, m2)); },
      nb::arg("k"), nb::arg("e"), nb::arg("m1"), nb::arg("m2") = 0.0f, "The damping c giving restitution e.");
  m.def(
      "dem_pair_forces",
      [](float k, float c, const Array& xi, const Array& vi, const Array& ri, const Array& xj, const Array& vj,
         const Array& rj) {
        if (xi.ndim() != 2 || (xi.shape(1) != 2 && xi.shape(1) != 3))
          throw nb::value_error("positions must have shape (m, 2) or (m, 3)");
        int D = int(xi.shape(1));
        auto a = vec<float>(xi, "xi"), b = vec<float>(vi, "vi"), e = vec<float>(xj, "xj"), f = vec<float>(vj, "vj");
        auto r1 = vec<float>(ri, "ri"), r2 = vec<float>(rj, "rj");
        size_t m = xi.shape(0);
        if (b.size() != D * m || e.size() != D * m || f.size() != D * m || r1.size() != m || r2.size() != m)
          throw nb::value_error("dem_pair_forces: inconsistent shapes");
        return D == 2 ? pair_forces_d<2>(k, c, a, b, r1, e, f, r2) : pair_forces_d<3>(k, c, a, b, r1, e, f, r2);
      },
      nb::arg("k"), nb::arg("c"), nb::arg("xi"), nb::arg("vi"), nb::arg("ri"), nb::arg("xj"), nb::arg("vj"),
      nb::arg("rj"),
      "Per pair, each computed both ways (i from j, j from i): the force on i, the force on j, |F| for i and for j, "
      "and touch flags (bit 0: i's call, bit 1: j's call).");
  m.def(
      "dem_polygon_forces",
      [](float k, float c, const Array& vertices, const Array& x, const Array& v, float r) {
        std::vector<float> xy = points2(vertices, "vertices"), p = points2(x, "x"), u = points2(v, "v");
        if (u.size() != p.size()) throw nb::value_error("x and v: one row per particle");
        int n = int(xy.size() / 2);
        PolygonVertices V{xy.data(), n};
        SpringDashpot law{k, c};
        size_t m = p.size() / 2;
        std::vector<float> f(2 * m), mag(m), sd(m);
        std::vector<uint8_t> touch(m);
        for (size_t i = 0; i < m; ++i) {
          Vec2 g;
          PolygonHit h;
          touch[i] = polygon_contact_force(law, V, Vec2{{p[2 * i], p[2 * i + 1]}}, Vec2{{u[2 * i], u[2 * i + 1]}}, r,
                                           g, mag[i], h);
          f[2 * i] = g[0];
          f[2 * i + 1] = g[1];
          sd[i] = h.distance;
        }
        return nb::make_tuple(np(f, 2), np(mag), np(touch), np(sd));
      },
      nb::arg("k"), nb::arg("c"), nb::arg("vertices"), nb::arg("x"), nb::arg("v"), nb::arg("radius"),
      "Per particle against the resting polygon: force on the particle, |F|, contact, signed distance.");

  bind_sph(m);
}
