// The wind tunnel pipeline: its buffers, the order of its stages for one step, the views.
// SimImpl (sim/sim_impl.h) owns the Exec, the per-scene record and the control.
//
// A step: the D-dimensional cell grid keys the current positions and sorts them (CellGrid<D, Exec>),
// the particle arrays are gathered into cell order in the other buffers, the cell ranges
// marked; then the contact forces by gather with the reductions and the per-scene finalize
// (dt, block averages, clock) fused into the same pass (the LBVH's walks: reduced after), and
// the integration (with recycling and the inflow conveyor) in place. The sorted
// buffers are current afterwards. Index plug-ins: the grid, the LBVH and all pairs. D = 2 is
// `wind-tunnel`, D = 3 `wind-tunnel-3d` (model.h).
#pragma once
#include <cmath>
#include <string>
#include <type_traits>
#include <vector>

#include "corpuscle/core/error.h"
#include "corpuscle/scenes/wind_tunnel/stages.h"
#include "corpuscle/scenes/wind_tunnel/tables.h"

namespace cps::wt {

struct GridIndex {
  static constexpr const char* name = "grid";
  static constexpr bool kGrid = true;
};
// every particle against every other (O(N^2)): the reference the grid is tested against
struct AllPairsIndex {
  static constexpr const char* name = "allpairs";
  static constexpr bool kGrid = false;
};
// the seed's Karras LBVH over Morton codes (spatial/lbvh.h), gather form
struct LbvhIndex {
  static constexpr const char* name = "lbvh";
  static constexpr bool kGrid = false;
};

// the kind's name of each dimension
template <int D>
constexpr const char* kind_name() {
  return D == 2 ? "wind-tunnel" : "wind-tunnel-3d";
}

template <class Exec, class Index, int Dim = 2>
class Pipeline {
 public:
  static constexpr int D = Dim;
  template <class T> using Buf = typename Exec::template Buffer<T>;
  using Model = wt::Model<D>;
  using Scene = wt::Scene<D>;
  using StepSums = wt::StepSums<D>;
  using Arrays = wt::Arrays<D>;
  using SceneRecord = Scene;
  using ControlRecord = Control;
  static constexpr const char* kind = kind_name<D>();
  static constexpr const char* index_name = Index::name;
  static constexpr int kNumStages = 6;
  static const char* stage_name(int s) {
    static const char* const names[] = {"keys+sort", "reorder", "build (cells / tree)", "contacts",
                                        "reduce+finalize", "integrate"};
    return names[s];
  }

  // cells of at least one contact diameter (larger cells: fewer of them, more candidates each)
  static CellGridSpec<D> grid_spec(const Model& m) {
    return make_cell_grid<D>(m.lo, m.hi, std::fmax(2.0f * m.radius, m.cell));
  }

  static double bytes_needed(const Model& m) {
    const double n = m.n;
    const double per = 2 * (2 * sizeof(Vec<D>) + 2 * sizeof(int)) + sizeof(Vec<D>) + 2 * sizeof(float) + sizeof(int) +
                       sizeof(StepSums) + 4 * sizeof(uint64_t) + 3 * sizeof(int);
    const double cells = 2.0 * double(grid_spec(m).table_size()) * sizeof(uint32_t);
    return n * per + cells + sizeof(Model);
  }

  CPS_KIND_TABLES(CPS_WT_FIELDS, CPS_WT_SCALARS, CPS_WT_CONTROLS, Scene, Control)

  Pipeline(Exec& ex, const Model& m, Scene* g, const Control* u)
      : ex_(ex), m_(m), g_(g), u_(u), grid_(grid_spec(m)), tree_(m.lo, m.hi, 2.0f * m.radius * (1.0f + 1e-6f)) {
    const int n = m.n;
    if (n <= 0) throw Error(std::string(kind) + ": no particles");
    if (m_.n_edges > 0) {
      // the airfoil's edge grid, built once and copied to the backend with the model
      const PolygonGridTables t = build_polygon_grid(m_.airfoil(), m_.radius);
      foil_start_.resize(t.start.size());
      foil_refs_.resize(t.refs.size());
      foil_flag_.resize(t.flag.size());
      ex_.to_device(foil_start_.data(), t.start.data(), t.start.size() * sizeof(int));
      ex_.to_device(foil_refs_.data(), t.refs.data(), t.refs.size() * sizeof(int));
      ex_.to_device(foil_flag_.data(), t.flag.data(), t.flag.size());
      m_.foil_cells = t.view(foil_start_.data(), foil_refs_.data(), foil_flag_.data());
    }
    model_.resize(1);
    ex_.to_device(model_.data(), &m_, sizeof(Model));
    for (int p = 0; p < 2; ++p) {
      pos_[p].resize(n);
      vel_[p].resize(n);
      id_[p].resize(n);
      scat_[p].resize(n);
    }
    force_.resize(n);
    if (std::is_same_v<Index, LbvhIndex>) tree_.resize(n);
    pressure_.resize(n);
    ndens_.resize(n);
    contacts_.resize(n);
    items_.resize(n);
    leaving_.resize(n);
  }

  static Scene initial_record(const Model& m) {
    Scene s{};
    s.clock = start_clock();
    s.sums = s.pending = StepSums::identity();
    s.block_len = m.block_time;
    for (int r = 0; r < kMaxRows; ++r) s.conv_claim[r] = kNoClaim;
    return s;
  }
  static void restored(Scene& r) {
    r.pending = r.sums;
    r.step_dt = 0.0f;
    r.n_leaving = 0;
    for (int k = 0; k < kMaxRows; ++k) r.conv_claim[k] = kNoClaim;  // no claim between steps
  }

  long long particles() const { return m_.n; }
  int scenes() const { return 1; }  // one scene per state (a batch of one)
  // nothing of this kind grows on a fault: an unsound step stops the run
  template <class R>
  bool recover(std::vector<R>&, double) { return false; }
  const Model& model() const { return m_; }
  int graph_slot() const { return parity_; }

  void prepare() {}
  void advance(bool) { parity_ ^= 1; }
  void invalidate(bool) {}

  void enqueue(bool integrate) {
    const int n = m_.n;
    const int cur = parity_, nxt = parity_ ^ 1;
    Model* md = model_.data();
    Scene* g = g_;
    // 1. key and sort the current positions, gather the arrays into cell order, mark cells
    // (a collisionless gas needs no index: the arrays are copied as they are)
    // (the all-pairs reference needs no order either)
    constexpr bool kTree = std::is_same_v<Index, LbvhIndex>;
    // stages timed: 0 keys and sort, 1 reorder, 2 build (cell ranges / the tree's nodes and boxes)
    if (m_.collide && kTree) {
      tree_.sort(ex_, pos_[cur].data(), n);
      ex_.mark(0);
      ex_.for_each(n, ReorderStage<D>{tree_.order(), arrays(cur, nxt)});
      ex_.mark(1);
      tree_.build(ex_, pos_[nxt].data());
    } else if (m_.collide && Index::kGrid) {
      grid_.sort(ex_, pos_[cur].data(), nullptr, n);
      ex_.mark(0);
      ex_.for_each(n, ReorderStage<D>{grid_.order(), arrays(cur, nxt)});
      ex_.mark(1);
      grid_.mark(ex_);
    } else {
      ex_.mark(0);
      ex_.for_each(n, ReorderStage<D>{nullptr, arrays(cur, nxt)});
      ex_.mark(1);
    }
    ex_.mark(2);
    Arrays s = arrays(nxt, cur);
    // 2. contacts by gather (or, reflexive, each pair once with atomics, then the rest), and
    // 3. the step's sums with the per-scene update (dt, block averages, clock): fused into the
    // contact pass (Exec::for_each_reduce_then) but for the tree, whose walks need shared memory
    auto contacts = [&](const auto& view) {
      using V = std::decay_t<decltype(view)>;
      // the tree's walks keep their stacks in shared memory on the device (spatial/lbvh.h)
      auto walking = [&](const auto& f) {
        if constexpr (kTree) ex_.for_each_shared(n, f, lbvh_stack_bytes(m_.lbvh_stack));
        else ex_.for_each(n, f);
      };
      if (m_.collide && m_.reflexive) {
        ex_.for_each(n, ZeroContactsStage<D>{s});
        walking(PairStage<D, V>{md, g, s, view});
      }
      const ForceStage<D, V> force{md, g, u_, s, view, grid_.spec()};
      if constexpr (kTree) {
        walking(force);
        ex_.mark(3);
        if (integrate) ex_.reduce_then(s.items, n, &g->pending, SumsOp<D>{}, StepSums::identity(), FinalizeStage<D>{md, g, u_});
        else ex_.reduce(s.items, n, &g->sums, SumsOp<D>{}, StepSums::identity());
      } else {
        // the forces and the step's sums in one pass: the sums items are never stored
        if (integrate)
          ex_.for_each_reduce_then(n, EvalOf<ForceStage<D, V>>{force}, &g->pending, SumsOp<D>{}, StepSums::identity(),
                                   FinalizeStage<D>{md, g, u_});
        else
          ex_.for_each_reduce_then(n, EvalOf<ForceStage<D, V>>{force}, &g->sums, SumsOp<D>{}, StepSums::identity(),
                                   NoFinalize{});
        ex_.mark(3);
      }
      ex_.mark(4);
    };
    if constexpr (Index::kGrid) {
      contacts(grid_.view(s.pos).with_radius(2.0f * m_.radius));  // the contact reach, whatever the cell
    } else if constexpr (kTree) {
      contacts(tree_.view(s.pos, &g->clock.bad, kBadTraversal, m_.lbvh_stack));
    } else {
      const float reach = 2.0f * m_.radius;
      contacts(AllPairsView<D>{s.pos, n, reach * reach * (1.0f + 4e-6f)});
    }
    if (integrate) {
      // 4. integrate in place (the sorted buffers become the current ones)
      ex_.for_each(n, IntegrateStage<D>{md, g, u_, s});
      // the cold beam's leaving particles onto the inflow conveyor's free slots
      // (one launch: the passes are separated by the block's barrier)
      if (m_.conv_rows > 0) ex_.template for_each_tile<kConveyorThreads>(1, ConveyorStage<D>{md, g, u_, s});
      ex_.mark(5);
    }
  }

  std::pair<void*, long long> view(const std::string& name, const Scene&) {
    const int n = m_.n;
    const int cur = parity_;
#define CPS_FIELD_VIEW(fname, T, comps, group, ckpt, settable, storage, count) \
  if (name == #fname) return {static_cast<void*>(storage), (long long)(count)};
    CPS_WT_FIELDS(CPS_FIELD_VIEW)
#undef CPS_FIELD_VIEW
    throw Error(std::string(kind) + ": no field '" + name + "'");
  }

  // positions (ids restart at 0..n-1), velocities, or a checkpoint's ids
  void upload(const std::string& name, const void* src, long long count) {
    const int n = m_.n;
    if (count != n) throw Error(std::string(kind) + ": " + name + " needs " + std::to_string(n) + " items");
    const int cur = parity_;
    if (name == "position") {
      ex_.to_device(pos_[cur].data(), src, n * sizeof(Vec<D>));
      std::vector<int> ids(n);
      for (int i = 0; i < n; ++i) ids[i] = i;
      ex_.to_device(id_[cur].data(), ids.data(), n * sizeof(int));
      std::vector<int> zero(n, 0);
      ex_.to_device(scat_[cur].data(), zero.data(), n * sizeof(int));
    } else if (name == "velocity") {
      ex_.to_device(vel_[cur].data(), src, n * sizeof(Vec<D>));
    } else if (name == "id") {
      ex_.to_device(id_[cur].data(), src, n * sizeof(int));
    } else if (name == "scattered") {
      ex_.to_device(scat_[cur].data(), src, n * sizeof(int));
    } else {
      throw Error(std::string(kind) + ": field '" + name + "' cannot be set");
    }
  }

  // lift and drag per unit span (D = 3: the whole span's over the span; D = 2: as summed)
  std::vector<std::pair<std::string, double>> derived(const Scene& r) const {
    const float me = effective_mass(m_.mass, m_.mass), mw = effective_mass(m_.mass, 0.0f);
    double lift = double(r.sums.force[1]), drag = double(r.sums.force[0]);
    if constexpr (D == 3) {
      const double span = double(m_.hi[2]) - double(m_.lo[2]);
      lift /= span;
      drag /= span;
    }
    return {{"vmax", std::sqrt(double(r.sums.vmax2))},
            {"lift", lift},
            {"drag", drag},
            {"chosen_dt", double(choose_dt(m_, r.sums.vmax2))},
            {"restitution_pp", double(restitution_from_damping(m_.pp, me))},
            {"restitution_wall", double(restitution_from_damping(m_.wall, mw))},
            {"restitution_wing", double(restitution_from_damping(m_.wing, mw))},
            {"contact_time_pp", double(contact_time(m_.pp, me))},
            {"contact_time_wing", double(contact_time(m_.wing, mw))}};
  }

 private:
  Arrays arrays(int cur, int nxt) {
    Arrays a;
    a.pos = pos_[cur].data();
    a.vel = vel_[cur].data();
    a.pos_alt = pos_[nxt].data();
    a.vel_alt = vel_[nxt].data();
    a.id = id_[cur].data();
    a.id_alt = id_[nxt].data();
    a.scattered = scat_[cur].data();
    a.scattered_alt = scat_[nxt].data();
    a.number_density = ndens_.data();
    a.force = force_.data();
    a.pressure = pressure_.data();
    a.contacts = contacts_.data();
    a.items = items_.data();
    a.leaving = leaving_.data();
    return a;
  }

  Exec& ex_;
  Model m_;
  Scene* g_;
  const Control* u_;
  CellGrid<D, Exec> grid_;
  Lbvh<D, Exec> tree_;
  Buf<Model> model_;
  Buf<int> foil_start_, foil_refs_;  // the airfoil's edge grid (polygon_grid.h)
  Buf<unsigned char> foil_flag_;
  Buf<Vec<D>> pos_[2], vel_[2];
  Buf<int> id_[2];
  Buf<int> scat_[2];
  Buf<float> ndens_;
  Buf<Vec<D>> force_;
  Buf<float> pressure_;
  Buf<int> contacts_;
  Buf<StepSums> items_;
  Buf<int> leaving_;  // this step's leaving particles (the inflow conveyor)
  int parity_ = 0;
};

}  // namespace cps::wt
