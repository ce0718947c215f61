// The one list of scene kinds: the registry (kinds(), bytes_needed) and each backend's
// make_sim read it. A new kind adds its entry here (sim/kind_list.h says what an entry has);
// its name and index names are spelled once, in its own build.h.
#pragma once
#include "corpuscle/scenes/fields_test/fields_test.h"
#include "corpuscle/scenes/magic8ball/build.h"
#include "corpuscle/scenes/sph/build.h"
#include "corpuscle/scenes/wind_tunnel/build.h"
#include "corpuscle/sim/kind_list.h"

namespace cps {

using Kinds = KindList<m8::Entry, wt::Entry<2>, wt::Entry<3>, sph::Entry<sph::FluidBoxKind>,
                       sph::Entry<sph::DamBreakKind>, sph::Entry<sph::DamBreak2Kind>,
                       sph::Entry<sph::FluidBox2Kind>, ftest::Entry>;

// a simulation of r's kind on the backend `ex`
template <class Exec>
std::unique_ptr<Sim> make_kind(Exec&& ex, const SimRequest& r) {
  return Kinds::with(r.kind, [&](auto kind) { return decltype(kind)::make(std::move(ex), r); });
}

}  // namespace cps
