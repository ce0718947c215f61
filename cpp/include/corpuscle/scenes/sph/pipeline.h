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
//   lists     Verlet lists (spatial/neighbor_list.h's slot lists): cells of h (1 + skin) are walked
//             only on the steps that relist, listing every slot's neighbours within h (1 + skin),
//             stored slot-interleaved so a thread per particle reads them coalesced and every
//             lane of the pair loop evaluates a listed neighbour; the other steps keep the order
//             (each slot keeps its sorted key: the stable sort leaves it in place) and walk the
//             lists. The integration raises the next step's relisting when a particle has
//             moved more than skin h / 2 since the build (so every pair within h then was within
//             h (1 + skin) at the build). skin = 0: relists every step, bit-identical to grid.
//             The pair pass runs model.lanes lanes per particle (sph.lanes: 1 a thread per
//             particle; 2, 4 or 8 threads splitting its list, ListGatherLanesFn).
#pragma once
#include <cmath>
#include <string>
#include <type_traits>
#include <vector>

#include "corpuscle/core/error.h"
#include "corpuscle/scenes/sph/ranks.h"
#include "corpuscle/scenes/sph/stages.h"
#include "corpuscle/scenes/sph/tables.h"
#include "corpuscle/spatial/allpairs.h"
#include "corpuscle/spatial/compact_grid.h"
#include "corpuscle/spatial/delta_list.h"
#include "corpuscle/spatial/neighbor_list.h"

namespace cps::sph {

struct GridIndex {
  static constexpr const char* name = index_name::grid;
};
struct CompactIndex {
  static constexpr const char* name = index_name::compact;
};
struct AllPairsIndex {
  static constexpr const char* name = index_name::allpairs;
};
struct ListsIndex {
  static constexpr const char* name = index_name::lists;
};

// the pair stage's blocks per multiprocessor on CUDA (__launch_bounds__: 128 threads and 8
// blocks leave 64 registers a thread; the cell walk's 72 gave 7 blocks, 44% occupancy); the
// `lists` pass's own: 10 blocks (51 registers). H200, 2026-12-03 (docs/benchmarks.md): 8 / 10 / 12
// blocks 1,884 / 1,928 / 1,945 steps/s at 129,600 particles, 352 / 353 / 332 at 1,056,321
constexpr int kPairBlocksPerSM = 8;
constexpr int kListPairBlocksPerSM = 10;

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
// the 2-D box of the canonical flows (Taylor-Green, Poiseuille, the lid-driven cavity)
struct FluidBox2Kind {
  static constexpr int D = 2;
  static constexpr const char* name = "fluid-box-2d";
};

// the `lists` pair pass's lanes per particle when the scene does not say (sph.lanes = 0): the
// CPU one; CUDA the fewest lanes (a power of two, at most kMaxAutoListLanes) that give lanes x
// fluid particles >= kListThreads. H200, 2026-12-02 (docs/benchmarks.md), with the list walk
// loading ahead: 129,600 particles 1,814 / 1,882 / 1,819 steps/s at 2 / 4 / 8 lanes; 1,056,321
// particles 351 / 297 at 1 / 2 (before it: 1,499 / 1,581 / 1,688 / 1,733 at 1 / 2 / 4 / 8). More
// lanes pay only while one lane a particle would leave the GPU short of threads.
constexpr int kMaxAutoListLanes = 8;
constexpr long long kListThreads = 400000;
template <class Exec>
inline int auto_list_lanes(int n_fluid) {
  if constexpr (!Exec::on_device) {
    return 1;
  } else {
    int g = 1;
    while (g < kMaxAutoListLanes && (long long)g * n_fluid < kListThreads) g *= 2;
    return g;
  }
}

// the `lists` build's lanes per slot on CUDA (SlotListFillFn: the lanes split each cell's
// candidates; the CPU runs one lane)
constexpr int kListFillLanes = 8;

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
  static constexpr bool kLists = std::is_same_v<Index, ListsIndex>;
  static const char* stage_name(int s) {
    static const char* const names[] = {"sort+reorder+mark", "interactions", "probes", "reduce+finalize",
                                        "integrate"};
    return names[s];
  }

  // cells of the support radius (lists: of the list radius, which the builds walk), sorted in
  // rows: a walk reads each row of its block (three cells) as one range
  static CellGridSpec<D> grid_spec(const ModelT& m) {
    return make_cell_grid<D>(m.domain_lo, m.domain_hi, kLists ? m.list_radius : m.h, 2, kCellGridMaxCells,
                             CellOrder::Rows, m.per.mask);
  }

  static double bytes_needed(const ModelT& m) {
    const double n = double(m.n_fluid) + double(m.n_wall);
    const double per = field_bytes(1.0) + double(sizeof(PairRecord<D>) + (D == 2 ? sizeof(PairRho) : 0) +
                       sizeof(StepSums) + sizeof(int) + 4 * sizeof(uint64_t) + 2 * sizeof(int) +
                       (std::is_same_v<Index, CompactIndex> ? 2 * sizeof(int) : 0) + (kLists ? sizeof(Vec<D>) : 0));
    const double cells = 2.0 * double(grid_spec(m).table_size()) * sizeof(uint32_t);
    const double lists = kLists ? list_bytes(m, int(n), m.max_neighbors) : 0.0;
    const double bodies = m.n_moving > 0 ? double(m.n_wall) * (sizeof(int) + 3 * sizeof(float)) : 0.0;
    const double free = m.n_free > 0 ? double(m.n_wall) * (sizeof(int) + sizeof(BodyItem)) : 0.0;
    const double tvf = m.tvf ? n * 3.0 * sizeof(Vec<D>) : 0.0;  // (transport_, transport_acc_)
    return n * per + cells + lists + bodies + free + tvf + sizeof(ModelT);
  }

  // the lists' bytes for n slots of `capacity` (entries, or bytes when delta-coded)
  static double list_bytes(const ModelT& m, int n, int capacity) {
    return m.list_delta ? DeltaSlotNeighborList<D, Exec>::bytes(n, capacity)
                        : SlotNeighborList<D, Exec>::bytes(n, capacity);
  }

  CPS_KIND_STORED_TABLES(CPS_SPH_FIELDS, CPS_SPH_WALL_FIELDS, CPS_SPH_SCALARS, CPS_SPH_CONTROLS, Scene, Control,
                         Arrays<D>)

  Pipeline(Exec& ex, const ModelT& m, Scene* g, const Control* u)
      : ex_(ex), m_(m), g_(g), u_(u), grid_(grid_spec(m)) {
    nf_ = m.n_fluid;
    n_ = m.n_fluid + m.n_wall;
    if (nf_ <= 0) throw Error(std::string(kind) + ": no fluid particles");
    if (m_.lanes == 0) m_.lanes = kLists ? auto_list_lanes<Exec>(nf_) : 1;
    if (m_.lanes != 1 && m_.lanes != 2 && m_.lanes != 4 && m_.lanes != 8)
      throw Error(std::string(kind) + ": lanes must be 1, 2, 4 or 8 (0: automatic), got " + std::to_string(m_.lanes));
    model_.resize(1);
    ex_.to_device(model_.data(), &m_, sizeof(ModelT));
    if constexpr (kLists)
      if (!(m.list_radius >= m.h) || !(m.rebuild_disp2 >= 0.0f) || m.max_neighbors < 1)
        throw Error(std::string(kind) + ": lists need list_radius >= h, rebuild_distance >= 0 and max_neighbors >= 1");
    id_bound_ = n_;
    resize_slots();
    std::vector<int> ids(n_);
    for (int i = 0; i < n_; ++i) ids[i] = i;
    ex_.to_device(fields_.id.cur(0), ids.data(), n_ * sizeof(int));
    if (m_.tvf) {  // the transport velocity's buffers: v~ - v (zero at the start) and the push
      for (auto& b : transport_) b.resize(n_);
      transport_acc_.resize(n_);
      reset_transport();
    }
  }

  static Scene initial_record(const ModelT& m) {
    Scene s{};
    for (int b = 0; b < m.n_moving; ++b)  // the free bodies' state at t = 0 (bodies.h)
      if (m.motion[b].kind == kBodyFree) free_body_start(m.motion[b], s.free_state + b * kFreeStateDoubles);
    s.clock = start_clock();
    s.sums = s.pending = StepSums::identity();
    s.rebuild = 1;
    return s;
  }
  static void restored(Scene& r) {
    r.pending = r.sums;
    r.step_dt = 0.0f;
    r.rebuild = 1;  // a restored state relists
  }

  long long particles() const { return nf_; }  // the fluid (the walls: n_wall in derived())

  // ---- a scene split over ranks (scenes/sph/ranks.h; driven by corpuscle/_ranks_sph.py) ----
  // the rank's slots: nf fluid (owned and halo), nw walls (owned and halo), ids below id_bound
  // (the whole scene's); every field's values are undefined until set_slots writes them
  void set_counts(int nf, int nw, long long id_bound) {
    if (nf < 0 || nw < 0) throw Error(std::string(kind) + ": negative particle counts");
    if (m_.n_moving > 0) throw Error(std::string(kind) + ": moving bodies are not split over ranks");
    nf_ = nf;
    n_ = nf + nw;
    m_.n_fluid = nf;
    m_.n_wall = nw;
    ex_.to_device(model_.data(), &m_, sizeof(ModelT));
    id_bound_ = id_bound;
    resize_slots();
    relist_ = true;
  }
  // a step in halves: phase 0 the step up to its reductions (the rank's sums written to `sums`,
  // a StepSums), phase 1 (`sums`: the ranks' StepSums, `ranks` of them, combined here in rank
  // order with StepSums::combine, the same on every rank) the finalize, the probes' series and
  // the integration. The caller advances the parity after phase 1 (SimImpl::step_half).
  void enqueue_half(int phase, void* sums, int ranks) {
    if (phase == 0) {
      front();
      ex_.reduce(arrays(parity_ ^ 1, parity_).items, n_, &g_->pending, SumsOp{}, StepSums::identity());
      ex_.mark(3);
      ex_.to_host(sums, &g_->pending, sizeof(StepSums));
    } else {
      const StepSums all = combine_rank_sums(static_cast<const StepSums*>(sums), ranks);
      ex_.to_device(&g_->pending, &all, sizeof(StepSums));
      ex_.single(FinalizeStage<D>{model_.data(), g_, kLists});
      back();
    }
  }
  static size_t step_sums_size() { return sizeof(StepSums); }
  static void rank_flags(const Scene& r, long long* flags) {
    flags[0] = r.clock.bad;
    flags[1] = r.rebuild;
    flags[2] = r.outside;
  }
  // the items of a stored field (every slot: fluid then walls) at `slots` to the host / from it
  void get_slots(const std::string& name, const int* slots, long long count, void* out) {
    slot_copy(name, slots, count, out, false);
  }
  void set_slots(const std::string& name, const int* slots, long long count, const void* in) {
    slot_copy(name, slots, count, const_cast<void*>(in), true);
  }
  long long slots() const { return n_; }
  int scenes() const { return 1; }

  // `lists`: a list that overflowed stopped the step before it was taken (kBadNeighbors); the
  // capacity grows to 1.25 times the largest count found (the counts are the true ones) and
  // the step is repeated with new lists. False (the run stops) when nothing overflowed or the
  // larger lists would not fit in `bytes_free`.
  template <class R>
  bool recover(std::vector<R>& recs, double bytes_free) {
    if constexpr (!kLists) {
      return false;
    } else {
      bool overflow = false;
      for (const R& r : recs) overflow = overflow || r.clock.bad == kBadNeighbors;
      if (!overflow) return false;
      const int need = m_.list_delta ? dlists_.max_count(ex_) : lists_.max_count(ex_);
      long long want = (long long)(1.25 * double(need)) + 32;
      want = (want + 31) / 32 * 32;
      if (want > n_ && !m_.list_delta) want = n_;  // never more than every other slot
      if (m_.list_delta && want > 5LL * n_ + 32) want = 5LL * n_ + 32;  // (every other slot escaped)
      if (want <= m_.max_neighbors) return false;
      const double extra = list_bytes(m_, n_, int(want)) - list_bytes(m_, n_, m_.max_neighbors);
      if (extra > bytes_free) return false;
      m_.max_neighbors = int(want);
      ex_.to_device(model_.data(), &m_, sizeof(ModelT));
      reserve_lists();
      for (R& r : recs)
        if (r.clock.bad == kBadNeighbors) {  // the step was not taken: it is repeated, relisting
          r.clock.bad = 0;
          r.clock.bad_step = -1;
          r.rebuild = 1;
        }
      return true;
    }
  }
  const ModelT& model() const { return m_; }
  int graph_slot() const { return parity_; }

  // `lists`: a replaced state relists at its next step (outside any captured graph)
  void prepare() {
    if constexpr (kLists) {
      if (relist_) ex_.single(RaiseRebuildStage{g_});
    }
    if (relist_ && m_.n_moving > 0) place_bodies(arrays(parity_, parity_ ^ 1));  // (a set or restored state)
    relist_ = false;
  }

  // the moving bodies (bodies.h): the motion tables' rows (kBodyTableCols floats each), and per
  // wall particle (by its slot at the build) its moving body (-1: none) and its offset in the
  // body's frame (3 floats)
  void set_bodies(const float* table, long long rows, const float* body, const float* local) {
    const int nw = n_ - nf_;
    if (rows > 0) {
      table_.resize(size_t(rows) * kBodyTableCols);
      ex_.to_device(table_.data(), table, size_t(rows) * kBodyTableCols * sizeof(float));
    }
    std::vector<int> b(size_t(nw > 0 ? nw : 0));
    for (int k = 0; k < nw; ++k) {
      b[k] = int(body[k]);
      if (b[k] < -1 || b[k] >= m_.n_moving)
        throw Error(std::string(kind) + ": wall particle " + std::to_string(k) + " names moving body " +
                    std::to_string(b[k]) + " of " + std::to_string(m_.n_moving));
    }
    wall_body_.resize(size_t(nw));
    wall_local_.resize(size_t(nw) * 3);
    if (nw > 0) {
      ex_.to_device(wall_body_.data(), b.data(), size_t(nw) * sizeof(int));
      ex_.to_device(wall_local_.data(), local, size_t(nw) * 3 * sizeof(float));
    }
    for (int k = 0; k < m_.n_moving; ++k)
      if (m_.motion[k].kind == kBodyTable && (m_.motion[k].row0 < 0 || m_.motion[k].rows < 2 ||
                                              m_.motion[k].row0 + m_.motion[k].rows > rows))
        throw Error(std::string(kind) + ": moving body " + std::to_string(k) + "'s table rows lie outside the table");
    // free bodies: each one's particles are a run of wall ids [w0, w0 + nw) (its force and
    // torque are reduced over it), flagged for the pair stage
    if (m_.n_free > 0) {
      std::vector<int> flag(size_t(nw > 0 ? nw : 0), 0);
      for (int bi = 0; bi < m_.n_moving; ++bi) {
        BodyMotion& mo = m_.motion[bi];
        if (mo.kind != kBodyFree) continue;
        int first = -1, last = -1, count = 0;
        for (int k = 0; k < nw; ++k)
          if (b[k] == bi) {
            if (first < 0) first = k;
            last = k;
            ++count;
            flag[k] = 1;
          }
        if (count == 0 || last - first + 1 != count)
          throw Error(std::string(kind) + ": free body " + std::to_string(bi) + "'s particles must be one run of wall ids");
        mo.w0 = first;
        mo.nw = count;
      }
      wall_free_.resize(size_t(nw));
      ex_.to_device(wall_free_.data(), flag.data(), size_t(nw) * sizeof(int));
      body_items_.resize(size_t(nw));
      ex_.to_device(model_.data(), &m_, sizeof(ModelT));
    }
    relist_ = true;
  }
  void advance(bool) { parity_ ^= 1; }
  void invalidate(bool) { relist_ = true; }

  void enqueue(bool integrate) {
    front();
    if (integrate) {
      // 4. the reductions and the per-scene update
      ex_.reduce_then(arrays(parity_ ^ 1, parity_).items, n_, &g_->pending, SumsOp{}, StepSums::identity(),
                      FinalizeStage<D>{model_.data(), g_, kLists});
      back();
    } else {
      ex_.reduce(arrays(parity_ ^ 1, parity_).items, n_, &g_->sums, SumsOp{}, StepSums::identity());
      ex_.mark(3);
    }
  }

 private:
  // the step up to its reductions: 1. sort, reorder, mark, lists; 2. the pair pass; 3. probes
  void front() {
    const int cur = parity_, nxt = parity_ ^ 1;
    ModelT* md = model_.data();
    Scene* g = g_;
    const int* ids = m_.order_by_id ? fields_.id.cur(cur) : nullptr;  // (the tie-break by id)
    // 1. key and sort (fluid tag 0, walls tag 1), gather into cell order, mark, chunk
    //    (lists: the key, sort and mark run only on the steps that relist, as a conditional part
    //    of the step (Exec::run_if: on CUDA a conditional node of the captured graph, skipped
    //    on the device's flag); run anyway (eagerly), a step that does not relist keeps every
    //    slot's key, so the sort leaves the order and the marks as they were. The reorder then
    //    takes slot j from slot j. The lists are built on the steps that relist only.)
    if constexpr (kLists) {
      ex_.run_if(&g->rebuild, [&] {
        grid_.sort_if(ex_, fields_.position.cur(cur), tags_.data(), n_, &g->rebuild, ids, id_bits());
        grid_.mark(ex_);
      });
      ex_.for_each(n_, ReorderStage<D>{md, grid_.order(), arrays(cur, nxt), &g->rebuild});
    } else {
      grid_.sort(ex_, fields_.position.cur(cur), tags_.data(), n_, ids, id_bits());
      ex_.for_each(n_, ReorderStage<D>{md, grid_.order(), arrays(cur, nxt), nullptr});
      grid_.mark(ex_);
    }
    Arrays<D> s = arrays(nxt, cur);
    CellGridView<D> gv = grid_.view(s.position);
    if constexpr (std::is_same_v<Index, CompactIndex>) compact_.build(ex_, gv);
    if constexpr (kLists) {
      if (m_.list_delta) fill_lists(dlists_, gv, g);
      else fill_lists(lists_, gv, g);
    }
    ex_.mark(0);
    // 2. the pair sums through the index (the default model's terms fixed at compile time,
    //    DefaultTerms: no per-pair dispatch; any other model dispatches them per pair)
    const InteractStage<D> st{PairConsts<D>::make(m_), u_, s, nf_, m_.n_free > 0 ? wall_free_.data() : nullptr};
    if (fixed_terms()) pair_pass(s, gv, InteractStage<D, DefaultTerms>{st.m, st.ctl, st.a, st.nf, st.free_wall});
    else pair_pass(s, gv, st);
    ex_.mark(1);
    // 3. the probes of this state (the grid's walk; all pairs for that index)
    if (m_.n_probes > 0) {
      if constexpr (std::is_same_v<Index, AllPairsIndex>)
        ex_.for_each(m_.n_probes, ProbeStage<D, AllPairsView<D>>{md, g, s, AllPairsView<D>{s.position, n_, m_.h * m_.h, m_.per}, nf_});
      else  // (lists: the cells of the last build, of the list radius, hold every fluid particle within h)
        ex_.for_each(m_.n_probes, ProbeStage<D, CellGridView<D>>{md, g, s, kLists ? gv.with_radius(m_.h) : gv, nf_});
    }
    // the free bodies' force and torque of this state (bodies.h)
    if (m_.n_free > 0) body_forces(s);
    ex_.mark(2);
  }
  // after the finalize: the probes' series, 5. the integration, the moving bodies
  void back() {
    ModelT* md = model_.data();
    Scene* g = g_;
    Arrays<D> s = arrays(parity_ ^ 1, parity_);
    // the probes' series: a taken step appends each due probe's reading (probe.h)
    if (m_.n_probes > 0) ex_.for_each(1, ProbeSeriesStage<D>{md, g});
    ex_.mark(3);
    // 5. integrate in place (the sorted buffers become the current ones)
    ex_.for_each(n_, IntegrateStage<D>{md, g, s, nf_});
    // the free bodies' step (their force and torque of this state, the step's dt)
    if (m_.n_free > 0) ex_.single(FreeBodyStage<D>{md, g, u_});
    // the moving bodies' particles at the pose of the new time (bodies.h)
    if (m_.n_moving > 0) place_bodies(s);
    ex_.mark(4);
  }

 public:

  std::pair<void*, long long> view(const std::string& name, const Scene&) {
    const int nf = nf_, nw = n_ - nf_;
    const int cur = parity_;
    std::pair<void*, long long> stored;
    if (field_view(name, cur, nf, stored)) return stored;
#define CPS_FIELD_VIEW(fname, T, comps, group, ckpt, settable, storage, count) \
  if (name == #fname) return {static_cast<void*>(storage), (long long)(count)};
    CPS_SPH_WALL_FIELDS(CPS_FIELD_VIEW)
#undef CPS_FIELD_VIEW
    throw Error(std::string(kind) + ": no field '" + name + "'");
  }

  // fluid positions (ids restart at 0..n-1), velocities, densities, a checkpoint's ids, or
  // the walls' positions and densities
  void upload(const std::string& name, const void* src, long long count) {
    relist_ = true;
    const int nf = nf_, nw = n_ - nf_;
    const bool wall = name.rfind("wall_", 0) == 0;
    const long long want = wall ? nw : nf;
    const int cur = parity_;
    const size_t off = wall ? size_t(nf) : 0;
    if (name == "transport") {  // (a checkpoint's; the fluid's slots, none when the formulation is off)
      if (count != transport_count()) throw Error(std::string(kind) + ": transport needs " + std::to_string(transport_count()) + " items");
      if (count > 0) ex_.to_device(transport_view(cur), src, count * sizeof(Vec<D>));
      return;
    }
    if (count != want) throw Error(std::string(kind) + ": " + name + " needs " + std::to_string(want) + " items");
    if (name == "position" || name == "wall_position") {
      ex_.to_device(fields_.position.cur(cur) + off, src, count * sizeof(Vec<D>));
      if (!wall && m_.tvf) reset_transport();  // a new state starts with v~ = v
      std::vector<int> ids(count);
      for (long long i = 0; i < count; ++i) ids[i] = int(off + i);
      ex_.to_device(fields_.id.cur(cur) + off, ids.data(), count * sizeof(int));
      if (wall) {
        // the walls never move: their velocity is zero (a moving wall's is set after, wall_velocity)
        std::vector<Vec<D>> zero(count, Vec<D>::zero());
        ex_.to_device(fields_.velocity.cur(cur) + off, zero.data(), count * sizeof(Vec<D>));
        ex_.to_device(fields_.velocity_prev.cur(cur) + off, zero.data(), count * sizeof(Vec<D>));
      }
    } else if (name == "wall_id") {
      // (a checkpoint's: the walls' order at the time, which the moving bodies' particles need;
      // a permutation of the walls' slots nf .. n - 1)
      const int* ids = static_cast<const int*>(src);
      std::vector<char> seen(size_t(count), 0);
      for (long long k = 0; k < count; ++k) {
        const long long w = (long long)ids[k] - nf;
        if (w < 0 || w >= count || seen[size_t(w)])
          throw Error(std::string(kind) + ": wall_id must be a permutation of " + std::to_string(nf) + " .. " +
                      std::to_string(nf + count - 1));
        seen[size_t(w)] = 1;
      }
      ex_.to_device(fields_.id.cur(cur) + off, src, count * sizeof(int));
    } else if (name == "wall_velocity") {
      // a moving wall's prescribed velocity (it enters the pair terms; the wall stays in place)
      ex_.to_device(fields_.velocity.cur(cur) + off, src, count * sizeof(Vec<D>));
      ex_.to_device(fields_.velocity_prev.cur(cur) + off, src, count * sizeof(Vec<D>));
    } else if (name == "velocity" || name == "velocity_prev") {
      // a velocity set is also the previous step's (a checkpoint's velocity_prev comes after)
      if (name == "velocity") ex_.to_device(fields_.velocity.cur(cur), src, count * sizeof(Vec<D>));
      ex_.to_device(fields_.velocity_prev.cur(cur), src, count * sizeof(Vec<D>));
    } else if (name == "density" || name == "wall_density" || name == "density_prev" || name == "wall_density_prev") {
      const bool prev = name.find("_prev") != std::string::npos;
      if (!prev) ex_.to_device(fields_.density.cur(cur) + off, src, count * sizeof(float));
      ex_.to_device(fields_.density_prev.cur(cur) + off, src, count * sizeof(float));
    } else if (name == "id") {
      ex_.to_device(fields_.id.cur(cur), src, count * sizeof(int));
    } else {
      throw Error(std::string(kind) + ": field '" + name + "' cannot be set");
    }
  }

  std::vector<std::pair<std::string, double>> derived(const Scene& r) const {
    const double nbrs = nf_ > 0 ? double(r.sums.nbrs) / double(nf_) : 0.0;
    std::vector<std::pair<std::string, double>> out = {{"vmax", std::sqrt(double(r.sums.vmax2))},
            {"amax", std::sqrt(double(r.sums.amax2))},
            {"mean_neighbors", nbrs},
            {"chosen_dt", double(choose_dt_cfl(m_.cfl, m_.hs, std::sqrt(r.sums.amax2), m_.c0, r.sums.mu_max,
                                               m_.laminar_nu(), m_.dt_min, m_.dt_max))},
            {"n_fluid", double(nf_)},
            {"n_wall", double(n_ - nf_)},
            {"grid_cells", double(grid_.spec().ncells)}};
    if constexpr (kLists) {
      out.push_back({"list_capacity", double(m_.max_neighbors)});
      out.push_back({"list_radius", double(m_.list_radius)});
      out.push_back({"lanes", double(m_.lanes)});  // lanes per particle in the pair pass
    }
    // 1: the pair pass's terms fixed at compile time (the default model's, DefaultTerms)
    out.push_back({"fixed_terms", fixed_terms() ? 1.0 : 0.0});
    return out;
  }

 private:
  // every per-slot buffer sized to n_ (the halo flags zero: every slot the rank's own), the tags
  void resize_slots() {
    fields_.resize(size_t(n_));
    ex_.zero(fields_.halo.cur(0), size_t(n_) * sizeof(int));
    ex_.zero(fields_.halo.cur(1), size_t(n_) * sizeof(int));
    rec_.resize(n_);
    if constexpr (D == 2) pr_.resize(n_);  // (3-D: rho_j rides in the record's position)
    if constexpr (kLists) {
      x_build_.resize(n_);
      reserve_lists();
    }
    items_.resize(n_);
    tags_.resize(n_);
    std::vector<int> tags(n_);
    for (int i = 0; i < n_; ++i) tags[i] = i < nf_ ? kTagFluid : kTagWall;
    if (n_ > 0) ex_.to_device(tags_.data(), tags.data(), n_ * sizeof(int));
  }
  // bits of the largest id (the tie-break's first sort)
  int id_bits() const {
    int b = 1;
    while ((1LL << b) < id_bound_) ++b;
    return b;
  }
  // a stored field's items at slots to the host (or back): through a staging buffer on the backend
  void slot_copy(const std::string& name, const int* slots, long long count, void* host, bool to_slots) {
    if (count <= 0) return;
    for (long long k = 0; k < count; ++k)
      if (slots[k] < 0 || slots[k] >= n_) throw Error(std::string(kind) + ": slot " + std::to_string(slots[k]) + " out of range");
    void* base = nullptr;
    size_t words = 0;
#define CPS_SPH_SLOT_FIELD_(fname, T, comps, group, ckpt, settable, recorded, moves) \
    if (name == #fname) { base = fields_.fname.cur(parity_); words = sizeof(CPS_FS_ITEM_(T, comps)) / 4; }
    CPS_SPH_FIELDS(CPS_SPH_SLOT_FIELD_)
#undef CPS_SPH_SLOT_FIELD_
    if (!base) throw Error(std::string(kind) + ": no stored field '" + name + "'");
    if (slot_idx_.size() < size_t(count)) slot_idx_.resize(size_t(count));
    if (slot_buf_.size() < size_t(count) * words) slot_buf_.resize(size_t(count) * words);
    ex_.to_device(slot_idx_.data(), slots, size_t(count) * sizeof(int));
    uint32_t* field = static_cast<uint32_t*>(base);
    if (to_slots) {
      ex_.to_device(slot_buf_.data(), host, size_t(count) * words * 4);
      ex_.for_each(int(count), SlotWordsStage{slot_idx_.data(), int(words), field, slot_buf_.data(), true});
    } else {
      ex_.for_each(int(count), SlotWordsStage{slot_idx_.data(), int(words), field, slot_buf_.data(), false});
      ex_.synchronize();
      ex_.to_host(host, slot_buf_.data(), size_t(count) * words * 4);
    }
  }
  bool fixed_terms() const {
    return m_.fixed_terms && DefaultTerms::matches(m_);
  }
  // the pair stage through the index
  template <class Stage>
  void pair_pass(const Arrays<D>& s, const CellGridView<D>& gv, const Stage& st) {
    if constexpr (kLists) {
      // (the walk reads the records' positions: the first member, a record apart)
      constexpr int stride = int(sizeof(PairRecord<D>) / sizeof(VecA<D>));
      const VecA<D>* rp = reinterpret_cast<const VecA<D>*>(s.rec);
      if (m_.list_delta) list_pass_lanes(dlists_.view(rp, m_.h, stride, m_.per), st);
      else list_pass_lanes(lists_.view(rp, m_.h, stride, m_.per), st);
    } else if constexpr (std::is_same_v<Index, AllPairsIndex>) {
      AllPairsView<D> av{s.position, n_, m_.h * m_.h, m_.per};
      if constexpr (Exec::on_device) gather_stage_tiled<kAllPairsTile>(ex_, av, st);
      else gather_stage(ex_, av, st);
    } else if constexpr (std::is_same_v<Index, CompactIndex>) {
      gather_stage_compact(ex_, compact_.view(gv, kTagWall), st);
    } else {
      ex_.template for_each_bounded<kPairBlocksPerSM>(nf_, GridGatherFn<D, Stage>{gv, st, nf_, 0});
      if (n_ > nf_) ex_.template for_each_bounded<kPairBlocksPerSM>(n_ - nf_, GridGatherFn<D, Stage>{gv, st, nf_, nf_});
    }
  }
  // the lists' storage (the model's list_delta) with room for max_neighbors
  void reserve_lists() {
    if (m_.list_delta) dlists_.reserve(ex_, n_, m_.max_neighbors);
    else lists_.reserve(ex_, n_, m_.max_neighbors);
  }
  // the lists' build on the steps that relist: the fluid's, then the walls' (of the fluid only)
  template <class Lists>
  void fill_lists(Lists& lists, const CellGridView<D>& gv, Scene* g) {
    lists.template fill<kListFillLanes>(ex_, gv, m_.list_radius, 0, nf_, &g->clock.bad, kBadNeighbors, &g->rebuild);
    if (n_ > nf_)  // the walls list the fluid only
      lists.template fill<kListFillLanes>(ex_, gv.tags(kTagFluid, kTagFluid + 1), m_.list_radius, nf_, n_ - nf_,
                                          &g->clock.bad, kBadNeighbors, &g->rebuild);
  }
  template <class LV, class Stage>
  void list_pass_lanes(const LV& lv, const Stage& st) {
    switch (m_.lanes) {
      case 2: list_pass<2>(lv, st); break;
      case 4: list_pass<4>(lv, st); break;
      case 8: list_pass<8>(lv, st); break;
      default: list_pass<1>(lv, st); break;
    }
  }
  // the `lists` pair pass with G lanes per particle (the fluid, then the walls)
  template <int G, class LV, class Stage>
  void list_pass(const LV& lv, const Stage& st) {
    if constexpr (G == 1) {
      using Fn = ListGatherFn<LV, Stage>;
      ex_.template for_each_bounded<kListPairBlocksPerSM>(nf_, Fn{lv, st, 0});
      if (n_ > nf_) ex_.template for_each_bounded<kListPairBlocksPerSM>(n_ - nf_, Fn{lv, st, nf_});
    } else {
      using Fn = ListGatherLanesFn<G, LV, Stage>;
      ex_.template for_each_lanes_w_bounded<G, kListPairBlocksPerSM>(nf_, Fn{lv, st, 0});
      if (n_ > nf_) ex_.template for_each_lanes_w_bounded<G, kListPairBlocksPerSM>(n_ - nf_, Fn{lv, st, nf_});
    }
  }

  // the free bodies' force and torque: each particle's share (by its wall id), then one
  // reduction a body over its run of wall ids into the record's body_force
  void body_forces(const Arrays<D>& a) {
    ex_.for_each(n_ - nf_, BodyForceStage<D>{model_.data(), g_, a, wall_body_.data(), body_items_.data(), nf_});
    for (int b = 0; b < m_.n_moving; ++b) {
      const BodyMotion& mo = m_.motion[b];
      if (mo.kind != kBodyFree) continue;
      ex_.reduce(body_items_.data() + mo.w0, mo.nw, reinterpret_cast<BodyItem*>(g_->body_force + b * kBodyForceDoubles),
                 BodyItemOp{}, BodyItem::identity());
    }
  }

  // the moving bodies' poses at the record's time and their particles at them (arrays a)
  void place_bodies(const Arrays<D>& a) {
    ex_.single(BodyPoseStage<D>{model_.data(), g_, table_.size() ? table_.data() : nullptr});
    if (n_ > nf_) ex_.for_each(n_ - nf_, BodyParticlesStage<D>{model_.data(), g_, a, wall_body_.data(), wall_local_.data(), nf_});
  }

  // the transport velocity's v~ - v (the fluid's slots of the current buffer; none when off)
  Vec<D>* transport_view(int cur) { return m_.tvf ? transport_[cur].data() : nullptr; }
  long long transport_count() const { return m_.tvf ? nf_ : 0; }
  void reset_transport() {
    std::vector<Vec<D>> zero(size_t(n_), Vec<D>::zero());
    for (auto& b : transport_) ex_.to_device(b.data(), zero.data(), size_t(n_) * sizeof(Vec<D>));
  }

  Arrays<D> arrays(int cur, int nxt) {
    Arrays<D> a;
    fields_.fill(a, cur);  // (the other buffers: nxt = cur ^ 1)
    (void)nxt;
    a.transport = m_.tvf ? transport_[cur].data() : nullptr;
    a.transport_alt = m_.tvf ? transport_[cur ^ 1].data() : nullptr;
    a.transport_acc = m_.tvf ? transport_acc_.data() : nullptr;
    a.rec = rec_.data();
    a.pr = D == 2 ? pr_.data() : nullptr;
    a.x_build = kLists ? x_build_.data() : nullptr;
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
  Buf<PairRecord<D>> rec_;
  Buf<PairRho> pr_;
  Buf<Vec<D>> x_build_;
  Buf<Vec<D>> transport_[2];   // the transport velocity's v~ - v (current and other, by parity)
  Buf<Vec<D>> transport_acc_;  // its step's background push
  SlotNeighborList<D, Exec> lists_;
  DeltaSlotNeighborList<D, Exec> dlists_;  // (list_delta: the lists delta-coded)
  bool relist_ = false;
  Buf<StepSums> items_;
  Buf<float> table_;      // the moving bodies' motion tables
  Buf<int> wall_body_;    // per wall particle (its slot at the build): its moving body or -1
  Buf<float> wall_local_; // per wall particle: its offset in its body's frame
  Buf<int> wall_free_;    // per wall particle: 1 for a free body's (the pair stage's flag)
  Buf<BodyItem> body_items_;  // per wall particle: its share of its free body's force and torque
  Buf<int> tags_;
  Buf<int> slot_idx_;        // get_slots / set_slots: the slots, and their items' words
  Buf<uint32_t> slot_buf_;
  long long id_bound_ = 0;   // ids lie below it (the tie-break's bits)
  int nf_ = 0, n_ = 0;
  int parity_ = 0;
};

}  // namespace cps::sph
