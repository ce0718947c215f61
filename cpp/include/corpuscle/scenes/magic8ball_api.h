// Backend-independent handle on a Magic 8-Ball simulation (what the bindings see).
#pragma once
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "corpuscle/scenes/magic8ball.h"

namespace cps::m8 {

// initial state handed in by the caller (host memory)
struct InitialState {
  std::vector<Vec3> pos, vel;
  RigidState die;
};

// the state a run resumes from: fluid arrays in their current order and the scalars
struct CheckpointState {
  std::vector<Vec3> pos, vel;
  std::vector<int> id;
  Globals g;
};

// polled between batches of steps; true stops stepping (after a whole step)
using StopCheck = std::function<bool()>;

// fields that can be read back or viewed
enum class Field { Position, Velocity, Density, Pressure, Id, Acceleration, GhostPosition, GhostVelocity };

class Sim {
 public:
  virtual ~Sim() = default;
  virtual const char* backend() const = 0;
  virtual bool on_device() const = 0;
  virtual const Model& model() const = 0;
  // advance up to n steps; returns how many were taken (none once the end time is reached
  // or the run went unsound, and stop() can end it early)
  virtual long long step(long long n, const StopCheck& stop) = 0;
  // recompute densities, forces and this state's dt without advancing (for comparisons)
  virtual void evaluate() = 0;
  virtual Globals globals() = 0;
  virtual void set_globals(const Globals& g) = 0;
  // replace particle state (fluid arrays, n_fluid entries each) keeping the model
  virtual void set_particles(const std::vector<Vec3>& pos, const std::vector<Vec3>& vel) = 0;
  // copy a field to host memory (fluid fields: n_fluid items; ghost fields: n_ghost items)
  virtual void download(Field f, void* dst) = 0;
  // pointer to the current field storage (host or device) and its item count
  virtual std::pair<void*, int> view(Field f) = 0;
  // seconds for n steps, timed on the backend's clock after a synchronise
  virtual double bench(long long n) = 0;
  // the state to resume from (the next step sorts and relists) / replace it
  virtual CheckpointState checkpoint() = 0;
  virtual void restore(const CheckpointState& c) = 0;
  // per-stage milliseconds per step over n steps
  virtual std::vector<std::pair<std::string, double>> profile(long long n) = 0;
};

// bytes a simulation of this model allocates, and bytes the backend has free
double bytes_needed(const Model& m);
double bytes_available_cpu();
double bytes_available_cuda();

std::unique_ptr<Sim> make_cpu(const Model& m, const InitialState& s, bool parallel);
// throws cps::Error when the CUDA backend is not compiled or no device is usable
std::unique_ptr<Sim> make_cuda(const Model& m, const InitialState& s);

}  // namespace cps::m8
