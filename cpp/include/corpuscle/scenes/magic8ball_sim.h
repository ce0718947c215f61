// Host orchestration of the Magic 8-Ball step, written once for every backend (Exec).
// Exec supplies buffers, parallel_for (for_each / single), sort, reduce, copies and timing.
#pragma once
#include <algorithm>
#include <cmath>
#include <limits>

#include "corpuscle/core/error.h"
#include "corpuscle/scenes/magic8ball_api.h"

namespace cps::m8 {

// names of the pipeline stages, in order (for profiles)
inline const char* const kStageNames[] = {"sort+reorder", "density", "forces+reduce+finalize",
                                          "integrate+keys"};
constexpr int kNumStages = 4;

template <class Exec>
class SimImpl final : public Sim {
 public:
  static constexpr int kPollBatch = 16;  // steps between scalar snapshots on a device
  template <class T> using Buf = typename Exec::template Buffer<T>;

  // the bytes the buffers below take (the sort's scratch included), for a check before
  // anything is allocated
  static double bytes_needed(const Model& m) {
    const double n = m.n_fluid, cap = 2.0 * n;
    const double per_slot = 2 * 2 * sizeof(Vec3) + 2 * sizeof(int) + 2 * sizeof(float) + 2 * sizeof(uint32_t) +
                            2 * sizeof(int);
    const double per_fluid = 2 * sizeof(int) + 3 * sizeof(Vec3) + sizeof(StepSums) + 2 * sizeof(int) +
                             sizeof(int) * (double(m.max_neighbors) + double(m.max_near));
    const double cells = 2.0 * 2.0 * double(m.grid.ncells) * sizeof(uint32_t);
    const double sort_scratch = cap * (sizeof(uint32_t) + sizeof(int)) * 2.0;
    return cap * per_slot + n * per_fluid + cells + sort_scratch;
  }

  SimImpl(Exec ex, const Model& m, const InitialState& s) : ex_(std::move(ex)), m_(m) {
    const int n = m.n_fluid, cap = 2 * n;
    if (n <= 0) throw Error("magic8ball: no fluid particles");
    model_.resize(1);
    ex_.to_device(model_.data(), &m_, sizeof(Model));
    g_.resize(1);
    for (int p = 0; p < 2; ++p) {
      pos_[p].resize(cap);
      vel_[p].resize(cap);
      id_[p].resize(cap);
    }
    rho_.resize(cap);
    prs_.resize(cap);
    keys_.resize(cap);
    keys_sorted_.resize(cap);
    idx_.resize(cap);
    perm_.resize(cap);
    ghost_of_.resize(n);
    ghost_slot_.resize(n);
    x_build_.resize(n);
    acc_.resize(n);
    xsph_.resize(n);
    items_.resize(n);
    nbr_.resize(size_t(n) * size_t(m.max_neighbors));
    nbr_count_.resize(n);
    near_.resize(size_t(n) * size_t(m.max_near));
    near_count_.resize(n);
    cells_start_.resize(2 * size_t(m.grid.ncells));
    cells_end_.resize(2 * size_t(m.grid.ncells));
    // initial globals
    Globals g{};
    g.time = 0.0;
    g.end_time = std::numeric_limits<double>::infinity();
    g.step = 0;
    g.dt = 0.0f;
    g.bad_step = -1;
    g.die = s.die;
    g.shell_q = Quat::identity();
    g.shell_omega = Vec3::zero();
    g.user_acc = g.user_torque = Vec3::zero();
    g.sums = g.pending = StepSums::identity();
    ex_.to_device(g_.data(), &g, sizeof(Globals));
    set_particles(s.pos, s.vel);
  }

  const char* backend() const override { return ex_.name(); }
  bool on_device() const override { return Exec::on_device; }
  const Model& model() const override { return m_; }

  void set_particles(const std::vector<Vec3>& pos, const std::vector<Vec3>& vel) override {
    const int n = m_.n_fluid;
    if (int(pos.size()) != n || int(vel.size()) != n)
      throw Error("magic8ball: expected " + std::to_string(n) + " positions and velocities");
    std::vector<int> ids(n);
    for (int i = 0; i < n; ++i) ids[i] = i;
    ex_.to_device(pos_[parity_].data(), pos.data(), n * sizeof(Vec3));
    ex_.to_device(vel_[parity_].data(), vel.data(), n * sizeof(Vec3));
    ex_.to_device(id_[parity_].data(), ids.data(), n * sizeof(int));
    sorted_ = false;
    keys_ready_ = false;
  }

  Globals globals() override {
    Globals g;
    ex_.to_host(&g, g_.data(), sizeof(Globals));
    return g;
  }
  void set_globals(const Globals& g) override {
    ex_.to_device(g_.data(), &g, sizeof(Globals));
    keys_ready_ = false;  // the next step re-evaluates its frame from the new control
  }

  // Steps are enqueued in batches; after each batch a snapshot of the scalars is copied back
  // (asynchronously on a device), and the snapshot of the batch before is read before the
  // next one is enqueued, so the device never waits for the host. A scene that is done or
  // unsound makes its steps no-ops on the device, and the host stops enqueuing once a
  // snapshot shows it: at most two batches of no-op steps follow the last real one.
  long long step(long long n, const StopCheck& stop) override {
    if (n <= 0) return 0;
    const Globals g0 = globals();
    if (halted(&g0)) return 0;
    const long long first = g0.step;
    const int batch = Exec::on_device ? kPollBatch : 1;
    int slot = 0;
    bool pending = false;
    for (long long k = 0; k < n;) {
      const long long b = std::min<long long>(batch, n - k);
      for (long long j = 0; j < b; ++j) {
        ensure_keys();
        ex_.launch_step(parity_, [&] { enqueue_step(true); });
        parity_ ^= 1;
      }
      sorted_ = true;
      k += b;
      ex_.poll_begin(slot, g_.data(), sizeof(Globals));
      if (pending || !Exec::on_device) {
        const int seen = Exec::on_device ? slot ^ 1 : slot;
        if (halted(static_cast<const Globals*>(ex_.poll_wait(seen)))) break;
      }
      pending = true;
      slot ^= 1;
      if (stop && stop()) break;
    }
    return globals().step - first;
  }

  void evaluate() override {
    // the same stages as a step, without integration; dt is chosen from these forces.
    // A finished or unsound run is evaluated too: its flags are lifted for the evaluation
    Globals g0 = globals();
    if (halted(&g0)) {
      Globals g = g0;
      g.done = g.bad = 0;
      ex_.to_device(g_.data(), &g, sizeof(Globals));
    }
    ensure_keys();
    ex_.launch_step(-1, [&] { enqueue_step(false); });
    keys_ready_ = false;
    parity_ ^= 1;
    sorted_ = true;
    if (halted(&g0)) {
      Globals g = globals();
      g.done = g0.done;
      g.bad = g0.bad;
      ex_.to_device(g_.data(), &g, sizeof(Globals));
    }
    ex_.synchronize();
  }

  double bench(long long n) override {
    step(1, {});  // capture / warm the step outside the timing
    ex_.synchronize();
    return ex_.time([&] { step(n, {}); });
  }

  // the state the next step reads, in the current order: the fluid arrays and the scalars.
  // The next step sorts and relists (as a restored state's first step does), so a run that
  // checkpoints and the run resumed from that checkpoint take identical steps
  CheckpointState checkpoint() override {
    const int n = m_.n_fluid;
    CheckpointState c;
    c.pos.resize(n);
    c.vel.resize(n);
    c.id.resize(n);
    ex_.synchronize();
    ex_.to_host(c.pos.data(), pos_[parity_].data(), n * sizeof(Vec3));
    ex_.to_host(c.vel.data(), vel_[parity_].data(), n * sizeof(Vec3));
    ex_.to_host(c.id.data(), id_[parity_].data(), n * sizeof(int));
    c.g = globals();
    keys_ready_ = false;
    return c;
  }

  void restore(const CheckpointState& c) override {
    const int n = m_.n_fluid;
    if (int(c.pos.size()) != n || int(c.vel.size()) != n || int(c.id.size()) != n)
      throw Error("magic8ball: the checkpoint holds " + std::to_string(c.pos.size()) + " particles, the model " +
                  std::to_string(n));
    ex_.to_device(pos_[parity_].data(), c.pos.data(), n * sizeof(Vec3));
    ex_.to_device(vel_[parity_].data(), c.vel.data(), n * sizeof(Vec3));
    ex_.to_device(id_[parity_].data(), c.id.data(), n * sizeof(int));
    ex_.to_device(g_.data(), &c.g, sizeof(Globals));
    sorted_ = false;
    keys_ready_ = false;
  }

  std::vector<std::pair<std::string, double>> profile(long long n) override {
    ex_.synchronize();
    ex_.profile_begin();
    for (long long k = 0; k < n; ++k) {
      ensure_keys();
      enqueue_step(true);
      parity_ ^= 1;
    }
    auto ms = ex_.profile_end();
    std::vector<std::pair<std::string, double>> out;
    for (int s = 0; s < kNumStages && s < int(ms.size()); ++s) out.emplace_back(kStageNames[s], ms[s] / double(n));
    return out;
  }

  void download(Field f, void* dst) override {
    auto [p, count] = view(f);
    ex_.synchronize();
    ex_.to_host(dst, p, size_t(count) * field_bytes(f));
  }

  std::pair<void*, int> view(Field f) override {
    // before the first step the arrays are in input order in the current buffers
    const int n = m_.n_fluid;
    const int cur = parity_;
    switch (f) {
      case Field::Position: return {pos_[cur].data(), n};
      case Field::Velocity: return {vel_[cur].data(), n};
      case Field::Density: return {rho_.data(), n};
      case Field::Pressure: return {prs_.data(), n};
      case Field::Id: return {id_[cur].data(), n};
      case Field::Acceleration: return {acc_.data(), n};
      case Field::GhostPosition: return {pos_[cur].data() + n, sorted_ ? globals().n_ghost : 0};
      case Field::GhostVelocity: return {vel_[cur].data() + n, sorted_ ? globals().n_ghost : 0};
    }
    return {nullptr, 0};
  }

  static size_t field_bytes(Field f) {
    switch (f) {
      case Field::Density:
      case Field::Pressure: return sizeof(float);
      case Field::Id: return sizeof(int);
      default: return sizeof(Vec3);
    }
  }

 private:
  // key the current state when no integration did (first step, replaced state, evaluate)
  void ensure_keys() {
    if (keys_ready_) return;
    ex_.for_each(keys_items(m_), KeysStage{model_.data(), g_.data(), arrays(parity_, parity_ ^ 1)});
    keys_ready_ = true;
  }

  // the step pipeline; parity_ selects the current buffers, the reorder writes the others
  void enqueue_step(bool integrate) {
    const Model& m = m_;
    const int n = m.n_fluid, cap = 2 * n;
    const int cur = parity_, nxt = parity_ ^ 1;
    Model* md = model_.data();
    Globals* g = g_.data();
    Arrays a = arrays(cur, nxt);
    // 1. keys come from the last step's integration (or ensure_keys)
    // 2. sort by key (when rebuilding), then reorder into the other buffers (ghosts built
    //    there, cell ranges) or carry the arrays over
    ex_.sort_then(a.keys, a.keys_sorted, a.idx, a.perm, cap, m.grid.key_bits(), RebuildFlag{g},
                  ReorderStage{md, g, a});
    ex_.mark(0);
    // from here on the sorted arrays are current
    Arrays s = arrays(nxt, cur);
    GridView<D> grid{m.grid, s.pos, s.cell_start, s.cell_end};
    // 3. density and pressure (and the neighbour lists)
    ex_.for_each_lanes(n, DensityStage{md, g, s, grid});
    ex_.mark(1);
    // 4. forces, then the reductions and the per-scene update (one kernel where it fits)
    if (integrate) {
      ex_.for_each_lanes_reduce_then(n, ForceStage{md, g, s, grid}, s.items, &g->pending, SumsOp{},
                                     StepSums::identity(), FinalizeStage{md, g});
      ex_.mark(2);
      // 5. integrate, then key the next step
      ex_.for_each(keys_items(m), IntegrateStage{md, g, s});
      ex_.mark(3);
    } else {
      ex_.for_each_lanes(n, ForceStage{md, g, s, grid});
      ex_.reduce(s.items, n, &g->sums, SumsOp{}, StepSums::identity());
      ex_.mark(2);
    }
  }

  Arrays arrays(int cur, int nxt) {
    Arrays a;
    a.pos = pos_[cur].data();
    a.vel = vel_[cur].data();
    a.pos_alt = pos_[nxt].data();
    a.vel_alt = vel_[nxt].data();
    a.id = id_[cur].data();
    a.id_alt = id_[nxt].data();
    a.rho = rho_.data();
    a.prs = prs_.data();
    a.keys = keys_.data();
    a.keys_sorted = keys_sorted_.data();
    a.idx = idx_.data();
    a.perm = perm_.data();
    a.ghost_of = ghost_of_.data();
    a.ghost_slot = ghost_slot_.data();
    a.x_build = x_build_.data();
    a.acc = acc_.data();
    a.xsph = xsph_.data();
    a.items = items_.data();
    a.nbr = nbr_.data();
    a.nbr_count = nbr_count_.data();
    a.near = near_.data();
    a.near_count = near_count_.data();
    a.cell_start = cells_start_.data();
    a.cell_end = cells_end_.data();
    return a;
  }

  Exec ex_;
  Model m_;
  Buf<Model> model_;
  Buf<Globals> g_;
  Buf<Vec3> pos_[2], vel_[2];
  Buf<int> id_[2];
  Buf<float> rho_, prs_;
  Buf<uint32_t> keys_, keys_sorted_;
  Buf<int> idx_, perm_, ghost_of_, ghost_slot_;
  Buf<Vec3> x_build_;
  Buf<Vec3> acc_, xsph_;
  Buf<StepSums> items_;
  Buf<int> nbr_, nbr_count_, near_, near_count_;
  Buf<uint32_t> cells_start_, cells_end_;
  int parity_ = 0;
  bool sorted_ = false;
  bool keys_ready_ = false;  // the last step's integration keyed the current state
};

}  // namespace cps::m8
