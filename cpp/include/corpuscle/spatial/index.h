// The spatial index protocol: every index (allpairs.h, cell_grid.h, neighbor_list.h) has a
// host-side structure built through an Exec, and a small POD *view* passed by value into
// CPS_HD functors. A view V of dimension D offers
//
//   static constexpr int kDim = D;
//   int size() const;                         // slots the index covers: i in [0, size())
//   bool active(int i) const;                 // slot i holds a particle (false: an unused slot)
//   const Vec<D>& position(int i) const;      // the position the index holds for slot i
//   float max_radius() const;                 // the largest radius the index can answer
//   V with_radius(float r) const;             // the same index queried with radius r <= max_radius()
//   void gather(int i, const Vec<D>& xi, Visit&& visit) const;
//       // visit(j, xi - x_j, r2) for every j (i itself included) with r2 < radius^2, in an
//       // order fixed by the index and the data (no atomics, the same on every run): a
//       // stage that sums into particle i alone is deterministic
//   void pairs(int i, const Vec<D>& xi, Visit&& visit) const;
//       // the same for j > i only: run over every i, each unordered pair comes once (for
//       // stages that apply a reaction to both particles with atomics, core/atomics.h)
//
// A stage uses a view like this (one thread per particle, any index, any backend):
//
//   struct Density {
//     CellGridView<3> view;  // or AllPairsView<3>, CsrView<3>
//     float* rho;
//     CPS_HD void operator()(int i) const {
//       float sum = 0.0f;
//       view.gather(i, view.position(i), [&](int j, const Vec3& d, float r2) { sum += w(r2); });
//       rho[i] = sum;
//     }
//   };
//   exec.for_each(view.size(), Density{grid.view(), rho});
//
// The gather-stage helpers below package that loop for a stage written as begin / visit /
// end (the form the tiled all-pairs kernel in allpairs.h runs as well):
//
//   struct Stage {
//     using Acc = ...;                                               // per-particle accumulator
//     CPS_HD Acc begin(int i) const;
//     CPS_HD void visit(Acc& acc, int i, int j, const Vec<D>& d, float r2) const;
//     CPS_HD void end(int i, Acc& acc) const;                        // write the result
//   };
#pragma once
#include "corpuscle/core/vec.h"

namespace cps {

// the names of the index plug-ins (`--neighbors`): a kind's plug-in takes its name from here,
// so one index is one name in every kind
namespace index_name {
inline constexpr const char* lists = "lists";
inline constexpr const char* grid = "grid";
inline constexpr const char* compact = "compact";
inline constexpr const char* allpairs = "allpairs";
inline constexpr const char* lbvh = "lbvh";
}  // namespace index_name

// the largest float: "no limit" for max_radius()
constexpr float kNoRadiusLimit = 3.402823466e38f;

// one particle's gather through a begin / visit / end stage (inactive slots are skipped)
template <class View, class Stage>
struct GatherStageFn {
  View view;
  Stage stage;
  CPS_HD void operator()(int i) const {
    if (!view.active(i)) return;
    auto acc = stage.begin(i);
    view.gather(i, view.position(i),
                [&](int j, const Vec<View::kDim>& d, float r2) { stage.visit(acc, i, j, d, r2); });
    stage.end(i, acc);
  }
};

// run a begin / visit / end stage over every slot of an index, one thread per slot
template <class Exec, class View, class Stage>
void gather_stage(Exec& ex, const View& view, const Stage& stage) {
  ex.for_each(view.size(), GatherStageFn<View, Stage>{view, stage});
}

}  // namespace cps
