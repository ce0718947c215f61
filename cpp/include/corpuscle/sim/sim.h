// The one interface the bindings see, for every scene kind: step, end time, control,
// scalars, fields, checkpoints, bench, profile. No scene name appears here; a kind
// describes its fields, scalars and control in tables (sim/table.h) and the bindings
// convert through them.
#pragma once
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "corpuscle/core/error.h"
#include "corpuscle/sim/table.h"

namespace cps {

// polled between batches of steps; true stops stepping (after a whole step)
using StopCheck = std::function<bool()>;

// a host copy of a simulation's whole state: the checkpointed fields (name -> bytes, in the
// current particle order) and the checkpointed scalars (the per-scene record's bytes)
struct Snapshot {
  std::vector<std::pair<std::string, std::vector<unsigned char>>> fields;
  std::vector<unsigned char> scene;    // the per-scene records (each sim/table.h's Clock first)
  std::vector<unsigned char> control;  // the controls the next step reads
};

// an array of one row per scene (`cols` values of `dtype` each) in the backend's memory
struct SceneArray {
  std::string name;
  void* data;
  DType dtype;
  int cols;
};

class Sim {
 public:
  virtual ~Sim() = default;
  virtual const char* kind() const = 0;
  virtual const char* backend() const = 0;
  virtual const char* index() const = 0;
  virtual bool on_device() const = 0;
  virtual int device() const = 0;
  virtual long long particles() const = 0;
  // independent scenes in this state (a single run: 1); per-scene calls name one
  virtual int scenes() const = 0;

  // the kind's tables
  virtual const std::vector<FieldInfo>& fields() const = 0;
  virtual const std::vector<ScalarInfo>& scalars() const = 0;
  virtual const std::vector<ScalarInfo>& controls() const = 0;

  // advance up to n steps; returns how many were taken (none once the end time is reached
  // or the run went unsound; stop() can end it early)
  virtual long long step(long long n, const StopCheck& stop) = 0;
  // densities, forces and reductions of the current state, without advancing
  virtual void evaluate() = 0;
  virtual void set_end_time(double t) = 0;

  // the per-scene record (Clock first, then the kind's scalars) as of the last step: one
  // copy per call on a device, cached until something changes it
  virtual const unsigned char* scene_record(int scene) = 0;
  virtual size_t record_size() const = 0;
  virtual size_t control_size() const = 0;
  // replace scalars of the record (name -> bytes as the table describes them)
  virtual void set_scalar(const std::string& name, const void* bytes, int scene) = 0;
  // the control read by the next step: own buffer, written asynchronously, no rebuild
  // (scene -1: every scene)
  virtual void set_control(const std::string& name, const void* bytes, int scene) = 0;
  // named values the kind derives from its record (the 8-ball's answer face, ...)
  virtual std::vector<std::pair<std::string, double>> derived(int scene) = 0;

  // current storage of a field (host or device) and its item count / a host copy
  virtual std::pair<void*, long long> view(const std::string& name) = 0;
  virtual void download(const std::string& name, void* dst) = 0;
  // host copies of several fields at once (a frame): one wait on a device
  virtual void download_many(const std::vector<std::string>& names, const std::vector<void*>& dst) = 0;
  // replace a field's values (the kind decides which fields may be set and what follows)
  virtual void upload(const std::string& name, const void* src, long long count) = 0;

  // one particle's record: every checkpointed field of the group "fluid" (the particles the
  // kind counts), in the field table's order, its slot's items one after another (what moves
  // a particle between ranks); unpack writes a record into a slot (the next step re-sorts)
  virtual size_t packed_size() const = 0;
  virtual void pack(long long slot, void* record) = 0;
  virtual void unpack(long long slot, const void* record) = 0;

  // the state the next step reads / replace it (the step after either sorts and relists,
  // so a run that checkpoints and the run resumed from it take identical steps)
  virtual Snapshot checkpoint() = 0;
  virtual void restore(const Snapshot& s) = 0;

  // a batch of scenes (kinds that support it; the others throw): every scene's control at
  // once (values: scenes x the control table's floats, in its order; one upload at the next
  // step), every scene's end time (relative: added to its time), the reset cache of every
  // scene's state, the restore of k distinct scenes from it (turn, sym: 4 floats each, see
  // the kind), and per-scene observations in arrays of their own on the backend
  virtual void set_controls(const float* values, int cols) = 0;
  virtual void set_end_times(const double* t, bool relative) = 0;
  virtual void cache_scenes() = 0;
  virtual void restore_scenes(const int* scenes, int k, const float* turn, const float* sym) = 0;
  virtual std::vector<SceneArray> observe() = 0;
  // copy bytes of the backend's memory (an observe() array) to the host
  virtual void copy_to_host(void* dst, const void* src, size_t bytes) = 0;

  // one scene split over ranks (kinds that support it: the SPH box, scenes/sph/ranks.h; the
  // others throw): the rank's slot counts (fluid, walls; ids below id_bound), a step in halves
  // around its reductions (phase 0 writes the rank's sums, step_sums_size() bytes, to `sums`;
  // phase 1 reads `ranks` of them, combines them and takes the step), and a stored field's
  // items at a list of slots (every slot, the fluid's then the walls'). No slot changes place
  // between a step's halves, nor between steps that do not relist. After each half `flags`
  // holds the record's clock.bad, whether the next step relists and the particles outside
  // the domain (kind's meaning); phase 2 grows a fixed-capacity buffer that overflowed in
  // phase 0 (false: it cannot), after which phase 0 is run again.
  virtual void set_counts(long long fluid, long long wall, long long id_bound) { no_ranks(); }
  virtual size_t step_sums_size() const { no_ranks(); }
  virtual bool step_half(int phase, void* sums, int ranks, long long* flags) { no_ranks(); }
  virtual long long slots() const { no_ranks(); }
  virtual void get_slots(const std::string& field, const int* slots, long long count, void* out) { no_ranks(); }
  virtual void set_slots(const std::string& field, const int* slots, long long count, const void* in) { no_ranks(); }

  // seconds for n steps on the backend's clock after a synchronise; per-stage ms per step
  // (stop: as step's, asked between batches of steps; a stopped measurement is meaningless and
  // the caller discards it)
  virtual double bench(long long n, const StopCheck& stop = {}) = 0;
  virtual std::vector<std::pair<std::string, double>> profile(long long n, const StopCheck& stop = {}) = 0;

 protected:
  [[noreturn]] void no_ranks() const { throw Error(std::string(kind()) + ": a scene of this kind is not split over ranks"); }
};

}  // namespace cps
