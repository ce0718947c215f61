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
#include <vector>

#include "corpuscle/core/error.h"
#include "corpuscle/sim/sim.h"

namespace cps {

template <class Exec, class P>
class SimImpl final : public Sim {
 public:
  template <class T> using Buf = typename Exec::template Buffer<T>;
  using Record = typename P::SceneRecord;
  using Control = typename P::ControlRecord;
  static constexpr int kPollBatch = 32;  // steps between record snapshots on a device

  template <class Model>
  SimImpl(Exec ex, const Model& m, const Record& initial, int device)
      : ex_(std::move(ex)), device_(device), record_(alloc_record(ex_, initial)),
        control_(alloc_control(ex_)), p_(ex_, m, record_.data(), control_.data()),
        fields_(P::field_table()), scalars_(P::scalar_table()), controls_(P::control_table()) {
    rec_ = initial;
    rec_valid_ = true;
    std::memset(&ctl_, 0, sizeof(Control));
  }

  const char* kind() const override { return P::kind; }
  const char* backend() const override { return ex_.name(); }
  const char* index() const override { return P::index_name; }
  bool on_device() const override { return Exec::on_device; }
  int device() const override { return device_; }
  long long particles() const override { return p_.particles(); }
  const std::vector<FieldInfo>& fields() const override { return fields_; }
  const std::vector<ScalarInfo>& scalars() const override { return scalars_; }
  const std::vector<ScalarInfo>& controls() const override { return controls_; }
  P& pipeline() { return p_; }

  long long step(long long n, const StopCheck& stop) override {
    if (n <= 0) return 0;
    const Record r0 = record();
    if (halted(r0)) return 0;
    const long long first = r0.clock.step;
    const int batch = Exec::on_device ? kPollBatch : 1;
    flush_control();
    int slot = 0;
    bool pending = false;
    rec_valid_ = false;
    for (long long k = 0; k < n;) {
      const long long b = std::min<long long>(batch, n - k);
      for (long long j = 0; j < b; ++j) {
        p_.prepare();
        ex_.launch_step(p_.graph_slot(), [&] { p_.enqueue(true); });
        p_.advance(true);
      }
      k += b;
      ex_.poll_begin(slot, record_.data(), sizeof(Record));
      if (pending || !Exec::on_device) {
        const int seen = Exec::on_device ? slot ^ 1 : slot;
        if (halted(*static_cast<const Record*>(ex_.poll_wait(seen)))) break;
      }
      pending = true;
      slot ^= 1;
      if (stop && stop()) break;
    }
    return record().clock.step - first;
  }

  void evaluate() override {
    // the same stages as a step, without integration. A finished or unsound run is
    // evaluated too: its flags are lifted for the evaluation
    Record r0 = record();
    const bool lift = halted(r0);
    if (lift) {
      Record r = r0;
      r.clock.done = r.clock.bad = 0;
      write_record(r);
    }
    flush_control();
    p_.prepare();
    ex_.launch_step(-1, [&] { p_.enqueue(false); });
    p_.advance(false);
    rec_valid_ = false;
    if (lift) {
      Record r = record();
      r.clock.done = r0.clock.done;
      r.clock.bad = r0.clock.bad;
      write_record(r);
    }
    ex_.synchronize();
  }

  void set_end_time(double t) override {
    Record r = record();
    r.clock.end_time = t;
    r.clock.done = r.clock.time >= t ? 1 : 0;
    write_record(r);
  }

  const unsigned char* scene_record() override {
    record();
    return reinterpret_cast<const unsigned char*>(&rec_);
  }

  size_t record_size() const override { return sizeof(Record); }
  size_t control_size() const override { return sizeof(Control); }

  void set_scalar(const std::string& name, const void* bytes) override {
    const ScalarInfo& s = find(scalars_, name, "scalar");
    Record r = record();
    std::memcpy(reinterpret_cast<char*>(&r) + s.offset, bytes, dtype_size(s.dtype) * size_t(s.count));
    write_record(r);
  }

  // staged on the host; the next step (or evaluation) uploads it once, asynchronously and
  // ordered before its first stage
  void set_control(const std::string& name, const void* bytes) override {
    const ScalarInfo& s = find(controls_, name, "control");
    std::memcpy(reinterpret_cast<char*>(&ctl_) + s.offset, bytes, dtype_size(s.dtype) * size_t(s.count));
    ctl_dirty_ = true;
  }

  std::vector<std::pair<std::string, double>> derived() override { return p_.derived(record()); }

  std::pair<void*, long long> view(const std::string& name) override {
    find(fields_, name, "field");
    return p_.view(name, record());
  }
  void download(const std::string& name, void* dst) override {
    const FieldInfo& f = find(fields_, name, "field");
    auto [ptr, count] = p_.view(name, record());
    ex_.synchronize();
    if (count > 0) ex_.to_host(dst, ptr, size_t(count) * size_t(f.components) * dtype_size(f.dtype));
  }
  void upload(const std::string& name, const void* src, long long count) override {
    const FieldInfo& f = find(fields_, name, "field");
    if (!f.settable && !f.checkpointed) throw Error(std::string(P::kind) + ": field '" + name + "' cannot be set");
    p_.upload(name, src, count);
  }

  Snapshot checkpoint() override {
    Snapshot s;
    for (const FieldInfo& f : fields_) {
      if (!f.checkpointed) continue;
      auto [ptr, count] = p_.view(f.name, record());
      std::vector<unsigned char> bytes(size_t(count) * size_t(f.components) * dtype_size(f.dtype));
      ex_.synchronize();
      if (!bytes.empty()) ex_.to_host(bytes.data(), ptr, bytes.size());
      s.fields.emplace_back(f.name, std::move(bytes));
    }
    const Record& r = record();
    s.scene.assign(reinterpret_cast<const unsigned char*>(&r), reinterpret_cast<const unsigned char*>(&r) + sizeof(r));
    const unsigned char* u = reinterpret_cast<const unsigned char*>(&ctl_);
    s.control.assign(u, u + sizeof(Control));
    p_.invalidate(false);  // the next step sorts and relists, as a restored state's does
    return s;
  }

  void restore(const Snapshot& s) override {
    if (s.scene.size() != sizeof(Record)) throw Error(std::string(P::kind) + ": the checkpoint's record has the wrong size");
    for (const auto& [name, bytes] : s.fields) {
      const FieldInfo& f = find(fields_, name, "field");
      const size_t item = size_t(f.components) * dtype_size(f.dtype);
      p_.upload(name, bytes.data(), (long long)(bytes.size() / item));
    }
    Record r;
    std::memcpy(&r, s.scene.data(), sizeof(Record));
    r.clock.done = r.clock.time >= r.clock.end_time ? 1 : 0;
    r.clock.bad = 0;
    r.clock.bad_step = -1;
    P::restored(r);
    write_record(r);
    if (!s.control.empty()) {
      if (s.control.size() != sizeof(Control)) throw Error(std::string(P::kind) + ": the checkpoint's control has the wrong size");
      std::memcpy(&ctl_, s.control.data(), sizeof(Control));
      ctl_dirty_ = true;
    }
    p_.invalidate(true);
  }

  double bench(long long n) override {
    step(1, {});  // capture / warm the step outside the timing
    ex_.synchronize();
    double s = ex_.time([&] { step(n, {}); });
    return s;
  }

  std::vector<std::pair<std::string, double>> profile(long long n) override {
    flush_control();
    ex_.synchronize();
    ex_.profile_begin();
    for (long long k = 0; k < n; ++k) {
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
  void flush_control() {
    if (!ctl_dirty_) return;
    ex_.upload_async(control_.data(), &ctl_, sizeof(Control));
    ctl_dirty_ = false;
  }
  static Buf<Record> alloc_record(Exec& ex, const Record& initial) {
    Buf<Record> b;
    b.resize(1);
    ex.to_device(b.data(), &initial, sizeof(Record));
    return b;
  }
  static Buf<Control> alloc_control(Exec& ex) {
    Buf<Control> b;
    b.resize(1);  // zero: no input
    (void)ex;
    return b;
  }
  // the record as of the last step (one copy when it is stale)
  const Record& record() {
    if (!rec_valid_) {
      ex_.to_host(&rec_, record_.data(), sizeof(Record));
      rec_valid_ = true;
    }
    return rec_;
  }
  void write_record(const Record& r) {
    ex_.to_device(record_.data(), &r, sizeof(Record));
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
  Record rec_;
  bool rec_valid_ = false;
  Control ctl_;
  bool ctl_dirty_ = false;
};

}  // namespace cps
