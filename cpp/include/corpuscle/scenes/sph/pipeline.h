// The SPH box pipeline: its buffers, the order of its stages for one step, the index
// plug-ins, the views. SimImpl (sim/sim_impl.h) owns the Exec, the record and the control.
//
// A step: the cell grid (cells of one support radius, tag 0 the fluid and tag 1 the walls)
// keys and sorts the current positions, the arrays are gathered into cell order in the other
// buffers (the pressure computed from the density there), the cell ranges marked (and, for
// the compact index, the chunks listed); then the pair stage through the index, the probes,
// the reductions with the per-scene finalize (CFL dt, clock), and the integration in place.
// The sorted buffers are current afterwards.
//
// Index plug-ins (the same pair stage through each):
//   grid      the cell grid's gather (3^D cells), one thread per particle
//   compact   the cells in chunks of <= 32 particles, one CUDA block per chunk with the
//             neighbour cells' particles staged through shared memory (spatial/compact_grid.h);
//             bit-identical to grid
//   allpairs  every particle against every other, O(N^2) (CUDA: shared-memory tiles of 128)
#pragma once
#include <cmath>
#include <string>
#include <type_traits>
#include <vector>

#include "corpuscle/core/error.h"
#include "corpuscle/scenes/sph/stages.h"
#include "corpuscle/scenes/sph/tables.h"
#include "corpuscle/spatial/allpairs.h"
#include "corpuscle/spatial/compact_grid.h"

namespace cps::sph {

struct GridIndex {
  static constexpr const char* name = "grid";
};
struct CompactIndex {
  static constexpr const char* name = "compact";
};
struct AllPairsIndex {
  static constexpr const char* name = "allpairs";
};

// the kinds this pipeline carries (their dimension and name)
struct FluidBoxKind {
  static constexpr int D = 3;
  static constexpr const char* name = "fluid-box";
};
struct DamBreakKind {
  static constexpr int D = 3;
  static constexpr const char* name = "dam-break";
};
struct DamBreak2Kind {
  static constexpr int D = 2;
  static constexpr const char* name = "dam-break-2d";
};

constexpr int kAllPairsTile = 128;
constexpr int kChunk = 32;

template <class Exec, class Index, class KindT>
class Pipeline {
 public:
  static constexpr int D = KindT::D;
  template <class T> using Buf = typename Exec::template Buffer<T>;
  using SceneRecord = Scene;
  using ControlRecord = Control;
  using ModelT = Model<D>;
  static constexpr const char* kind = KindT::name;
  static constexpr const char* index_name = Index::name;
  static constexpr int kNumStages = 5;
  static const char* stage_name(int s) {
    static const char* const names[] = {"sort+reorder+mark", "interactions", "probes", "reduce+finalize",
                                        "integrate"};
    return names[s];
  }

  static CellGridSpec<D> grid_spec(const ModelT& m) { return make_cell_grid<D>(m.domain_lo, m.domain_hi, m.h, 2); }

  static double bytes_needed(const ModelT& m) {
    const double n = double(m.n_fluid) + double(m.n_wall);
    const double per = 2 * (3 * sizeof(Vec<D>) + 2 * sizeof(float) + sizeof(int)) + sizeof(float) + sizeof(Vec<D>) +
                       sizeof(float) + sizeof(StepSums) + sizeof(int) + 4 * sizeof(uint64_t) + 2 * sizeof(int) +
                       (std::is_same_v<Index, CompactIndex> ? 2 * sizeof(int) : 0);
    const double cells = 2.0 * double(grid_spec(m).table_size()) * sizeof(uint32_t);
    return n * per + cells + sizeof(ModelT);
  }

  CPS_KIND_TABLES(CPS_SPH_FIELDS, CPS_SPH_SCALARS, CPS_SPH_CONTROLS, Scene, Control)

  Pipeline(Exec& ex, const ModelT& m, Scene* g, const Control* u)
      : ex_(ex), m_(m), g_(g), u_(u), grid_(grid_spec(m)) {
    nf_ = m.n_fluid;
    n_ = m.n_fluid + m.n_wall;
    if (nf_ <= 0) throw Error(std::string(kind) + ": no fluid particles");
    model_.resize(1);
    ex_.to_device(model_.data(), &m_, sizeof(ModelT));
    for (int p = 0; p < 2; ++p) {
      pos_[p].resize(n_);
      vel_[p].resize(n_);
      velm_[p].resize(n_);
      rho_[p].resize(n_);
      rhom_[p].resize(n_);
      id_[p].resize(n_);
    }
    prs_.resize(n_);
    acc_.resize(n_);
    drho_.resize(n_);
    items_.resize(n_);
    tags_.resize(n_);
    std::vector<int> tags(n_);
    for (int i = 0; i < n_; ++i) tags[i] = i < nf_ ? kTagFluid : kTagWall;
    ex_.to_device(tags_.data(), tags.data(), n_ * sizeof(int));
    std::vector<int> ids(n_);
    for (int i = 0; i < n_; ++i) ids[i] = i;
    ex_.to_device(id_[0].data(), ids.data(), n_ * sizeof(int));
  }

  static Scene initial_record(const ModelT&) {
    Scene s{};
    s.clock = start_clock();
    s.sums = s.pending = StepSums::identity();
    return s;
  }
  static void restored(Scene& r) {
    r.pending = r.sums;
    r.step_dt = 0.0f;
  }

  long long particles() const { return nf_; }  // the fluid (the walls: n_wall in derived())
  int scenes() const { return 1; }
  template <class R>
  bool recover(std::vector<R>&, double) { return false; }
  const ModelT& model() const { return m_; }
  int graph_slot() const { return parity_; }

  void prepare() {}
  void advance(bool) { parity_ ^= 1; }
  void invalidate(bool) {}

  void enqueue(bool integrate) {
    const int cur = parity_, nxt = parity_ ^ 1;
    ModelT* md = model_.data();
    Scene* g = g_;
    // 1. key and sort (fluid tag 0, walls tag 1), gather into cell order, mark, chunk
    grid_.sort(ex_, pos_[cur].data(), tags_.data(), n_);
    ex_.for_each(n_, ReorderStage<D>{md, grid_.order(), arrays(cur, nxt)});
    grid_.mark(ex_);
    Arrays<D> s = arrays(nxt, cur);
    CellGridView<D> gv = grid_.view(s.pos);
    if constexpr (std::is_same_v<Index, CompactIndex>) compact_.build(ex_, gv);
    ex_.mark(0);
    // 2. the pair sums through the index
    InteractStage<D> st{PairConsts<D>::make(m_), u_, s, nf_};
    if constexpr (std::is_same_v<Index, AllPairsIndex>) {
      AllPairsView<D> av{s.pos, n_, m_.h * m_.h};
      if constexpr (Exec::on_device) gather_stage_tiled<kAllPairsTile>(ex_, av, st);
      else gather_stage(ex_, av, st);
    } else if constexpr (std::is_same_v<Index, CompactIndex>) {
      gather_stage_compact(ex_, compact_.view(gv, kTagWall), st);
    } else {
      ex_.for_each(nf_, GridGatherFn<D, InteractStage<D>>{gv, st, nf_, 0});
      if (n_ > nf_) ex_.for_each(n_ - nf_, GridGatherFn<D, InteractStage<D>>{gv, st, nf_, nf_});
    }
    ex_.mark(1);
    // 3. the probes of this state (the grid's walk; all pairs for that index)
    if (m_.n_probes > 0) {
      if constexpr (std::is_same_v<Index, AllPairsIndex>)
        ex_.for_each(m_.n_probes, ProbeStage<D, AllPairsView<D>>{md, g, s, AllPairsView<D>{s.pos, n_, m_.h * m_.h}, nf_});
      else
        ex_.for_each(m_.n_probes, ProbeStage<D, CellGridView<D>>{md, g, s, gv, nf_});
    }
    ex_.mark(2);
    if (integrate) {
      // 4. the reductions and the per-scene update
      ex_.reduce_then(s.items, n_, &g->pending, SumsOp{}, StepSums::identity(), FinalizeStage<D>{md, g});
      ex_.mark(3);
      // 5. integrate in place (the sorted buffers become the current ones)
      ex_.for_each(n_, IntegrateStage<D>{md, g, s, nf_});
      ex_.mark(4);
    } else {
      ex_.reduce(s.items, n_, &g->sums, SumsOp{}, StepSums::identity());
      ex_.mark(3);
    }
  }

  std::pair<void*, long long> view(const std::string& name, const Scene&) {
    const int nf = nf_, nw = n_ - nf_;
    const int cur = parity_;
#define CPS_FIELD_VIEW(fname, T, comps, group, ckpt, settable, storage, count) \
  if (name == #fname) return {static_cast<void*>(storage), (long long)(count)};
    CPS_SPH_FIELDS(CPS_FIELD_VIEW)
#undef CPS_FIELD_VIEW
    throw Error(std::string(kind) + ": no field '" + name + "'");
  }

  // fluid positions (ids restart at 0..n-1), velocities, densities, a checkpoint's ids, or
  // the walls' positions and densities
  void upload(const std::string& name, const void* src, long long count) {
    const int nf = nf_, nw = n_ - nf_;
    const bool wall = name.rfind("wall_", 0) == 0;
    const long long want = wall ? nw : nf;
    if (count != want) throw Error(std::string(kind) + ": " + name + " needs " + std::to_string(want) + " items");
    const int cur = parity_;
    const size_t off = wall ? size_t(nf) : 0;
    if (name == "position" || name == "wall_position") {
      ex_.to_device(pos_[cur].data() + off, src, count * sizeof(Vec<D>));
      std::vector<int> ids(count);
      for (long long i = 0; i < count; ++i) ids[i] = int(off + i);
      ex_.to_device(id_[cur].data() + off, ids.data(), count * sizeof(int));
      if (wall) {
        // the walls never move: their velocity is zero
        std::vector<Vec<D>> zero(count, Vec<D>::zero());
        ex_.to_device(vel_[cur].data() + off, zero.data(), count * sizeof(Vec<D>));
        ex_.to_device(velm_[cur].data() + off, zero.data(), count * sizeof(Vec<D>));
      }
    } else if (name == "velocity" || name == "velocity_prev") {
      // a velocity set is also the previous step's (a checkpoint's velocity_prev comes after)
      if (name == "velocity") ex_.to_device(vel_[cur].data(), src, count * sizeof(Vec<D>));
      ex_.to_device(velm_[cur].data(), src, count * sizeof(Vec<D>));
    } else if (name == "density" || name == "wall_density" || name == "density_prev" || name == "wall_density_prev") {
      const bool prev = name.find("_prev") != std::string::npos;
      if (!prev) ex_.to_device(rho_[cur].data() + off, src, count * sizeof(float));
      ex_.to_device(rhom_[cur].data() + off, src, count * sizeof(float));
    } else if (name == "id") {
      ex_.to_device(id_[cur].data(), src, count * sizeof(int));
    } else {
      throw Error(std::string(kind) + ": field '" + name + "' cannot be set");
    }
  }

  std::vector<std::pair<std::string, double>> derived(const Scene& r) const {
    const double nbrs = nf_ > 0 ? double(r.sums.nbrs) / double(nf_) : 0.0;
    return {{"vmax", std::sqrt(double(r.sums.vmax2))},
            {"amax", std::sqrt(double(r.sums.amax2))},
            {"mean_neighbors", nbrs},
            {"chosen_dt", double(choose_dt_cfl(m_.cfl, m_.hs, std::sqrt(r.sums.amax2), m_.c0, r.sums.mu_max,
                                               m_.dt_min, m_.dt_max))},
            {"n_fluid", double(nf_)},
            {"n_wall", double(n_ - nf_)},
            {"grid_cells", double(grid_.spec().ncells)}};
  }

 private:
  Arrays<D> arrays(int cur, int nxt) {
    Arrays<D> a;
    a.pos = pos_[cur].data();
    a.vel = vel_[cur].data();
    a.pos_alt = pos_[nxt].data();
    a.vel_alt = vel_[nxt].data();
    a.rho = rho_[cur].data();
    a.rho_alt = rho_[nxt].data();
    a.velm = velm_[cur].data();
    a.velm_alt = velm_[nxt].data();
    a.rhom = rhom_[cur].data();
    a.rhom_alt = rhom_[nxt].data();
    a.id = id_[cur].data();
    a.id_alt = id_[nxt].data();
    a.prs = prs_.data();
    a.acc = acc_.data();
    a.drho = drho_.data();
    a.items = items_.data();
    return a;
  }

  Exec& ex_;
  ModelT m_;
  Scene* g_;
  const Control* u_;
  CellGrid<D, Exec> grid_;
  CompactGrid<D, Exec, kChunk> compact_;
  Buf<ModelT> model_;
  Buf<Vec<D>> pos_[2], vel_[2], velm_[2];
  Buf<float> rho_[2], rhom_[2];
  Buf<int> id_[2];
  Buf<float> prs_, drho_;
  Buf<Vec<D>> acc_;
  Buf<StepSums> items_;
  Buf<int> tags_;
  int nf_ = 0, n_ = 0;
  int parity_ = 0;
};

}  // namespace cps::sph
