// SimImpl<Exec, Pipeline>: the engine's side of every simulation, written once. It owns the
// backend (Exec: buffers, launches, graphs, clocks), the per-scene record and the control
// buffer, and runs a kind's Pipeline (its buffers and the order of its stages for a step).
//
// A step is Pipeline::prepare (key a new state), Exec::launch_step (the first steps eagerly,
// then a captured CUDA graph per parity) over Pipeline::enqueue, and Pipeline::advance.
// Steps run in batches; after each batch one snapshot of the record is copied back
// (asynchronously on a device) and the snapshot of the batch before is read, so the device
// never waits for the host. A scene that is done or unsound makes its steps no-ops on the
// device, and the host stops enqueuing once a snapshot shows it.
#pragma once
#include <algorithm>
#include <cstring>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "corpuscle/core/copies.h"
#include "corpuscle/core/error.h"
#include "corpuscle/sim/registry.h"
#include "corpuscle/sim/sim.h"

namespace cps {

// whether a kind's pipeline has a batch's reset cache, restore and observations
// (cache_scenes, restore_scenes, observe; the CUDA build is C++17: no concepts)
template <class P, class = void>
struct has_batch_api : std::false_type {};
template <class P>
struct has_batch_api<P, std::void_t<decltype(std::declval<P&>().cache_scenes())>> : std::true_type {};
// whether a kind's pipeline runs a scene split over ranks (set_counts, enqueue_half, get_slots, ...)
template <class P, class = void>
struct has_ranks_api : std::false_type {};
template <class P>
struct has_ranks_api<P, std::void_t<decltype(std::declval<P&>().enqueue_half(0, nullptr, 0))>> : std::true_type {};
// whether a kind's pipeline can take several steps in one launch (chip_steps, enqueue_chip:
// the 8-ball's chip path)
template <class P, class = void>
struct has_chip_steps : std::false_type {};
template <class P>
struct has_chip_steps<P, std::void_t<decltype(std::declval<P&>().chip_steps(1LL))>> : std::true_type {};

template <class Exec, class P>
class SimImpl final : public Sim {
 public:
  template <class T> using Buf = typename Exec::template Buffer<T>;
  using Record = typename P::SceneRecord;
  using Control = typename P::ControlRecord;
  static constexpr int kPollBatch = 32;  // steps between record snapshots on a device

  // `initial` holds one record per scene of the state (a single run: one)
  template <class Model>
  SimImpl(Exec ex, const Model& m, const std::vector<Record>& initial, int device)
      : ex_(std::move(ex)), device_(device), record_(alloc_record(ex_, initial)),
        control_(alloc_control(initial.size())), p_(ex_, m, record_.data(), control_.data()),
        fields_(P::field_table()), scalars_(P::scalar_table()), controls_(P::control_table()) {
    if (int(initial.size()) != p_.scenes()) throw Error(std::string(P::kind) + ": one initial record per scene");
    rec_ = initial;
    rec_valid_ = true;
    ctl_.assign(initial.size(), Control{});
    std::memset(ctl_.data(), 0, sizeof(Control) * ctl_.size());
  }

  const char* kind() const override { return P::kind; }
  const char* backend() const override { return ex_.name(); }
  const char* index() const override { return P::index_name; }
  bool on_device() const override { return Exec::on_device; }
  int device() const override { return device_; }
  long long particles() const override { return p_.particles(); }
  int scenes() const override { return p_.scenes(); }
  const std::vector<FieldInfo>& fields() const override { return fields_; }
  const std::vector<ScalarInfo>& scalars() const override { return scalars_; }
  const std::vector<ScalarInfo>& controls() const override { return controls_; }
  P& pipeline() { return p_; }

  long long step(long long n, const StopCheck& stop) override {
    if (n <= 0) return 0;
    if (all_halted(records().data()) && !recover()) return 0;
    std::vector<long long> first;
    for (const Record& r : rec_) first.push_back(r.clock.step);
    bool multi = false;  // launches of several steps: batches of them on the CPU too
    if constexpr (has_chip_steps<P>::value) multi = p_.chip_steps(2) > 1;
    const int batch = Exec::on_device || multi ? kPollBatch : 1;
    flush_control();
    bool stopped = false;
    for (long long k = 0; k < n && !stopped;) {
      int slot = 0;
      bool pending = false;
      rec_valid_ = false;
      while (k < n) {
        const long long b = std::min<long long>(batch, n - k);
        for (long long j = 0; j < b;) {
          p_.prepare();
          int steps = 0;  // several steps in one launch (a pipeline's chip path), or one
          if constexpr (has_chip_steps<P>::value) steps = p_.chip_steps(b - j);
          if (steps > 0) {
            if constexpr (has_chip_steps<P>::value) p_.enqueue_chip(steps);
          } else {
            ex_.launch_step(p_.graph_slot(), [&] { p_.enqueue(true); });
            steps = 1;
          }
          p_.advance(true);
          j += steps;
        }
        k += b;
        ex_.poll_begin(slot, record_.data(), sizeof(Record) * rec_.size());
        if (pending || !Exec::on_device) {
          const int seen = Exec::on_device ? slot ^ 1 : slot;
          if (all_halted(static_cast<const Record*>(ex_.poll_wait(seen)))) break;
        }
        pending = true;
        slot ^= 1;
        if (stop && stop()) {
          stopped = true;
          break;
        }
      }
      // a fixed-capacity buffer that overflowed stopped its scene before the step was taken:
      // the pipeline grows it when it can, and the steps go on (the step is repeated)
      if (stopped || !all_halted(records().data()) || !recover() || all_halted(rec_.data())) break;
      // the budget counts steps taken, not the no-ops launched after the fault
      k = 0;
      for (size_t q = 0; q < rec_.size(); ++q) k = std::max(k, rec_[q].clock.step - first[q]);
    }
    // the steps taken: those of the scene that took the most
    long long taken = 0;
    const auto& r = records();
    for (size_t k = 0; k < r.size(); ++k) taken = std::max(taken, r[k].clock.step - first[k]);
    return taken;
  }

  void evaluate() override {
    // the same stages as a step, without integration. A finished or unsound run is
    // evaluated too: its flags are lifted for the evaluation
    const std::vector<Record> r0 = records();
    bool lift = false;
    for (const Record& r : r0) lift = lift || halted(r);
    if (lift) {
      std::vector<Record> r = r0;
      for (Record& x : r) x.clock.done = x.clock.bad = 0;
      write_records(r);
    }
    flush_control();
    for (int attempt = 0;; ++attempt) {
      p_.prepare();
      ex_.launch_step(-1, [&] { p_.enqueue(false); });
      p_.advance(false);
      rec_valid_ = false;
      // an overflowing buffer grows and the evaluation is repeated (a few times at most)
      if (attempt == 3 || !recover()) break;
    }
    if (lift) {
      std::vector<Record> r = records();
      for (size_t k = 0; k < r.size(); ++k) {
        r[k].clock.done = r0[k].clock.done;
        r[k].clock.bad = r0[k].clock.bad;
      }
      write_records(r);
    }
    ex_.synchronize();
  }

  void set_end_time(double t) override {
    std::vector<Record> r = records();
    for (Record& x : r) {
      x.clock.end_time = t;
      x.clock.done = x.clock.time >= t ? 1 : 0;
    }
    write_records(r);
  }

  const unsigned char* scene_record(int scene) override {
    return reinterpret_cast<const unsigned char*>(&records().at(check_scene(scene)));
  }

  size_t record_size() const override { return sizeof(Record); }
  size_t control_size() const override { return sizeof(Control); }

  void set_scalar(const std::string& name, const void* bytes, int scene) override {
    const ScalarInfo& s = find(scalars_, name, "scalar");
    std::vector<Record> r = records();
    std::memcpy(reinterpret_cast<char*>(&r.at(check_scene(scene))) + s.offset, bytes,
                dtype_size(s.dtype) * size_t(s.count));
    write_records(r);
  }

  // staged on the host; the next step (or evaluation) uploads it once, asynchronously and
  // ordered before its first stage
  // scene -1: every scene
  void set_control(const std::string& name, const void* bytes, int scene) override {
    const ScalarInfo& s = find(controls_, name, "control");
    for (int k = 0; k < scenes(); ++k) {
      if (scene >= 0 && k != check_scene(scene)) continue;
      std::memcpy(reinterpret_cast<char*>(&ctl_[k]) + s.offset, bytes, dtype_size(s.dtype) * size_t(s.count));
    }
    ctl_dirty_ = true;
  }

  std::vector<std::pair<std::string, double>> derived(int scene) override {
    return p_.derived(records().at(check_scene(scene)));
  }

  std::pair<void*, long long> view(const std::string& name) override {
    find(fields_, name, "field");
    return p_.view(name, records()[0]);
  }
  void download(const std::string& name, void* dst) override {
    const FieldInfo& f = find(fields_, name, "field");
    auto [ptr, count] = p_.view(name, records()[0]);
    ex_.synchronize();
    if (count > 0) ex_.to_host(dst, ptr, size_t(count) * size_t(f.components) * dtype_size(f.dtype));
  }
  void download_many(const std::vector<std::string>& names, const std::vector<void*>& dst) override {
    if (names.size() != dst.size()) throw Error("download_many: one destination per field");
    std::vector<HostCopy> copies;
    for (size_t k = 0; k < names.size(); ++k) {
      const FieldInfo& f = find(fields_, names[k], "field");
      auto [ptr, count] = p_.view(names[k], records()[0]);
      copies.push_back({dst[k], ptr, size_t(count) * size_t(f.components) * dtype_size(f.dtype)});
    }
    ex_.to_host_many(copies);
  }
  void upload(const std::string& name, const void* src, long long count) override {
    const FieldInfo& f = find(fields_, name, "field");
    if (!f.settable && !f.checkpointed) throw Error(std::string(P::kind) + ": field '" + name + "' cannot be set");
    p_.upload(name, src, count);
  }

  size_t packed_size() const override {
    size_t bytes = 0;
    for (const FieldInfo& f : fields_)
      if (packed(f)) bytes += item_size(f);
    return bytes;
  }
  void pack(long long slot, void* record) override {
    unsigned char* out = static_cast<unsigned char*>(record);
    ex_.synchronize();
    for (const FieldInfo& f : fields_) {
      if (!packed(f)) continue;
      ex_.to_host(out, packed_item(f, slot), item_size(f));
      out += item_size(f);
    }
  }
  void unpack(long long slot, const void* record) override {
    const unsigned char* in = static_cast<const unsigned char*>(record);
    ex_.synchronize();
    for (const FieldInfo& f : fields_) {
      if (!packed(f)) continue;
      ex_.to_device(packed_item(f, slot), in, item_size(f));
      in += item_size(f);
    }
    p_.invalidate(true);  // the next step sorts and relists
  }

  Snapshot checkpoint() override {
    Snapshot s;
    for (const FieldInfo& f : fields_) {
      if (!f.checkpointed) continue;
      auto [ptr, count] = p_.view(f.name, records()[0]);
      std::vector<unsigned char> bytes(size_t(count) * size_t(f.components) * dtype_size(f.dtype));
      ex_.synchronize();
      if (!bytes.empty()) ex_.to_host(bytes.data(), ptr, bytes.size());
      s.fields.emplace_back(f.name, std::move(bytes));
    }
    const auto& r = records();
    const unsigned char* rb = reinterpret_cast<const unsigned char*>(r.data());
    s.scene.assign(rb, rb + sizeof(Record) * r.size());
    const unsigned char* u = reinterpret_cast<const unsigned char*>(ctl_.data());
    s.control.assign(u, u + sizeof(Control) * ctl_.size());
    p_.invalidate(false);  // the next step sorts and relists, as a restored state's does
    return s;
  }

  void restore(const Snapshot& s) override {
    if (s.scene.size() != sizeof(Record) * rec_.size())
      throw Error(std::string(P::kind) + ": the checkpoint's records have the wrong size");
    for (const auto& [name, bytes] : s.fields) {
      const FieldInfo& f = find(fields_, name, "field");
      const size_t item = size_t(f.components) * dtype_size(f.dtype);
      p_.upload(name, bytes.data(), (long long)(bytes.size() / item));
    }
    std::vector<Record> r(rec_.size());
    std::memcpy(r.data(), s.scene.data(), sizeof(Record) * r.size());
    for (Record& x : r) {
      x.clock.done = x.clock.time >= x.clock.end_time ? 1 : 0;
      x.clock.bad = 0;
      x.clock.bad_step = -1;
      P::restored(x);
    }
    write_records(r);
    if (!s.control.empty()) {
      if (s.control.size() != sizeof(Control) * ctl_.size())
        throw Error(std::string(P::kind) + ": the checkpoint's control has the wrong size");
      std::memcpy(ctl_.data(), s.control.data(), sizeof(Control) * ctl_.size());
      ctl_dirty_ = true;
    }
    p_.invalidate(true);
  }

  void set_controls(const float* values, int cols) override {
    int total = 0;
    for (const ScalarInfo& c : controls_) {
      if (c.dtype != DType::F32) throw Error(std::string(P::kind) + ": only float controls are set by array");
      total += c.count;
    }
    if (cols != total)
      throw Error(std::string(P::kind) + ": the controls of every scene need " + std::to_string(total) +
                  " values a scene, got " + std::to_string(cols));
    for (int k = 0; k < scenes(); ++k) {
      int col = 0;
      for (const ScalarInfo& c : controls_) {
        std::memcpy(reinterpret_cast<char*>(&ctl_[k]) + c.offset, values + size_t(k) * cols + col,
                    sizeof(float) * size_t(c.count));
        col += c.count;
      }
    }
    ctl_dirty_ = true;
  }

  void set_end_times(const double* t, bool relative) override {
    std::vector<Record> r = records();
    for (size_t k = 0; k < r.size(); ++k) {
      Record& x = r[k];
      x.clock.end_time = relative ? x.clock.time + t[k] : t[k];
      x.clock.done = x.clock.time >= x.clock.end_time ? 1 : 0;
    }
    write_records(r);
  }

  void cache_scenes() override {
    if constexpr (has_batch_api<P>::value) {
      p_.cache_scenes();
      ex_.synchronize();
    } else {
      unsupported("reset cache");
    }
  }

  void restore_scenes(const int* scenes_, int k, const float* turn, const float* sym) override {
    if constexpr (has_batch_api<P>::value) {
      std::vector<char> seen(size_t(scenes()), 0);
      for (int q = 0; q < k; ++q) {
        check_scene(scenes_[q]);
        if (seen[size_t(scenes_[q])]++)
          throw Error(std::string(P::kind) + ": scene " + std::to_string(scenes_[q]) + " is restored twice");
      }
      p_.restore_scenes(scenes_, k, turn, sym);
      ex_.synchronize();
      rec_valid_ = false;
    } else {
      unsupported("reset cache");
    }
  }

  std::vector<SceneArray> observe() override {
    if constexpr (has_batch_api<P>::value) {
      auto out = p_.observe();
      ex_.synchronize();  // the arrays are read by other streams and libraries
      return out;
    } else {
      unsupported("observations");
      return {};
    }
  }

  void copy_to_host(void* dst, const void* src, size_t bytes) override {
    ex_.synchronize();
    ex_.to_host(dst, src, bytes);
  }

  void set_counts(long long fluid, long long wall, long long id_bound) override {
    if constexpr (has_ranks_api<P>::value) {
      if (fluid > (1LL << 30) || wall > (1LL << 30)) throw Error(std::string(P::kind) + ": counts out of range");
      p_.set_counts(int(fluid), int(wall), id_bound);
      ex_.reset_graphs();  // (they name the old buffers)
    } else {
      no_ranks();
    }
  }
  size_t step_sums_size() const override {
    if constexpr (has_ranks_api<P>::value) return P::step_sums_size();
    else no_ranks();
  }
  // phase 0: prepare and the step to its reductions; phase 1: the rest, then the parity
  // advances (eagerly: no graphs, the host reads and writes between the halves)
  bool step_half(int phase, void* sums, int ranks, long long* flags) override {
    if constexpr (has_ranks_api<P>::value) {
      if (phase == 2) return recover();
      flush_control();
      if (phase == 0) p_.prepare();
      ex_.launch_step(-1, [&] { p_.enqueue_half(phase, sums, ranks); });
      if (phase == 1) p_.advance(true);
      ex_.synchronize();
      rec_valid_ = false;
      p_.rank_flags(records()[0], flags);
      return true;
    } else {
      no_ranks();
    }
  }
  long long slots() const override {
    if constexpr (has_ranks_api<P>::value) return p_.slots();
    else no_ranks();
  }
  void get_slots(const std::string& field, const int* slots, long long count, void* out) override {
    if constexpr (has_ranks_api<P>::value) p_.get_slots(field, slots, count, out);
    else no_ranks();
  }
  void set_slots(const std::string& field, const int* slots, long long count, const void* in) override {
    if constexpr (has_ranks_api<P>::value) {
      p_.set_slots(field, slots, count, in);
      ex_.synchronize();
    } else {
      no_ranks();
    }
  }

  double bench(long long n, const StopCheck& stop) override {
    step(1, {});  // capture / warm the step outside the timing
    ex_.synchronize();
    double s = ex_.time([&] { step(n, stop); });
    return s;
  }

  std::vector<std::pair<std::string, double>> profile(long long n, const StopCheck& stop) override {
    flush_control();
    ex_.synchronize();
    ex_.profile_begin();
    for (long long k = 0; k < n; ++k) {
      if (stop && stop()) break;
      p_.prepare();
      p_.enqueue(true);
      p_.advance(true);
    }
    auto ms = ex_.profile_end();
    rec_valid_ = false;
    std::vector<std::pair<std::string, double>> out;
    for (int s = 0; s < P::kNumStages && s < int(ms.size()); ++s) out.emplace_back(P::stage_name(s), ms[s] / double(n));
    return out;
  }

 private:
  static bool halted(const Record& r) { return r.clock.done != 0 || r.clock.bad != 0; }
  static bool packed(const FieldInfo& f) { return f.checkpointed && f.group == "fluid"; }
  static size_t item_size(const FieldInfo& f) { return size_t(f.components) * dtype_size(f.dtype); }
  // the item of slot `slot` of a packed field, in the backend's memory
  unsigned char* packed_item(const FieldInfo& f, long long slot) {
    auto [ptr, count] = p_.view(f.name, records()[0]);
    if (slot < 0 || slot >= count)
      throw Error(std::string(P::kind) + ": slot " + std::to_string(slot) + " out of range (" + f.name + " has " +
                  std::to_string(count) + ")");
    return static_cast<unsigned char*>(ptr) + size_t(slot) * item_size(f);
  }
  [[noreturn]] static void unsupported(const char* what) {
    throw Error(std::string(P::kind) + ": this kind has no " + what + " (batches of scenes: magic8ball)");
  }
  // a fixed-capacity buffer that overflowed stopped its scene before the step was taken: the
  // pipeline grows it when it can (clearing the flags it handled) and the step is repeated
  bool recover() {
    std::vector<Record> r = records();
    if (!p_.recover(r, bytes_available(backend(), device_))) return false;
    write_records(r);
    ex_.reset_graphs();
    return true;
  }
  bool all_halted(const Record* r) const {
    for (size_t k = 0; k < rec_.size(); ++k)
      if (!halted(r[k])) return false;
    return true;
  }
  int check_scene(int scene) const {
    if (scene < 0 || scene >= scenes())
      throw Error(std::string(P::kind) + ": scene " + std::to_string(scene) + " out of range (this state has " +
                  std::to_string(scenes()) + ")");
    return scene;
  }
  void flush_control() {
    if (!ctl_dirty_) return;
    ex_.upload_async(control_.data(), ctl_.data(), sizeof(Control) * ctl_.size());
    ctl_dirty_ = false;
  }
  static Buf<Record> alloc_record(Exec& ex, const std::vector<Record>& initial) {
    Buf<Record> b;
    b.resize(initial.size());
    ex.to_device(b.data(), initial.data(), sizeof(Record) * initial.size());
    return b;
  }
  static Buf<Control> alloc_control(size_t scenes) {
    Buf<Control> b;
    b.resize(scenes);  // zero: no input
    return b;
  }
  // the records as of the last step (one copy when they are stale)
  const std::vector<Record>& records() {
    if (!rec_valid_) {
      ex_.to_host(rec_.data(), record_.data(), sizeof(Record) * rec_.size());
      rec_valid_ = true;
    }
    return rec_;
  }
  void write_records(const std::vector<Record>& r) {
    ex_.to_device(record_.data(), r.data(), sizeof(Record) * r.size());
    rec_ = r;
    rec_valid_ = true;
  }
  template <class T>
  const T& find(const std::vector<T>& table, const std::string& name, const char* what) const {
    for (const T& t : table)
      if (t.name == name) return t;
    std::string known;
    for (const T& t : table) known += (known.empty() ? "" : ", ") + t.name;
    throw Error(std::string(P::kind) + ": no " + what + " '" + name + "' (" + what + "s: " + known + ")");
  }

  Exec ex_;
  int device_;
  Buf<Record> record_;
  Buf<Control> control_;
  P p_;
  std::vector<FieldInfo> fields_;
  std::vector<ScalarInfo> scalars_, controls_;
  std::vector<Record> rec_;
  bool rec_valid_ = false;
  std::vector<Control> ctl_;
  bool ctl_dirty_ = false;
};

}  // namespace cps
