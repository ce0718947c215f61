// `fields-test`: a kind built for tests (hidden: _core.kinds(hidden=True) lists it) and the
// worked example of fields that own their storage (sim/field_store.h). Free particles in a
// 2-D box: each step keys and sorts them on the engine's cell grid, gathers every moving field
// by the sort's permutation (Fields::gather), and moves them ballistically (a body
// acceleration from the control), reflecting at the walls.
//
// Its `distance` field (the path length each particle has travelled) is what adding a field
// takes: the table line (recorded, moving with the particle, checkpointed) and the line of
// physics that writes it (MoveStage). tests/sim/test_field_store.py finds it in frames,
// checkpoints and Simulation.field, and packs and unpacks particles.
#pragma once
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "corpuscle/core/error.h"
#include "corpuscle/sim/field_store.h"
#include "corpuscle/sim/kind_list.h"
#include "corpuscle/sim/params.h"
#include "corpuscle/sim/sim_impl.h"
#include "corpuscle/spatial/cell_grid.h"

namespace cps::ftest {

constexpr int D = 2;

// X(name, C type, components, group, checkpointed, settable, recorded, moves)
#define CPS_FTEST_FIELDS(X)                                   \
  X(position, float, 2, "fluid", true, true, true, true)      \
  X(velocity, float, 2, "fluid", true, true, false, true)     \
  X(id, int, 1, "fluid", true, false, true, true)             \
  X(distance, float, 1, "fluid", true, false, true, true)     \
  X(speed, float, 1, "fluid", false, false, false, false)

// the device pointers the stages take
struct Fields {
  CPS_FIELD_PTRS(CPS_FTEST_FIELDS)
};

struct Model {
  int n;
  Vec<D> lo, hi;
  float dt;
  float cell;  // the cell grid's cell size
};

struct Control {
  float acc[D];
};

struct Scene {
  Clock clock;
  float step_dt;  // the dt this step moves by (0: not taken)
};

#define CPS_FTEST_SCALARS(X) CPS_CLOCK_SCALARS(X)
#define CPS_FTEST_CONTROLS(X) X(acceleration, float, D, acc)

struct GridIndex {
  static constexpr const char* name = index_name::grid;
};

// the clock: the step's dt (shortened to land on the end time), or none
struct FinalizeStage {
  const Model* m;
  Scene* g;
  CPS_HD void operator()(int) const {
    g->step_dt = 0.0f;
    if (g->clock.bad != 0 || clock_at_end(g->clock)) return;
    bool last = false;
    const float dt = clip_to_end(g->clock, m->dt, last);
    g->step_dt = dt;
    advance_clock(g->clock, dt, last);
  }
};

template <class Ptrs>
struct ReorderStage {
  const int* order;
  Ptrs a;
  CPS_HD void operator()(int j) const { a.gather(j, order[j]); }
};

// ballistic motion with the control's acceleration, reflected at the walls
template <class Ptrs>
struct MoveStage {
  const Model* m;
  const Scene* g;
  const Control* u;
  Ptrs a;
  bool integrate;
  CPS_HD void operator()(int i) const {
    const float dt = integrate ? g->step_dt : 0.0f;
    Vec<D> x = a.position[i], v = a.velocity[i];
    for (int c = 0; c < D; ++c) {
      v[c] += u->acc[c] * dt;
      x[c] += v[c] * dt;
      if (x[c] < m->lo[c]) {
        x[c] = 2.0f * m->lo[c] - x[c];
        v[c] = -v[c];
      } else if (x[c] > m->hi[c]) {
        x[c] = 2.0f * m->hi[c] - x[c];
        v[c] = -v[c];
      }
    }
    const float s = norm(v);
    a.position[i] = x;
    a.velocity[i] = v;
    a.speed[i] = s;
    a.distance[i] += s * dt;  // the distance field's line of physics
  }
};

template <class Exec, class Index>
class Pipeline {
 public:
  using SceneRecord = Scene;
  using ControlRecord = Control;
  static constexpr const char* kind = "fields-test";
  static constexpr const char* index_name = Index::name;
  static constexpr int kNumStages = 2;
  static const char* stage_name(int s) {
    static const char* const names[] = {"sort+reorder", "move"};
    return names[s];
  }
  CPS_KIND_STORED_TABLES(CPS_FTEST_FIELDS, CPS_NO_FIELDS, CPS_FTEST_SCALARS, CPS_FTEST_CONTROLS, Scene, Control, Fields)

  static CellGridSpec<D> grid_spec(const Model& m) { return make_cell_grid<D>(m.lo, m.hi, m.cell); }
  static double bytes_needed(const Model& m) {
    return field_bytes(double(m.n)) + double(m.n) * 4.0 * sizeof(uint64_t) +
           2.0 * double(grid_spec(m).table_size()) * sizeof(uint32_t) + sizeof(Model);
  }

  Pipeline(Exec& ex, const Model& m, Scene* g, const Control* u) : ex_(ex), m_(m), g_(g), u_(u), grid_(grid_spec(m)) {
    if (m.n <= 0) throw Error(std::string(kind) + ": no particles");
    fields_.resize(size_t(m.n));
    model_.resize(1);
    ex_.to_device(model_.data(), &m_, sizeof(Model));
  }

  static Scene initial_record(const Model&) {
    Scene s{};
    s.clock = start_clock();
    return s;
  }
  static void restored(Scene& r) { r.step_dt = 0.0f; }
  long long particles() const { return m_.n; }
  int scenes() const { return 1; }
  template <class R>
  bool recover(std::vector<R>&, double) { return false; }
  const Model& model() const { return m_; }
  int graph_slot() const { return parity_; }
  void prepare() {}
  void advance(bool) { parity_ ^= 1; }
  void invalidate(bool) {}

  void enqueue(bool integrate) {
    const int cur = parity_, nxt = parity_ ^ 1;
    grid_.sort(ex_, fields_.position.cur(cur), nullptr, m_.n);
    ex_.for_each(m_.n, ReorderStage<Fields>{grid_.order(), ptrs(cur)});
    ex_.mark(0);
    if (integrate) ex_.single(FinalizeStage{model_.data(), g_});
    ex_.for_each(m_.n, MoveStage<Fields>{model_.data(), g_, u_, ptrs(nxt), integrate});
    ex_.mark(1);
  }

  std::pair<void*, long long> view(const std::string& name, const Scene&) {
    std::pair<void*, long long> out;
    if (!field_view(name, parity_, m_.n, out)) throw Error(std::string(kind) + ": no field '" + name + "'");
    return out;
  }

  // positions restart the ids at 0..n-1 and the distances at 0
  void upload(const std::string& name, const void* src, long long count) {
    if (count != m_.n) throw Error(std::string(kind) + ": " + name + " needs " + std::to_string(m_.n) + " items");
    if (!field_upload(ex_, name, src, count, parity_)) throw Error(std::string(kind) + ": field '" + name + "' cannot be set");
    if (name == "position") {
      std::vector<int> ids(size_t(m_.n));
      for (int i = 0; i < m_.n; ++i) ids[size_t(i)] = i;
      std::vector<float> zero(size_t(m_.n), 0.0f);
      field_upload(ex_, "id", ids.data(), count, parity_);
      field_upload(ex_, "distance", zero.data(), count, parity_);
    }
  }

  std::vector<std::pair<std::string, double>> derived(const Scene&) const { return {}; }

 private:
  template <class T> using Buf = typename Exec::template Buffer<T>;
  Fields ptrs(int parity) {
    Fields p;
    fields_.fill(p, parity);
    return p;
  }
  Exec& ex_;
  Model m_;
  Scene* g_;
  const Control* u_;
  CellGrid<D, Exec> grid_;
  Buf<Model> model_;
  int parity_ = 0;
};

inline Model build_model(const ParamSource& p) {
  Model m{};
  m.n = int(p.integer("n"));
  const auto lo = p.numbers("lo"), hi = p.numbers("hi");
  if (lo.size() != D || hi.size() != D) throw Error("fields-test: lo and hi need 2 numbers");
  for (int c = 0; c < D; ++c) {
    m.lo[c] = float(lo[c]);
    m.hi[c] = float(hi[c]);
  }
  m.dt = p.f("dt");
  m.cell = p.f("cell");
  if (m.n <= 0 || !(m.dt > 0.0f) || !(m.cell > 0.0f)) throw Error("fields-test: n, dt and cell must be positive");
  return m;
}

using Indexes = IndexList<GridIndex>;

struct Entry {
  static constexpr const char* name = "fields-test";
  static constexpr bool hidden = true;
  using Indexes = ftest::Indexes;
  template <class Exec>
  static std::unique_ptr<Sim> make(Exec&& ex, const SimRequest& r) {
    return Indexes::with(name, r.index, [&](auto index) -> std::unique_ptr<Sim> {
      using P = Pipeline<std::decay_t<Exec>, decltype(index)>;
      const Model m = build_model(*r.params);
      auto sim = std::make_unique<SimImpl<std::decay_t<Exec>, P>>(std::move(ex), m, std::vector<Scene>{P::initial_record(m)},
                                                                  r.device);
      for (const char* field : {"position", "velocity"}) {
        if (!r.arrays || !r.arrays->has(field)) throw Error(std::string(name) + ": no initial " + field + " array");
        ArrayView a = r.arrays->get(field);
        if (a.components != D || a.count != m.n) throw Error(std::string(name) + ": the initial " + field + " array must be (n, 2)");
        sim->upload(field, a.data, a.count);
      }
      return sim;
    });
  }
  template <class Exec>
  static double bytes(const SimRequest& r) {
    const Model m = build_model(*r.params);
    return Pipeline<Exec, GridIndex>::bytes_needed(m);
  }
};

}  // namespace cps::ftest
