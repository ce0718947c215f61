// corpuscle._core.Simulation: one class for every scene kind on every backend. Fields,
// scalars and controls go through the kind's tables (sim/table.h), so nothing here names a
// kind: a field is a zero-copy view (NumPy on the CPU, DLPack on CUDA), the record's scalars
// a dict, a checkpoint a dict of arrays and scalars.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>

#include "corpuscle/core/error.h"
#include "corpuscle/sim/registry.h"

namespace nb = nanobind;
using namespace cps;

namespace {

// parameters from a dict of numbers, lists of numbers and dicts (lists of dicts for tables)
class DictParams final : public ParamSource {
 public:
  explicit DictParams(nb::dict d, std::string where = "") : d_(std::move(d)), where_(std::move(where)) {}
  bool has(const std::string& key) const override { return d_.contains(key.c_str()); }
  double number(const std::string& key) const override {
    try {
      return nb::cast<double>(get(key));
    } catch (const nb::cast_error&) {
      throw Error("parameter '" + name(key) + "' must be a number");
    }
  }
  long long integer(const std::string& key) const override {
    try {
      return nb::cast<long long>(get(key));
    } catch (const nb::cast_error&) {
      throw Error("parameter '" + name(key) + "' must be an integer");
    }
  }
  std::vector<double> numbers(const std::string& key) const override {
    try {
      return nb::cast<std::vector<double>>(get(key));
    } catch (const nb::cast_error&) {
      throw Error("parameter '" + name(key) + "' must be a list of numbers");
    }
  }
  std::vector<std::unique_ptr<ParamSource>> tables(const std::string& key) const override {
    std::vector<std::unique_ptr<ParamSource>> out;
    nb::handle v = get(key);
    if (!nb::isinstance<nb::list>(v)) throw Error("parameter '" + name(key) + "' must be a list of tables");
    size_t k = 0;
    for (nb::handle item : nb::borrow<nb::list>(v)) {
      if (!nb::isinstance<nb::dict>(item)) throw Error("parameter '" + name(key) + "' must be a list of tables");
      out.push_back(std::make_unique<DictParams>(nb::borrow<nb::dict>(item), name(key) + "[" + std::to_string(k++) + "]."));
    }
    return out;
  }
  std::unique_ptr<ParamSource> table(const std::string& key) const override {
    nb::handle v = get(key);
    if (!nb::isinstance<nb::dict>(v)) throw Error("parameter '" + name(key) + "' must be a table");
    return std::make_unique<DictParams>(nb::borrow<nb::dict>(v), name(key) + ".");
  }

 private:
  std::string name(const std::string& key) const { return where_ + key; }
  nb::handle get(const std::string& key) const {
    if (!d_.contains(key.c_str())) throw Error("missing parameter '" + name(key) + "'");
    return d_[key.c_str()];
  }
  nb::dict d_;
  std::string where_;
};

using F32Array = nb::ndarray<const float, nb::c_contig, nb::device::cpu>;

// initial arrays: name -> float32 array of shape (n, components) or (n,)
class DictArrays final : public ArraySource {
 public:
  explicit DictArrays(nb::dict d) {
    for (auto [k, v] : d) {
      auto a = nb::cast<F32Array>(v);
      ArrayView view{a.data(), a.ndim() > 0 ? (long long)a.shape(0) : 0, a.ndim() > 1 ? int(a.shape(1)) : 1};
      arrays_.emplace_back(nb::cast<std::string>(k), view);
      keep_.push_back(a);
    }
  }
  bool has(const std::string& name) const override {
    for (auto& [n, v] : arrays_)
      if (n == name) return true;
    return false;
  }
  ArrayView get(const std::string& name) const override {
    for (auto& [n, v] : arrays_)
      if (n == name) return v;
    throw Error("no initial array '" + name + "'");
  }

 private:
  std::vector<std::pair<std::string, ArrayView>> arrays_;
  std::vector<F32Array> keep_;
};

nb::dlpack::dtype dl(DType t) {
  switch (t) {
    case DType::F32: return nb::dtype<float>();
    case DType::F64: return nb::dtype<double>();
    case DType::I32: return nb::dtype<int>();
    case DType::I64: return nb::dtype<long long>();
  }
  return nb::dtype<float>();
}

// one scalar of a record or control as Python values (a number, or a list of `count`)
nb::object scalar_value(const ScalarInfo& s, const unsigned char* base) {
  const unsigned char* p = base + s.offset;
  auto one = [&](int k) -> nb::object {
    switch (s.dtype) {
      case DType::F32: { float v; std::memcpy(&v, p + 4 * k, 4); return nb::float_(double(v)); }
      case DType::F64: { double v; std::memcpy(&v, p + 8 * k, 8); return nb::float_(v); }
      case DType::I32: { int v; std::memcpy(&v, p + 4 * k, 4); return nb::int_(v); }
      case DType::I64: { long long v; std::memcpy(&v, p + 8 * k, 8); return nb::int_(v); }
    }
    return nb::none();
  };
  if (s.count == 1) return one(0);
  nb::list l;
  for (int k = 0; k < s.count; ++k) l.append(one(k));
  return l;
}

// Python values into a scalar's bytes (exact for float32 values given as Python floats)
std::vector<unsigned char> scalar_bytes(const ScalarInfo& s, nb::handle v) {
  std::vector<unsigned char> out(dtype_size(s.dtype) * size_t(s.count));
  std::vector<double> vals;
  try {
    if (s.count == 1 && !nb::isinstance<nb::list>(v) && !nb::isinstance<nb::tuple>(v)) vals.push_back(nb::cast<double>(v));
    else vals = nb::cast<std::vector<double>>(v);
  } catch (const nb::cast_error&) {
    throw nb::value_error((s.name + " must be " + (s.count == 1 ? "a number" : std::to_string(s.count) + " numbers")).c_str());
  }
  if (int(vals.size()) != s.count)
    throw nb::value_error((s.name + " must be " + std::to_string(s.count) + " numbers").c_str());
  for (int k = 0; k < s.count; ++k) {
    unsigned char* p = out.data() + dtype_size(s.dtype) * k;
    switch (s.dtype) {
      case DType::F32: { float x = float(vals[k]); std::memcpy(p, &x, 4); break; }
      case DType::F64: { double x = vals[k]; std::memcpy(p, &x, 8); break; }
      case DType::I32: { int x = int(vals[k]); std::memcpy(p, &x, 4); break; }
      case DType::I64: { long long x = (long long)vals[k]; std::memcpy(p, &x, 8); break; }
    }
  }
  return out;
}

const FieldInfo& field_info(Sim& s, const std::string& name) {
  for (const FieldInfo& f : s.fields())
    if (f.name == name) return f;
  std::string known;
  for (const FieldInfo& f : s.fields()) known += (known.empty() ? "" : ", ") + f.name;
  throw nb::key_error(("unknown field '" + name + "' (fields: " + known + ")").c_str());
}

// a host array owning its bytes
nb::ndarray<nb::numpy> owned(std::vector<unsigned char> bytes, const FieldInfo& f, long long count) {
  auto* buf = new std::vector<unsigned char>(std::move(bytes));
  nb::capsule owner(buf, [](void* p) noexcept { delete static_cast<std::vector<unsigned char>*>(p); });
  size_t shape[2] = {size_t(count), size_t(f.components)};
  return nb::ndarray<nb::numpy>(buf->data(), f.components > 1 ? 2 : 1, shape, owner, nullptr, dl(f.dtype));
}

// Python signals (Ctrl-C) are looked at every 50 ms while stepping; a raised one stops
// the stepping after a whole step and is re-raised once the GIL is back
struct SignalCheck {
  using clock = std::chrono::steady_clock;
  clock::time_point last = clock::now();
  bool raised = false;
  bool operator()() {
    auto now = clock::now();
    if (now - last < std::chrono::milliseconds(50)) return false;
    last = now;
    nb::gil_scoped_acquire acquire;
    if (PyErr_CheckSignals() != 0) raised = true;
    return raised;
  }
};

struct PySim {
  std::unique_ptr<Sim> sim;
};

SimRequest request(const std::string& kind, const std::string& backend, const std::string& index, int device,
                   const ParamSource* params, const ArraySource* arrays) {
  SimRequest r;
  r.kind = kind;
  r.backend = backend;
  r.index = index;
  r.device = device;
  r.params = params;
  r.arrays = arrays;
  return r;
}

}  // namespace

void bind_sim(nb::module_& m) {
  nb::register_exception_translator([](const std::exception_ptr& p, void*) {
    try {
      std::rethrow_exception(p);
    } catch (const cps::Error& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    }
  });

  m.def("kinds", [](bool hidden) {
    nb::dict d;
    for (const KindInfo& k : kinds())
      if (hidden || !k.hidden) d[k.kind.c_str()] = k.indexes;
    return d;
  }, nb::arg("hidden") = false,
     "Scene kinds this core simulates -> their index plug-ins (the first is the default); hidden: also the "
     "kinds built for tests.");
  m.def("bytes_needed", [](const std::string& kind, const std::string& index, nb::dict params) {
    DictParams p(params);
    return bytes_needed(request(kind, "cpu", index, 0, &p, nullptr));
  }, nb::arg("kind"), nb::arg("index"), nb::arg("params"), "Bytes a simulation with these parameters allocates.");
  m.def("bytes_available", [](const std::string& backend, int device) { return bytes_available(backend, device); },
        nb::arg("backend"), nb::arg("device") = 0,
        "Bytes the backend can allocate now (host MemAvailable, or the GPU's free memory).");

  nb::class_<PySim>(m, "Simulation", "A simulation of any scene kind on one backend (serial, cpu or cuda).")
      .def("__init__",
           [](PySim* self, const std::string& kind, const std::string& backend, const std::string& index,
              nb::dict params, nb::dict arrays, int device) {
             DictParams p(params);
             DictArrays a(arrays);
             new (self) PySim();
             self->sim = make_sim(request(kind, backend, index, device, &p, &a));
           },
           nb::arg("kind"), nb::arg("backend"), nb::arg("index"), nb::arg("params"), nb::arg("arrays"),
           nb::arg("device") = 0)
      .def_prop_ro("kind", [](PySim& s) { return std::string(s.sim->kind()); })
      .def_prop_ro("backend", [](PySim& s) { return std::string(s.sim->backend()); })
      .def_prop_ro("index", [](PySim& s) { return std::string(s.sim->index()); })
      .def_prop_ro("on_device", [](PySim& s) { return s.sim->on_device(); })
      .def_prop_ro("device", [](PySim& s) { return s.sim->device(); })
      .def_prop_ro("n_particles", [](PySim& s) { return s.sim->particles(); })
      .def_prop_ro("n_scenes", [](PySim& s) { return s.sim->scenes(); })
      .def("step", [](PySim& s, long long n) {
             SignalCheck check;
             long long taken = 0;
             {
               nb::gil_scoped_release r;
               taken = s.sim->step(n, [&check] { return check(); });
             }
             if (check.raised) throw nb::python_error();
             return taken;
           }, nb::arg("n") = 1,
           "Advance up to n steps; returns the steps taken (none once the end time is reached or the "
           "run went unsound). A Python signal (Ctrl-C) stops it after a whole step and is raised.")
      .def("evaluate", [](PySim& s) { s.sim->evaluate(); },
           "Compute the pair stages and reductions for the current state without advancing.")
      .def("set_end_time", [](PySim& s, double t) { s.sim->set_end_time(t); }, nb::arg("t"))
      .def("scalars", [](PySim& s, int scene) {
             const unsigned char* rec = s.sim->scene_record(scene);
             nb::dict d;
             for (const ScalarInfo& x : s.sim->scalars()) d[x.name.c_str()] = scalar_value(x, rec);
             for (const auto& [k, v] : s.sim->derived(scene)) d[k.c_str()] = v;
             return d;
           }, nb::arg("scene") = 0,
           "The scalars of a scene's record as of the last step, and the values the kind derives.")
      .def("scalar_of_scenes", [](PySim& s, const std::string& name) {
             // one scalar of every scene's record: (scenes,) or (scenes, count), the record's dtype
             for (const ScalarInfo& x : s.sim->scalars()) {
               if (x.name != name) continue;
               const int B = s.sim->scenes();
               const size_t item = dtype_size(x.dtype) * size_t(x.count);
               std::vector<unsigned char> bytes(item * size_t(B));
               for (int k = 0; k < B; ++k) std::memcpy(bytes.data() + item * k, s.sim->scene_record(k) + x.offset, item);
               FieldInfo f{x.name, "scene", x.dtype, x.count, false, false};
               return owned(std::move(bytes), f, B);
             }
             throw nb::key_error(("unknown scalar '" + name + "'").c_str());
           }, nb::arg("name"), "One scalar of every scene (a host array: one row per scene).")
      .def("set_control_of_scenes", [](PySim& s, const std::string& name,
                                       nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu> values) {
             // one control input for every scene at once: values (scenes, count)
             for (const ScalarInfo& x : s.sim->controls()) {
               if (x.name != name) continue;
               const int B = s.sim->scenes();
               if (x.dtype != DType::F32) throw nb::value_error((name + ": only float controls are set by array").c_str());
               if (int(values.shape(0)) != B || int(values.shape(1)) != x.count)
                 throw nb::value_error((name + " must be a (" + std::to_string(B) + ", " + std::to_string(x.count) +
                                        ") array of numbers").c_str());
               for (int k = 0; k < B; ++k) {
                 std::vector<float> row(size_t(x.count));
                 for (int c = 0; c < x.count; ++c) {
                   double v = values(k, c);
                   if (!std::isfinite(v))
                     throw nb::value_error((name + "[" + std::to_string(k) + "] must be finite").c_str());
                   row[c] = float(v);
                 }
                 s.sim->set_control(name, row.data(), k);
               }
               return;
             }
             throw nb::key_error(("unknown control '" + name + "'").c_str());
           }, nb::arg("name"), nb::arg("values"),
           "Set one control input of every scene: values (scenes, count), float64; no rebuild.")
      .def("set_controls", [](PySim& s, nb::ndarray<const float, nb::ndim<2>, nb::c_contig, nb::device::cpu> values) {
             // every control of every scene from one (scenes, columns) float32 array, in the
             // control table's order; staged, uploaded once by the next step
             if (int(values.shape(0)) != s.sim->scenes())
               throw nb::value_error(("controls must have one row per scene (" + std::to_string(s.sim->scenes()) +
                                      "), got " + std::to_string(values.shape(0))).c_str());
             s.sim->set_controls(values.data(), int(values.shape(1)));
           }, nb::arg("values"),
           "Set every control of every scene: a (scenes, columns) float32 array in controls() order; no rebuild.")
      .def("set_end_times", [](PySim& s, nb::ndarray<const double, nb::ndim<1>, nb::c_contig, nb::device::cpu> t,
                               bool relative) {
             if (int(t.shape(0)) != s.sim->scenes())
               throw nb::value_error(("end times must be one per scene (" + std::to_string(s.sim->scenes()) +
                                      "), got " + std::to_string(t.shape(0))).c_str());
             s.sim->set_end_times(t.data(), relative);
           }, nb::arg("t"), nb::arg("relative") = false,
           "Set each scene's end time (relative: its time plus t[scene]).")
      .def("cache_scenes", [](PySim& s) { s.sim->cache_scenes(); },
           "Keep every scene's state (fluid slots and record, the clock restarted) for restore_scenes.")
      .def("restore_scenes", [](PySim& s, nb::ndarray<const int, nb::ndim<1>, nb::c_contig, nb::device::cpu> scenes,
                                nb::ndarray<const float, nb::ndim<2>, nb::c_contig, nb::device::cpu> turn,
                                nb::ndarray<const float, nb::ndim<2>, nb::c_contig, nb::device::cpu> sym) {
             const size_t k = scenes.shape(0);
             if (turn.shape(0) != k || turn.shape(1) != 4 || sym.shape(0) != k || sym.shape(1) != 4)
               throw nb::value_error("restore_scenes: turn and sym must be (k, 4) arrays, one row per scene");
             nb::gil_scoped_release r;
             s.sim->restore_scenes(scenes.data(), int(k), turn.data(), sym.data());
           }, nb::arg("scenes"), nb::arg("turn"), nb::arg("sym"),
           "Restore distinct scenes from the cache, each turned by a quaternion and its die by another.")
      .def("observe", [](nb::handle self, bool copy) {
             PySim& s = nb::cast<PySim&>(self);
             const int B = s.sim->scenes();
             nb::dict d;
             for (const SceneArray& a : s.sim->observe()) {
               size_t shape[2] = {size_t(B), size_t(a.cols)};
               const int ndim = a.cols > 1 ? 2 : 1;
               if (copy) {  // host copies (NumPy arrays of their own)
                 std::vector<unsigned char> bytes(dtype_size(a.dtype) * size_t(a.cols) * size_t(B));
                 s.sim->copy_to_host(bytes.data(), a.data, bytes.size());
                 FieldInfo f{a.name, "scene", a.dtype, a.cols, false, false};
                 d[a.name.c_str()] = owned(std::move(bytes), f, B);
                 continue;
               }
               // host memory: NumPy arrays; device memory: arrays exposing __dlpack__ (no copies)
               if (!s.sim->on_device())
                 d[a.name.c_str()] = nb::cast(nb::ndarray<nb::numpy>(a.data, ndim, shape, self, nullptr, dl(a.dtype)));
               else
                 d[a.name.c_str()] = nb::cast(nb::ndarray<nb::array_api>(a.data, ndim, shape, self, nullptr, dl(a.dtype),
                                                                         nb::device::cuda::value, s.sim->device()));
             }
             return d;
           }, nb::arg("copy") = false,
           "Per-scene observations as zero-copy arrays (NumPy on the CPU, DLPack on CUDA; overwritten by the next "
           "call), or host copies (copy=True).")
      .def("set_scalar", [](PySim& s, const std::string& name, nb::handle value, int scene) {
             for (const ScalarInfo& x : s.sim->scalars())
               if (x.name == name) {
                 auto b = scalar_bytes(x, value);
                 s.sim->set_scalar(name, b.data(), scene);
                 return;
               }
             throw nb::key_error(("unknown scalar '" + name + "'").c_str());
           }, nb::arg("name"), nb::arg("value"), nb::arg("scene") = 0)
      .def("controls", [](PySim& s) {
             nb::dict d;
             for (const ScalarInfo& x : s.sim->controls()) d[x.name.c_str()] = x.count;
             return d;
           }, "Control inputs -> number of values.")
      .def("set_control", [](PySim& s, nb::dict values, int scene) {
             for (auto [k, v] : values) {
               std::string name = nb::cast<std::string>(k);
               bool found = false;
               for (const ScalarInfo& x : s.sim->controls())
                 if (x.name == name) {
                   auto b = scalar_bytes(x, v);
                   s.sim->set_control(name, b.data(), scene);
                   found = true;
                 }
               if (!found) throw nb::key_error(("unknown control '" + name + "'").c_str());
             }
           }, nb::arg("values"), nb::arg("scene") = -1,
           "Set control inputs (name -> values) of a scene (-1: every scene) for the next steps; no rebuild.")
      .def("fields", [](PySim& s) {
             nb::list l;
             for (const FieldInfo& f : s.sim->fields()) {
               nb::dict d;
               d["name"] = f.name;
               d["group"] = f.group;
               d["dtype"] = std::string(dtype_kind(f.dtype) == 'f' ? "<f" : "<i") + std::to_string(dtype_size(f.dtype));
               d["components"] = f.components;
               d["checkpointed"] = f.checkpointed;
               d["settable"] = f.settable;
               d["recorded"] = f.recorded;
               l.append(d);
             }
             return l;
           }, "The kind's particle fields.")
      .def("download", [](PySim& s, const std::string& name) {
             const FieldInfo& f = field_info(*s.sim, name);
             auto [ptr, count] = s.sim->view(name);
             (void)ptr;
             std::vector<unsigned char> bytes(size_t(count) * size_t(f.components) * dtype_size(f.dtype));
             if (count > 0) s.sim->download(name, bytes.data());
             return owned(std::move(bytes), f, count);
           }, nb::arg("name"), "A host (NumPy) copy of a field.")
      .def("download_many", [](PySim& s, const std::vector<std::string>& names) {
             std::vector<std::vector<unsigned char>> bytes(names.size());
             std::vector<void*> dst(names.size());
             std::vector<long long> counts(names.size());
             for (size_t k = 0; k < names.size(); ++k) {
               const FieldInfo& f = field_info(*s.sim, names[k]);
               counts[k] = s.sim->view(names[k]).second;
               bytes[k].resize(std::max<size_t>(1, size_t(counts[k]) * size_t(f.components) * dtype_size(f.dtype)));
               dst[k] = bytes[k].data();
             }
             {
               nb::gil_scoped_release release;
               s.sim->download_many(names, dst);
             }
             nb::dict d;
             for (size_t k = 0; k < names.size(); ++k) {
               const FieldInfo& f = field_info(*s.sim, names[k]);
               bytes[k].resize(size_t(counts[k]) * size_t(f.components) * dtype_size(f.dtype));
               d[names[k].c_str()] = owned(std::move(bytes[k]), f, counts[k]);
             }
             return d;
           }, nb::arg("names"), "Host (NumPy) copies of several fields, in one transfer (a frame).")
      .def("view", [](nb::handle self, const std::string& name) {
             PySim& s = nb::cast<PySim&>(self);
             const FieldInfo& f = field_info(*s.sim, name);
             auto [ptr, count] = s.sim->view(name);
             size_t shape[2] = {size_t(count), size_t(f.components)};
             int ndim = f.components > 1 ? 2 : 1;
             // host memory: a NumPy array; device memory: an array exposing __dlpack__
             if (!s.sim->on_device())
               return nb::cast(nb::ndarray<nb::numpy>(ptr, ndim, shape, self, nullptr, dl(f.dtype)));
             return nb::cast(nb::ndarray<nb::array_api>(ptr, ndim, shape, self, nullptr, dl(f.dtype),
                                                        nb::device::cuda::value, s.sim->device()));
           }, nb::arg("name"),
           "A zero-copy view of a field (host memory, or device memory through DLPack); valid until the next step.")
      .def("upload", [](PySim& s, const std::string& name, nb::ndarray<nb::ro, nb::c_contig, nb::device::cpu> a) {
             const FieldInfo& f = field_info(*s.sim, name);
             size_t item = size_t(f.components) * dtype_size(f.dtype);
             if (a.nbytes() % item != 0) throw nb::value_error(("upload " + name + ": wrong item size").c_str());
             s.sim->upload(name, a.data(), (long long)(a.nbytes() / item));
           }, nb::arg("name"), nb::arg("values"), "Replace a field's values (host array of the field's dtype).")
      .def("checkpoint", [](PySim& s) {
             if (s.sim->scenes() != 1) throw nb::value_error("checkpoints of a batch of scenes are not supported yet");
             Snapshot snap = s.sim->checkpoint();
             nb::dict d;
             for (auto& [name, bytes] : snap.fields) {
               const FieldInfo& f = field_info(*s.sim, name);
               long long count = (long long)(bytes.size() / (size_t(f.components) * dtype_size(f.dtype)));
               d[name.c_str()] = owned(std::move(bytes), f, count);
             }
             for (const ScalarInfo& x : s.sim->scalars())
               if (x.checkpointed) d[x.name.c_str()] = scalar_value(x, snap.scene.data());
             for (const ScalarInfo& x : s.sim->controls())
               d[("control_" + x.name).c_str()] = scalar_value(x, snap.control.data());
             return d;
           }, "The state the next step reads: checkpointed fields (current order) and scalars; the next step relists.")
      .def("restore", [](PySim& s, nb::dict d) {
             if (s.sim->scenes() != 1) throw nb::value_error("checkpoints of a batch of scenes are not supported yet");
             Snapshot snap;
             // start from the current record (keeps what a checkpoint does not hold: the end time)
             const unsigned char* rec = s.sim->scene_record(0);
             snap.scene.assign(rec, rec + s.sim->record_size());
             for (const ScalarInfo& x : s.sim->scalars()) {
               if (!x.checkpointed) continue;
               if (!d.contains(x.name.c_str())) throw nb::value_error(("checkpoint: missing '" + x.name + "'").c_str());
               auto b = scalar_bytes(x, d[x.name.c_str()]);
               std::memcpy(snap.scene.data() + x.offset, b.data(), b.size());
             }
             // the control: the checkpoint's, or none
             snap.control.assign(s.sim->control_size(), 0);
             for (const ScalarInfo& x : s.sim->controls()) {
               std::string key = "control_" + x.name;
               if (!d.contains(key.c_str())) continue;
               auto b = scalar_bytes(x, d[key.c_str()]);
               std::memcpy(snap.control.data() + x.offset, b.data(), b.size());
             }
             for (const FieldInfo& f : s.sim->fields()) {
               if (!f.checkpointed) continue;
               if (!d.contains(f.name.c_str())) throw nb::value_error(("checkpoint: missing '" + f.name + "'").c_str());
               auto a = nb::cast<nb::ndarray<nb::ro, nb::c_contig, nb::device::cpu>>(d[f.name.c_str()]);
               if (a.dtype() != dl(f.dtype))
                 throw nb::value_error(("checkpoint: '" + f.name + "' has the wrong dtype").c_str());
               const unsigned char* p = static_cast<const unsigned char*>(a.data());
               snap.fields.emplace_back(f.name, std::vector<unsigned char>(p, p + a.nbytes()));
             }
             s.sim->restore(snap);
           }, nb::arg("state"), "Replace the whole state by a checkpoint's (as checkpoint() returns it).")
      .def("packed_size", [](PySim& s) { return s.sim->packed_size(); },
           "Bytes of one particle's record (pack / unpack).")
      .def("pack", [](PySim& s, long long slot) {
             std::string rec(s.sim->packed_size(), '\0');
             s.sim->pack(slot, rec.data());
             return nb::bytes(rec.data(), rec.size());
           }, nb::arg("slot"),
           "Slot `slot`'s record: every checkpointed fluid field's item, in the field table's order.")
      .def("unpack", [](PySim& s, long long slot, nb::bytes rec) {
             if (rec.size() != s.sim->packed_size())
               throw nb::value_error(("unpack: a record has " + std::to_string(s.sim->packed_size()) + " bytes, got " +
                                      std::to_string(rec.size())).c_str());
             s.sim->unpack(slot, rec.c_str());
           }, nb::arg("slot"), nb::arg("record"), "Write a record (as pack() returns it) into slot `slot`.")
      // one scene split over ranks (scenes/sph/ranks.h; python/corpuscle/_ranks_sph.py drives them)
      .def("set_counts", [](PySim& s, long long fluid, long long wall, long long id_bound) {
             s.sim->set_counts(fluid, wall, id_bound);
           }, nb::arg("fluid"), nb::arg("wall"), nb::arg("id_bound"),
           "A rank's slots: fluid (owned and halo), walls; ids below id_bound. Every field is then unset.")
      .def("slots", [](PySim& s) { return s.sim->slots(); }, "Slots of the state (fluid and walls).")
      .def("step_half", [](PySim& s, int phase, nb::bytes sums, int ranks) {
             const size_t sz = s.sim->step_sums_size();
             long long flags[3] = {0, 0, 0};
             std::string buf;
             bool ok = true;
             if (phase == 0) {
               buf.assign(sz, '\0');
               s.sim->step_half(0, buf.data(), 1, flags);
             } else if (phase == 1) {
               if (ranks < 1 || sums.size() != sz * size_t(ranks))
                 throw nb::value_error("step_half: phase 1 takes one step sums record a rank");
               std::string in(sums.c_str(), sums.size());
               s.sim->step_half(1, in.data(), ranks, flags);
             } else if (phase == 2) {
               ok = s.sim->step_half(2, nullptr, 0, flags);
             } else {
               throw nb::value_error("step_half: phase 0, 1 or 2");
             }
             return nb::make_tuple(nb::bytes(buf.data(), buf.size()), flags[0], flags[1], flags[2], ok);
           }, nb::arg("phase"), nb::arg("sums") = nb::bytes("", 0), nb::arg("ranks") = 1,
           "A step in halves: phase 0 to the reductions, phase 1 with every rank's sums (concatenated in rank "
           "order) the finalize and the integration, phase 2 grows what overflowed in phase 0. Returns (the "
           "rank's sums after phase 0, bad, relist, outside, ok).")
      .def("get_slots", [](PySim& s, const std::string& name,
                           nb::ndarray<const int, nb::ndim<1>, nb::c_contig, nb::device::cpu> slots) {
             const FieldInfo& f = field_info(*s.sim, name);
             const long long count = (long long)slots.shape(0);
             std::vector<unsigned char> bytes(size_t(count) * size_t(f.components) * dtype_size(f.dtype));
             s.sim->get_slots(name, slots.data(), count, bytes.data());
             return owned(std::move(bytes), f, count);
           }, nb::arg("name"), nb::arg("slots"), "A stored field's items at the slots (every slot: fluid, then walls).")
      .def("set_slots", [](PySim& s, const std::string& name,
                           nb::ndarray<const int, nb::ndim<1>, nb::c_contig, nb::device::cpu> slots,
                           nb::ndarray<nb::ro, nb::c_contig, nb::device::cpu> values) {
             const FieldInfo& f = field_info(*s.sim, name);
             const long long count = (long long)slots.shape(0);
             if (values.dtype() != dl(f.dtype) || values.nbytes() != size_t(count) * size_t(f.components) * dtype_size(f.dtype))
               throw nb::value_error(("set_slots " + name + ": one item of the field's dtype a slot").c_str());
             s.sim->set_slots(name, slots.data(), count, values.data());
           }, nb::arg("name"), nb::arg("slots"), nb::arg("values"),
           "Write a stored field's items at the slots (no relisting follows).")
      .def("bench", [](PySim& s, long long n) {
             SignalCheck check;
             double seconds = 0.0;
             {
               nb::gil_scoped_release r;
               seconds = s.sim->bench(n, [&check] { return check(); });
             }
             if (check.raised) throw nb::python_error();
             return seconds;
           }, nb::arg("steps"),
           "Seconds for `steps` steps (CUDA events / monotonic clock after a synchronise). A Python "
           "signal (Ctrl-C) stops it after a whole step and is raised.")
      .def("profile", [](PySim& s, long long n) {
             SignalCheck check;
             std::vector<std::pair<std::string, double>> out;
             {
               nb::gil_scoped_release r;
               out = s.sim->profile(n, [&check] { return check(); });
             }
             if (check.raised) throw nb::python_error();
             return out;
           }, nb::arg("steps"), "Per-stage milliseconds per step over `steps` steps (Ctrl-C: as bench).");
}
