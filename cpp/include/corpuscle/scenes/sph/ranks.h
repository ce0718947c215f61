// One SPH box scene split over ranks: what the core does for it. The ranks themselves, the
// decomposition, the halo exchange and the migration live in Python
// (python/corpuscle/_ranks_sph.py, over mpi4py): the core never links MPI.
//
// A rank's Pipeline holds its slots as a single run does (fluid [0, nf), walls after), each
// either the rank's own particle or a halo slot: a copy of a particle another rank owns that
// lies within the lists' reach of the rank's slab (the field `halo`, 1). Every index and pair
// stage walks halo slots as any neighbour; a halo slot adds nothing to the step's reductions
// (InteractStage::end) and is not integrated (IntegrateStage): its owner moves it and sends
// its new values before the next step. The counts change with every migration
// (Pipeline::set_counts), the fields are written and read by slot lists (get_slots /
// set_slots: SlotWordsStage through a staging buffer on the backend), and a step runs in two
// halves around the reductions (Pipeline::enqueue_half): the ranks' sums are combined on the
// host in rank order with StepSums::combine (combine_rank_sums), so every rank finalizes the
// same global dt. With the sort's ties broken by id (Model::order_by_id) every particle's
// neighbours are walked in the order one process walks them: the run is bitwise that of one
// process with the same key.
#pragma once
#include <cstdint>

#include "corpuscle/core/hd.h"
#include "corpuscle/scenes/sph/model.h"

namespace cps::sph {

// words of a field's items at a list of slots, to a packed buffer or back
struct SlotWordsStage {
  const int* slots;
  int words;       // 32-bit words an item
  uint32_t* field;
  uint32_t* buf;   // item k at buf[k * words]
  bool to_field;
  CPS_HD void operator()(int k) const {
    uint32_t* f = field + size_t(slots[k]) * size_t(words);
    uint32_t* b = buf + size_t(k) * size_t(words);
    for (int w = 0; w < words; ++w) {
      if (to_field) f[w] = b[w];
      else b[w] = f[w];
    }
  }
};

// the ranks' step sums combined in rank order (the same on every rank)
inline StepSums combine_rank_sums(const StepSums* s, int ranks) {
  StepSums all = StepSums::identity();
  for (int r = 0; r < ranks; ++r) all = StepSums::combine(all, s[r]);
  return all;
}

}  // namespace cps::sph
