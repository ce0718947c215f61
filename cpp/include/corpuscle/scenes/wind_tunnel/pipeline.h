// The wind tunnel pipeline: its buffers, the order of its stages for one step, the views.
// SimImpl (sim/sim_impl.h) owns the Exec, the per-scene record and the control.
//
// A step is the DEM module's (dem/step.h) with the tunnel's hooks (stages.h): the index (the
// D-dimensional cell grid, CellGrid<D, Exec>, or the LBVH) keys the current positions and sorts
// them, the particle arrays are gathered into its order in the other buffers (the airfoil flag
// too: ReorderScattered), the cell ranges marked (the tree built); then the contact forces by
// gather, the walls and the airfoil (Boundary), with the reductions and the per-scene finalize
// (dt; block averages and the conveyor's phase: Finalize; clock) fused into the same pass (the
// LBVH's walks: reduced after), and the integration (recycling and keeping out of the airfoil:
// Outflow) in place, then the inflow conveyor. The sorted buffers are current afterwards.
// Index plug-ins: the grid, the LBVH and all pairs. D = 2 is `wind-tunnel`, D = 3
// `wind-tunnel-3d` (model.h).
#pragma once
#include <cmath>
#include <memory>
#include <string>
#include <type_traits>
#include <vector>

#include "corpuscle/core/error.h"
#include "corpuscle/dem/step.h"
#include "corpuscle/scenes/wind_tunnel/stages.h"
#include "corpuscle/scenes/wind_tunnel/tables.h"

namespace cps::wt {

// the index plug-ins: the DEM module's (dem/step.h)
using dem::AllPairsIndex;
using dem::GridIndex;
using dem::LbvhIndex;

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

  // cells of at least one contact diameter (dem::grid_spec)
  static CellGridSpec<D> grid_spec(const Model& m) { return dem::grid_spec<D>(m); }

  static double bytes_needed(const Model& m) {
    const double n = m.n;
    const double per = sizeof(StepSums) + 4 * sizeof(uint64_t) + 3 * sizeof(int);
    const double cells = 2.0 * double(grid_spec(m).table_size()) * sizeof(uint32_t);
    return field_bytes(n) + n * per + cells + sizeof(Model);
  }

  CPS_KIND_STORED_TABLES(CPS_WT_FIELDS, CPS_NO_FIELDS, CPS_WT_SCALARS, CPS_WT_CONTROLS, Scene, Control, Arrays)

  Pipeline(Exec& ex, const Model& m, Scene* g, const Control* u)
      : ex_(ex), m_(m), g_(g), u_(u), grid_(grid_spec(m)), tree_(m.lo, m.hi, dem::tree_reach<D>(m)) {
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
    if constexpr (D == 3) {
      if (m_.n_tris > 0) {
        // the mesh body's triangle tree, built once (dem/mesh_body.h); a query that would
        // overflow its stack makes the run unsound, as the particle tree's
        if (!m_.body_host) throw Error(std::string(kind) + ": the mesh body's triangles were not given");
        body_tree_ = std::make_unique<MeshTree<Exec>>(ex_, m_.body_host, m_.n_tris, m_.body_lo, m_.body_hi);
        m_.body = body_tree_->view(&g_->clock.bad, kBadTraversal);
      }
    }
    m_.body_host = nullptr;
    model_.resize(1);
    ex_.to_device(model_.data(), &m_, sizeof(Model));
    fields_.resize(size_t(n));
    if (std::is_same_v<Index, LbvhIndex>) tree_.resize(n);
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
    // 1. key and sort the current positions, gather the arrays into the index's order (the
    // airfoil flag with them), build the index (the DEM module's; stages timed 0, 1, 2)
    const Arrays a = arrays(cur, nxt);
    dem::sort_and_reorder<Index>(ex_, m_, grid_, tree_, a);
    Arrays s = arrays(nxt, cur);
    // 2. contacts (gather or reflexive), walls and airfoil (the Boundary hook), and 3. the
    // step's sums with the per-scene update (dt, block averages, clock: the Finalize hook)
    // (stages timed 3, 4)
    dem::contacts_and_sums<Index>(ex_, m_, md, g, s, s.items, grid_, tree_, Boundary<D>{md, u_, s.scattered},
                                  Finalize<D>{md, u_}, integrate);
    if (integrate) {
      // 4. integrate in place (the sorted buffers become the current ones), recycling at the
      // outflow and keeping out of the airfoil (the Outflow hook)
      ex_.for_each(n, dem::IntegrateStage<D, Scene, Outflow<D>>{md, g, s, Outflow<D>{md, g, u_, s}});
      // the cold beam's leaving particles onto the inflow conveyor's free slots
      // (one launch: the passes are separated by the block's barrier)
      if (m_.conv_rows > 0) ex_.template for_each_tile<kConveyorThreads>(1, ConveyorStage<D>{md, g, u_, s});
      ex_.mark(5);
    }
  }

  std::pair<void*, long long> view(const std::string& name, const Scene&) {
    std::pair<void*, long long> stored;
    if (field_view(name, parity_, m_.n, stored)) return stored;
    throw Error(std::string(kind) + ": no field '" + name + "'");
  }

  // positions (ids restart at 0..n-1), velocities, or a checkpoint's ids
  void upload(const std::string& name, const void* src, long long count) {
    const int n = m_.n;
    if (count != n) throw Error(std::string(kind) + ": " + name + " needs " + std::to_string(n) + " items");
    const int cur = parity_;
    // settable, or a checkpoint's (id, scattered)
    if (!field_upload(ex_, name, src, n, cur))
      throw Error(std::string(kind) + ": field '" + name + "' cannot be set");
    if (name == "position") {  // a new state: its particles numbered in order, none scattered
      std::vector<int> ids(n);
      for (int i = 0; i < n; ++i) ids[i] = i;
      ex_.to_device(fields_.id.cur(cur), ids.data(), n * sizeof(int));
      std::vector<int> zero(n, 0);
      ex_.to_device(fields_.scattered.cur(cur), zero.data(), n * sizeof(int));
    }
  }

  // lift and drag per unit span (D = 3: the whole span's over the span; D = 2: as summed)
  std::vector<std::pair<std::string, double>> derived(const Scene& r) const {
    const float me = effective_mass(m_.mass, m_.mass), mw = effective_mass(m_.mass, 0.0f);
    double lift = double(r.sums.force[1]), drag = double(r.sums.force[0]);
    if constexpr (D == 3) {
      if (m_.n_tris == 0) {  // (a mesh body's force is the whole body's)
        const double span = double(m_.hi[2]) - double(m_.lo[2]);
        lift /= span;
        drag /= span;
      }
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
  Arrays arrays(int cur, int /* nxt: cur ^ 1 */) {
    Arrays a;
    fields_.fill(a, cur);
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
  Buf<StepSums> items_;
  Buf<int> leaving_;  // this step's leaving particles (the inflow conveyor)
  std::unique_ptr<MeshTree<Exec>> body_tree_;  // D = 3: the mesh body's triangles (model.h)
  int parity_ = 0;
};

}  // namespace cps::wt
