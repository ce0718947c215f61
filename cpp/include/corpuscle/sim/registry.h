// The registry of scene kinds and their index plug-ins: make_sim builds any of them on any
// backend; the bindings (and `corpuscle scenes`) list what exists.
#pragma once
#include <memory>
#include <string>
#include <vector>

#include "corpuscle/sim/params.h"
#include "corpuscle/sim/sim.h"

namespace cps {

struct KindInfo {
  std::string kind;
  std::vector<std::string> indexes;  // the first is the default
  bool hidden = false;               // built for tests: _core.kinds() lists it only when asked
};

const std::vector<KindInfo>& kinds();
// throws cps::Error naming the unknown kind, index or backend, or why CUDA is unusable
std::unique_ptr<Sim> make_sim(const SimRequest& r);
// bytes a simulation of this request would allocate (checked before anything is)
double bytes_needed(const SimRequest& r);
// bytes the backend can allocate now (host MemAvailable; the device's free memory)
double bytes_available(const std::string& backend, int device);

// per backend, built in their own translation units (the CUDA one is a stub without CUDA)
std::unique_ptr<Sim> make_sim_cpu(const SimRequest& r, bool parallel);
std::unique_ptr<Sim> make_sim_cuda(const SimRequest& r);
double bytes_available_cuda(int device);

}  // namespace cps
