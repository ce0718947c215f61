// The Magic 8-Ball pipeline: its buffers (declared by the field table and the lists below),
// the order of its stages for one step, and the views the engine hands out. SimImpl
// (sim/sim_impl.h) owns the Exec, the per-scene record and the control, and runs it.
//
// Index plug-ins (`--neighbors`): Lists (cells walked on rebuilds only, neighbour lists with a
// skin reused in between), Grid (the cells walked every step by both pair stages) and
// Compact (the grid's cells in chunks of a warp, each chunk's neighbour cells staged through
// shared memory: spatial/compact_grid.h; a single scene) and AllPairs (every fluid particle
// and ghost visited: O(N^2), a reference). All four visit the same neighbours within h, so
// they give the same physics to float rounding (on the CPU, grid and compact visit them in
// the same order: the same results).
#pragma once
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "corpuscle/core/error.h"
#include "corpuscle/scenes/magic8ball/batch.h"
#include "corpuscle/scenes/magic8ball/chip.h"
#include "corpuscle/scenes/magic8ball/stages.h"
#include "corpuscle/scenes/magic8ball/tables.h"

namespace cps::m8 {

template <class Exec, class Index>
class Pipeline {
 public:
  template <class T> using Buf = typename Exec::template Buffer<T>;
  using SceneRecord = Scene;
  using ControlRecord = Control;
  static constexpr const char* kind = "magic8ball";
  static constexpr const char* index_name = Index::name;
  static constexpr int kNumStages = 4;
  static const char* stage_name(int s) {
    static const char* const names[] = {"sort+reorder", "density", "forces+reduce+finalize", "integrate+keys"};
    return names[s];
  }

  // element counts of the buffers, for the allocation and the estimate before it
  static size_t list_slots(const Model& m) { return Index::lists ? size_t(total_fluid(m)) * size_t(m.max_neighbors) : 0; }
  static size_t near_slots(const Model& m) { return Index::lists ? size_t(total_fluid(m)) * size_t(m.max_near) : 0; }
  static double bytes_needed(const Model& m) {
    const double n = total_fluid(m), cap = 2.0 * n;
    const double per_slot = sizeof(ForceTerms) + 2 * sizeof(uint32_t) + 2 * sizeof(int);
    const double per_fluid = 2 * sizeof(int) + 2 * sizeof(Vec3) + sizeof(StepSums) + 2 * sizeof(int) +
                             (Index::compact ? 2 * sizeof(int) : 0);
    const double lists = sizeof(int) * (double(list_slots(m)) + double(near_slots(m)));
    const double cells = 2.0 * double(cells_per_scene(m)) * double(m.n_scenes) * sizeof(uint32_t);
    const double sort_scratch = cap * (sizeof(uint32_t) + sizeof(int)) * 2.0;
    const double batch = m.n_scenes > 1 ? (narrow_key_bits(m) ? 0.0 : cap * 2.0 * sizeof(uint64_t)) +
                                              m.n_scenes * sizeof(StepSums)
                                        : 0.0;
    return field_bytes(cap) + cap * per_slot + n * per_fluid + lists + cells + sort_scratch + batch;
  }

  // a batch's sort keys: the segment (layer and scene) above the cell key, or above a scene
  // that keeps its order's slot index (below n_fluid); 32-bit keys when both fit in 32 bits
  // (the low field's width returned), else 64-bit (0)
  static int segment_bits(const Model& m) {
    int b = 1;
    while ((1LL << b) < 2LL * m.n_scenes) ++b;
    return b;
  }
  static int narrow_key_bits(const Model& m) {
    int low = 1;
    while ((1LL << low) < (long long)m.n_fluid) ++low;
    if (low < key_bits(m)) low = key_bits(m);
    return !m.wide_keys && low + segment_bits(m) <= 32 ? low : 0;
  }

  CPS_KIND_STORED_TABLES(CPS_M8_FIELDS, CPS_M8_GHOST_FIELDS, CPS_M8_SCALARS, CPS_M8_CONTROLS, Scene, Control, Arrays)

  Pipeline(Exec& ex, const Model& m, Scene* g, const Control* u) : ex_(ex), m_(m), g_(g), u_(u) {
    if (m.n_fluid <= 0) throw Error("magic8ball: no fluid particles");
    if (m.n_scenes <= 0) throw Error("magic8ball: no scenes");
    if (Index::compact && m.n_scenes > 1)
      throw Error("magic8ball: the compact index runs one scene; a batch of scenes uses lists, grid or allpairs");
    const int n = total_fluid(m), cap = 2 * n;
    model_.resize(1);
    ex_.to_device(model_.data(), &m_, sizeof(Model));
    fields_.resize(size_t(cap));
    terms_.resize(cap);
    keys_.resize(cap);
    keys_sorted_.resize(cap);
    idx_.resize(cap);
    perm_.resize(cap);
    ghost_of_.resize(n);
    ghost_slot_.resize(n);
    x_build_.resize(n);
    xsph_.resize(n);
    items_.resize(n);
    nbr_.resize(list_slots(m));
    nbr_count_.resize(n);
    near_.resize(near_slots(m));
    near_count_.resize(n);
    cells_start_.resize(cells_per_scene(m) * size_t(m.n_scenes));
    cells_end_.resize(cells_per_scene(m) * size_t(m.n_scenes));
    if (m.n_scenes > 1) {
      key_low_bits_ = narrow_key_bits(m);
      if (!key_low_bits_) {
        keys64_.resize(cap);
        keys64_sorted_.resize(cap);
      }
      scene_sums_.resize(m.n_scenes);
    }
    chip_ = choose_chip(ex_, m);
  }

  // The chip path (chip.h: a block per scene, K steps a launch) where the scenes fit a block's
  // shared memory: forced by path 1 (a device) or 2
  // (also the CPU's emulated tiles: the tests'); the general path for the rest. The lists
  // index has it (its lists, in the pipeline's buffers, are the one array off chip)
  static constexpr bool kChipIndex = Index::lists;
  static bool choose_chip(Exec& ex, const Model& m) {
    // auto (path -1) takes the general path: measured on an H200 (batch 4,096 x 1,000), the chip
    // path ran 0.70x the general one (docs/magic8ball.md); it is chosen only when asked for
    if (m.path <= 0) return false;
    const size_t limit = ex.tile_shared_limit();
    const bool fits = kChipIndex && chip_fits(m, limit);
    if (m.path == 1 && !Exec::on_device)
      throw Error("magic8ball: path = chip runs on the cuda backend (the CPU backends step the general path)");
    if (!kChipIndex)
      throw Error(std::string("magic8ball: path = chip needs the lists index, got ") + Index::name);
    if (!chip_layout(m).words_fit())
      throw Error("magic8ball: path = chip: " + std::to_string(m.n_fluid) +
                  " particle slots a scene and its cell grid need more than 32-bit sort words: use path = general");
    if (!fits) {
      char msg[320];
      std::snprintf(msg, sizeof msg,
                    "magic8ball: path = chip: a scene of %d particle slots needs %.1f KiB of shared memory a block, "
                    "the device has %.1f KiB: use path = general (or fewer particles a scene)",
                    m.n_fluid, double(chip_bytes(m)) / 1024.0, double(limit) / 1024.0);
      throw Error(msg);
    }
    return true;
  }
  bool chip() const { return chip_; }
  // steps the next launch takes on chip (at most `want`), or 0: the general path's one step
  int chip_steps(long long want) const { return chip_ ? int(std::min<long long>(want, kChipLaunchSteps)) : 0; }
  static constexpr int kChipLaunchSteps = 1024;
  // k steps of every scene on chip, one launch (the state in the other buffers: advance flips)
  void enqueue_chip(int k) {
    ex_.template for_each_tile<kChipThreads>(m_.n_scenes, ChipStage{model_.data(), g_, u_, arrays(parity_, parity_ ^ 1), k},
                                             chip_bytes(m_));
  }

  int scenes() const { return m_.n_scenes; }

  // the record of a new scene: the clock at zero, the die as given, the shell at rest
  static Scene initial_record(const RigidState& die, const ScenePhysics& phys) {
    Scene s{};
    s.phys = phys;
    s.clock = start_clock();
    s.die = die;
    s.shell_q = Quat::identity();
    s.shell_omega = Vec3::zero();
    s.sums = s.pending = StepSums::identity();
    return s;
  }

  // A list overflow stops a scene before its step is taken (kBadNeighbors); the lists then
  // grow to 1.25 times the largest count found (the counts are the true ones, past the
  // capacity) and every scene relists: the engine clears the flags and repeats the step.
  // False (the run stops) when nothing overflowed or the larger lists would not fit in
  // `bytes_free`.
  bool recover(std::vector<Scene>& recs, double bytes_free) {
    if constexpr (!Index::lists) {
      return false;
    } else {
      bool overflow = false;
      for (const Scene& r : recs) overflow = overflow || r.clock.bad == kBadNeighbors;
      if (!overflow) return false;
      const int n = total_fluid(m_);
      std::vector<int> counts(n), kept(n);
      ex_.synchronize();
      ex_.to_host(counts.data(), nbr_count_.data(), n * sizeof(int));
      ex_.to_host(kept.data(), near_count_.data(), n * sizeof(int));
      auto grown = [n](int cap, int need) {
        long long want = (long long)(1.25 * need) + 32;
        long long all = 2LL * n;  // every particle and ghost of the state
        want = std::min(want, all);
        want = (want + 31) / 32 * 32;
        return int(std::max<long long>(cap, want));
      };
      Model m = m_;
      m.max_neighbors = grown(m_.max_neighbors, *std::max_element(counts.begin(), counts.end()));
      m.max_near = grown(m_.max_near, *std::max_element(kept.begin(), kept.end()));
      if (m.max_neighbors == m_.max_neighbors && m.max_near == m_.max_near) return false;
      if (bytes_needed(m) - bytes_needed(m_) > bytes_free) return false;
      const double list_bytes = sizeof(int) * (double(list_slots(m)) + double(near_slots(m)));
      if (m_.max_list_bytes > 0.0 && list_bytes > m_.max_list_bytes) return false;
      m_ = m;
      ex_.to_device(model_.data(), &m_, sizeof(Model));
      nbr_.resize(list_slots(m_));
      near_.resize(near_slots(m_));
      invalidate(false);  // every scene sorts and relists
      for (Scene& r : recs)
        if (r.clock.bad == kBadNeighbors) {  // the step was not taken: it is repeated
          r.clock.bad = 0;
          r.clock.bad_step = -1;
        }
      return true;
    }
  }

  // a restored record: its scratch starts clean (the first step sorts and relists)
  static void restored(Scene& r) {
    r.rebuild[0] = r.rebuild[1] = 0;
    r.moved[0] = r.moved[1] = 0;
    r.pending = r.sums;
    r.step_dt = 0.0f;
  }

  long long particles() const { return total_fluid(m_); }
  const Model& model() const { return m_; }
  int graph_slot() const { return parity_; }

  // key the current state when no integration did (first step, replaced state, evaluate)
  void prepare() {
    if (keys_ready_) return;
    ex_.for_each(keys_items(m_), KeysStage{model_.data(), g_, arrays(parity_, parity_ ^ 1)});
    keys_ready_ = true;
  }
  // the buffers now hold the state the step wrote
  void advance(bool integrated) {
    parity_ ^= 1;
    sorted_ = true;
    if (!integrated) keys_ready_ = false;
  }
  // a new state (fields or scalars replaced, or a checkpoint): the next step sorts and relists
  void invalidate(bool order_changed) {
    keys_ready_ = false;
    if (order_changed) sorted_ = false;
  }

  // the step pipeline; parity_ selects the current buffers, the reorder writes the others.
  // A single run and a batch run the same stages, the single run's instantiated without
  // the per-item scene arithmetic
  void enqueue(bool integrate) {
    if (chip_) {
      if (integrate) {
        enqueue_chip(1);
        return;
      }
      // an evaluation by the general stages: the chip path keeps no lists, so every scene
      // sorts and relists (as a new state's first step does)
      ex_.for_each(keys_items(m_), KeysStage{model_.data(), g_, arrays(parity_, parity_ ^ 1)});
    }
    if (m_.n_scenes == 1) enqueue_as<false>(integrate);
    else enqueue_as<true>(integrate);
  }

 private:
  template <bool Many>
  void enqueue_as(bool integrate) {
    const Model& m = m_;
    const int n = total_fluid(m), cap = 2 * n, B = m.n_scenes;
    const int cur = parity_, nxt = parity_ ^ 1;
    Model* md = model_.data();
    Scene* g = g_;
    Arrays a = arrays(cur, nxt);
    // 1. keys come from the last step's integration (or prepare)
    // 2. sort by key (when rebuilding), then reorder into the other buffers (ghosts built
    //    there, cell ranges) or carry the arrays over; a batch sorts the segments of the
    //    scenes that rebuild (or, where a segment is too long for that or the keys need 64
    //    bits, every scene's segments at once, each scene that does not rebuild keeping its
    //    order)
    if constexpr (!Many) {
      ex_.sort_then(a.keys, a.keys_sorted, a.idx, a.perm, cap, key_bits(m), RebuildFlag{md, g},
                    ReorderStage<Many>{md, g, a});
    } else {
      a.key_low_bits = key_low_bits_;
      if (key_low_bits_ && Exec::segment_sort_fits(m.n_fluid)) {
        // each segment (a scene's fluid or ghosts) by its cell keys where its scene rebuilds,
        // the others left as they are, then the reorder (CUDA: a block a segment, one kernel)
        ex_.sort_segments_then(a.keys, a.keys_sorted, a.idx, a.perm, 2 * B, m.n_fluid, key_low_bits_,
                               SegmentRebuilds{md, g}, ReorderStage<Many>{md, g, a});
      } else {
        ex_.for_each(cap, SelectKeysStage{md, g, a});
        if (key_low_bits_)
          ex_.sort_pairs(a.keys, a.keys_sorted, a.idx, a.perm, cap, key_low_bits_ + segment_bits(m));
        else
          ex_.sort_pairs(a.keys64, a.keys64_sorted, a.idx, a.perm, cap, 32 + segment_bits(m));
        ex_.for_each(cap, ReorderStage<Many>{md, g, a});
      }
    }
    ex_.mark(0);
    // from here on the sorted arrays are current
    Arrays s = arrays(nxt, cur);
    CellGridView<D> grid;  // the walks' view (the sorted keys of a single scene: a batch's are its own)
    grid.spec = m.grid;
    if constexpr (!Many) grid.keys32 = s.keys_sorted;
    grid.pos = s.position;
    grid.cell_start = s.cell_start;
    grid.cell_end = s.cell_end;
    grid.n = cap;
    grid.r2 = m.list_radius * m.list_radius;
    grid.tag_end = 2;  // fluid and ghosts
    // the compact index's chunks of the fluid's cells
    if constexpr (Index::compact) {
      CellGridView<D> fluid = grid;
      fluid.n = n;
      compact_.build(ex_, fluid);
    }
    // 3. density and pressure (and the neighbour lists); the container frame of this step
    pair_pass(n, grid, DensityStage<Index, Many>{md, g, u_, s, grid});
    ex_.mark(1);
    // 4. forces, then the reductions and the per-scene update (one kernel where it fits)
    if (integrate) {
      if constexpr (!Many) {
        if (m.lanes == 32 && !Index::compact) {
          ex_.for_each_lanes_reduce_then(n, ForceStage<Index, Many>{md, g, s, grid}, s.items, &g->pending, SumsOp{},
                                         StepSums::identity(), FinalizeStage{md, g});
        } else {
          pair_pass(n, grid, ForceStage<Index, Many>{md, g, s, grid});
          ex_.reduce_then(s.items, n, &g->pending, SumsOp{}, StepSums::identity(), FinalizeStage{md, g});
        }
      } else {
        for_each_pair_lanes(n, ForceStage<Index, Many>{md, g, s, grid});
        reduce_scenes(ex_, B, SceneReduceStage{md, g, s.items, scene_sums_.data()});
        ex_.for_each(B, FinalizeStage{md, g, scene_sums_.data()});
      }
      ex_.mark(2);
      // 5. integrate, then key the next step
      ex_.for_each(keys_items(m), IntegrateStage<Many>{md, g, s});
      ex_.mark(3);
    } else {
      pair_pass(n, grid, ForceStage<Index, Many>{md, g, s, grid});
      if constexpr (!Many) {
        ex_.reduce(s.items, n, &g->sums, SumsOp{}, StepSums::identity());
      } else {
        reduce_scenes(ex_, B, SceneReduceStage{md, g, s.items, scene_sums_.data()});
        ex_.for_each(B, StoreSumsStage{g, scene_sums_.data()});
      }
      ex_.mark(2);
    }
  }

  // a pair stage over the fluid: through the compact grid's chunks, or by lanes
  template <class F>
  void pair_pass(int n, const CellGridView<D>& grid, const F& f) {
    if constexpr (Index::compact) gather_stage_compact(ex_, compact_.view(grid), f);
    else for_each_pair_lanes(n, f);
  }
  // a pair stage with the model's lanes per particle (CUDA: a warp, or groups of 16, 8 or 4
  // lanes of one; the CPU runs one lane whatever the width)
  template <class F>
  void for_each_pair_lanes(int n, const F& f) {
    switch (m_.lanes) {
      case 4: ex_.template for_each_lanes_w<4>(n, f); break;
      case 8: ex_.template for_each_lanes_w<8>(n, f); break;
      case 16: ex_.template for_each_lanes_w<16>(n, f); break;
      default: ex_.for_each_lanes(n, f); break;
    }
  }

 public:
  // the current storage of a field (before the first step: input order, current buffers)
  std::pair<void*, long long> view(const std::string& name, const Scene& rec) {
    const int n = total_fluid(m_);
    const int cur = parity_;
    const int n_ghost = sorted_ ? rec.n_ghost : 0;
    std::pair<void*, long long> stored;
    if (field_view(name, cur, n, stored)) return stored;
    if (m_.n_scenes > 1 && name.rfind("ghost_", 0) == 0)
      throw Error("magic8ball: ghost fields of a batch of scenes are not contiguous; read them per scene (not yet)");
#define CPS_FIELD_VIEW(fname, T, comps, group, ckpt, settable, storage, count) \
  if (name == #fname) return {static_cast<void*>(storage), (long long)(count)};
    CPS_M8_GHOST_FIELDS(CPS_FIELD_VIEW)
#undef CPS_FIELD_VIEW
    throw Error("magic8ball: no field '" + name + "'");
  }

  // replace the fluid's positions or velocities (ids restart at 0..n-1 with positions), or
  // restore a checkpoint's ids; the next step sorts and relists
  void upload(const std::string& name, const void* src, long long count) {
    const int n = total_fluid(m_);
    if (count != n) throw Error("magic8ball: " + name + " needs " + std::to_string(n) + " items");
    const int cur = parity_;
    if (!field_upload(ex_, name, src, n, cur)) throw Error("magic8ball: field '" + name + "' cannot be set");
    if (name == "position") {  // a new state: its particles numbered in order
      std::vector<int> ids(n);
      for (int i = 0; i < n; ++i) ids[i] = i;
      ex_.to_device(fields_.id.cur(cur), ids.data(), n * sizeof(int));
    }
    invalidate(true);
  }

  // a batch's reset cache: every scene's fluid slots and record as they are now, the clock
  // restarted (allocated on first use: 28 bytes a fluid slot)
  void cache_scenes() {
    const int n = total_fluid(m_), B = m_.n_scenes;
    if (cache_rec_.size() == 0) {
      cache_pos_.resize(n);
      cache_vel_.resize(n);
      cache_id_.resize(n);
      cache_rec_.resize(B);
      turns_.resize(B);
    }
    ex_.for_each(n, CacheFluidStage{arrays(parity_, parity_ ^ 1), cache_pos_.data(), cache_vel_.data(), cache_id_.data()});
    ex_.for_each(B, CacheRecordStage{g_, cache_rec_.data()});
  }
  // restore k distinct scenes from the cache, each turned by turn[4q..] and its die by
  // sym[4q..] (w, x, y, z; identity: the cached state exactly); the next step sorts and
  // relists them, the other scenes go on untouched
  void restore_scenes(const int* scenes, int k, const float* turn, const float* sym) {
    if (cache_rec_.size() == 0) throw Error("magic8ball: no cached scenes to restore (cache_scenes first)");
    if (k <= 0) return;
    std::vector<SceneTurn> t(static_cast<size_t>(k));
    for (int q = 0; q < k; ++q)
      t[q] = SceneTurn{Quat{turn[4 * q], turn[4 * q + 1], turn[4 * q + 2], turn[4 * q + 3]},
                       Quat{sym[4 * q], sym[4 * q + 1], sym[4 * q + 2], sym[4 * q + 3]}, scenes[q]};
    ex_.to_device(turns_.data(), t.data(), sizeof(SceneTurn) * t.size());
    ex_.for_each(k * m_.n_fluid, RestoreFluidStage{model_.data(), cache_rec_.data(), turns_.data(),
                                                   arrays(parity_, parity_ ^ 1), cache_pos_.data(),
                                                   cache_vel_.data(), cache_id_.data()});
    ex_.for_each(k, RestoreRecordStage{g_, cache_rec_.data(), turns_.data()});
  }
  // the per-scene observations, written into arrays of their own (valid until the next call)
  std::vector<SceneArray> observe() {
    const int B = m_.n_scenes;
    if (obs_f_.size() == 0) {
      obs_f_.resize(13 * size_t(B));
      obs_i_.resize(3 * size_t(B));
      obs_t_.resize(B);
    }
    float* f = obs_f_.data();
    int* i = obs_i_.data();
    ex_.for_each(B, ObserveStage{g_, f, f + 3 * B, f + 7 * B, f + 10 * B, i, i + B, i + 2 * B, obs_t_.data()});
    return {{"die_position", f, DType::F32, 3},           {"die_orientation", f + 3 * B, DType::F32, 4},
            {"die_velocity", f + 7 * B, DType::F32, 3},   {"die_angular_velocity", f + 10 * B, DType::F32, 3},
            {"answer_face", i, DType::I32, 1},            {"time", obs_t_.data(), DType::F64, 1},
            {"done", i + B, DType::I32, 1},               {"bad", i + 2 * B, DType::I32, 1}};
  }

  // named values derived from the record
  std::vector<std::pair<std::string, double>> derived(const Scene& r) const {
    Vec3 w = qrotate(r.die.q, r.die.w_body);  // the die's angular velocity in the container frame
    return {{"answer_face", double(window_face(r.die.q))},
            {"chosen_dt", double(sums_dt(m_, r.phys, r.sums, r.die))},  // what a step would choose from these sums
            {"vmax", std::sqrt(double(r.sums.vmax2))},
            {"amax", std::sqrt(double(r.sums.amax2))},
            {"mean_density", double(r.sums.rho_sum) / double(r.phys.n_active)},
            {"max_neighbors", double(m_.max_neighbors)},  // the list capacities now (they grow)
            {"max_near", double(m_.max_near)},
            {"lanes", double(m_.lanes)},  // CUDA lanes per particle in the pair stages
            {"list_scan", double(m_.list_scan)},  // lists rebuilt by a scan of the scene (1) or the cells (0)
            {"chip_path", chip_ ? 1.0 : 0.0},     // the steps run on chip (chip.h: 1) or the general path (0)
            {"chip_shared_bytes", double(chip_bytes(m_))},  // the shared memory a scene's block needs on chip
            {"die_angular_velocity_x", double(w[0])},
            {"die_angular_velocity_y", double(w[1])},
            {"die_angular_velocity_z", double(w[2])}};
  }

 private:
  Arrays arrays(int cur, int /* nxt: cur ^ 1 */) {
    Arrays a;
    fields_.fill(a, cur);  // (the other buffers: nxt = cur ^ 1)
    a.terms = terms_.data();
    a.keys = keys_.data();
    a.keys_sorted = keys_sorted_.data();
    a.idx = idx_.data();
    a.perm = perm_.data();
    a.ghost_of = ghost_of_.data();
    a.ghost_slot = ghost_slot_.data();
    a.x_build = x_build_.data();
    a.xsph = xsph_.data();
    a.items = items_.data();
    a.nbr = nbr_.data();
    a.nbr_count = nbr_count_.data();
    a.near = near_.data();
    a.near_count = near_count_.data();
    a.cell_start = cells_start_.data();
    a.cell_end = cells_end_.data();
    a.keys64 = keys64_.data();
    a.keys64_sorted = keys64_sorted_.data();
    a.key_low_bits = 0;
    return a;
  }

  Exec& ex_;
  Model m_;
  Scene* g_;
  const Control* u_;
  Buf<Model> model_;
  Buf<ForceTerms> terms_;
  Buf<uint32_t> keys_, keys_sorted_;
  Buf<int> idx_, perm_, ghost_of_, ghost_slot_;
  Buf<Vec3> x_build_;
  Buf<Vec3> xsph_;
  Buf<StepSums> items_;
  Buf<int> nbr_, nbr_count_, near_, near_count_;
  Buf<uint32_t> cells_start_, cells_end_;
  Buf<uint64_t> keys64_, keys64_sorted_;  // a batch's segmented sort (64-bit keys)
  int key_low_bits_ = 0;                  // a batch's keys are 32-bit (narrow_key_bits), or 64-bit (0)
  CompactGrid<D, Exec> compact_;         // the compact index's chunks
  Buf<StepSums> scene_sums_;              // a batch's per-scene reductions
  Buf<Vec3> cache_pos_, cache_vel_;       // a batch's reset cache (cache_scenes)
  Buf<int> cache_id_;
  Buf<Scene> cache_rec_;
  Buf<SceneTurn> turns_;                  // the scenes a restore_scenes call restores
  Buf<float> obs_f_;                      // observations (observe)
  Buf<int> obs_i_;
  Buf<double> obs_t_;
  int parity_ = 0;
  bool sorted_ = false;
  bool keys_ready_ = false;  // the last step's integration keyed the current state
  bool chip_ = false;        // the steps run on chip (choose_chip)
};

}  // namespace cps::m8
