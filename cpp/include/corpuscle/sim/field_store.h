// Fields that own their storage: a kind declares its particle fields once, in a table whose
// rows are
//   X(name, C type, components, group, checkpointed, settable, recorded, moves)
// and CPS_KIND_STORED_TABLES (inside its Pipeline<Exec, ...>) generates from it
//   - the field table (names, dtypes, shapes: Simulation.field, checkpoints, frames),
//   - a buffer per field in the Exec's memory (FieldStore `fields_`; two for a field that
//     `moves`: the current and the other, sorted, one), sized by fields_.resize(n),
//   - the device pointers the stages take (CPS_FIELD_PTRS in the kind's arrays struct: `name`,
//     the current slots, `name_alt`, the other buffer; filled by fields_.fill), with
//     gather(j, o), which copies every moving field of slot o into slot j of the other
//     buffers (the reorder by the sort's permutation),
//   - field_view / field_upload (view(), upload(), downloads and checkpoints through SimImpl),
//   - field_bytes(n) (bytes_needed's part for the fields).
// `moves`: the field is part of the particle (gathered with it by every reorder, carried by
// Sim::pack / unpack when checkpointed); otherwise the step recomputes it (one buffer).
// `recorded`: every frame carries it. Every field spans the pipeline's n slots (group
// "fluid": the particles the kind counts).
//
// Adding a recorded, reordered, checkpointed per-particle field to such a kind is its table
// line plus the line of physics that writes it (scenes/fields_test/ is the worked example).
#pragma once
#include <string>
#include <type_traits>
#include <utility>

#include "corpuscle/core/field_ptrs.h"
#include "corpuscle/sim/table.h"

namespace cps {

// one field's buffers in the Exec's memory: two for a field that moves with the particle
// (the current slots and the other, sorted ones; parity picks which is current), else one
template <class Exec, class Item, bool Moves>
struct FieldBuffer {
  static constexpr int kCopies = Moves ? 2 : 1;
  typename Exec::template Buffer<Item> b[kCopies];
  void resize(size_t n) {
    for (auto& x : b) x.resize(n);
  }
  Item* cur(int parity) { return b[Moves ? parity : 0].data(); }
  Item* alt(int parity) { return b[Moves ? parity ^ 1 : 0].data(); }
};

#define CPS_FS_MEMBER_(name, T, comps, group, ckpt, settable, recorded, moves) \
  ::cps::FieldBuffer<Exec, CPS_FS_ITEM_(T, comps), moves> name;
#define CPS_FS_RESIZE_(name, T, comps, group, ckpt, settable, recorded, moves) name.resize(n);
#define CPS_FS_FILL_(name, T, comps, group, ckpt, settable, recorded, moves) \
  p.name = name.cur(parity);                                                \
  p.name##_alt = name.alt(parity);
#define CPS_FS_BYTES_(name, T, comps, group, ckpt, settable, recorded, moves) \
  +double(sizeof(CPS_FS_ITEM_(T, comps))) * ((moves) ? 2 : 1)
#define CPS_FS_VIEW_(name, T, comps, group, ckpt, settable, recorded, moves)      \
  if (field == #name) {                                                           \
    out = {static_cast<void*>(fields_.name.cur(parity)), (long long)(count)};    \
    return true;                                                                  \
  }
#define CPS_FS_UPLOAD_(name, T, comps, group, ckpt, settable, recorded, moves)                 \
  if (field == #name && ((settable) || (ckpt))) {                                              \
    ex.to_device(fields_.name.cur(parity), src, size_t(count) * sizeof(CPS_FS_ITEM_(T, comps))); \
    return true;                                                                               \
  }
#define CPS_FS_INFO_(name, T, comps, group, ckpt, settable, recorded, moves) \
  t.push_back(FieldInfo{#name, group, dtype_of<T>(), comps, ckpt, settable, recorded});

// a kind's tables (sim/table.h) with the fields of FIELDS stored as above, then those of VIEWS
// (sim/table.h's rows: views the pipeline gives itself, into the stored buffers; a macro
// taking X and expanding to nothing when there are none). Inside its Pipeline: `Exec` is the
// backend; `Ptrs` the struct with CPS_FIELD_PTRS(FIELDS) the stages take. Generates
// field_table(), FieldStore `fields_` (resize(n): every buffer n slots; fill(ptrs, parity)),
// field_bytes(n), and field_view / field_upload of the stored fields (the first `count` slots;
// field_upload takes what a user may set or a checkpoint restores, and returns false for the rest)
#define CPS_KIND_STORED_TABLES(FIELDS, VIEWS, SCALARS, CONTROLS, Record, Control, Ptrs)           \
  CPS_KIND_SCALAR_TABLES_(SCALARS, CONTROLS, Record, Control)                                     \
  static std::vector<FieldInfo> field_table() {                                                   \
    std::vector<FieldInfo> t;                                                                     \
    FIELDS(CPS_FS_INFO_)                                                                          \
    VIEWS(CPS_TABLE_FIELD_)                                                                       \
    return t;                                                                                     \
  }                                                                                               \
  struct FieldStore {                                                                             \
    FIELDS(CPS_FS_MEMBER_)                                                                        \
    void resize(size_t n) { FIELDS(CPS_FS_RESIZE_) }                                              \
    void fill(Ptrs& p, int parity) { FIELDS(CPS_FS_FILL_) }                                       \
  };                                                                                              \
  static double field_bytes(double n) { return n * (0.0 FIELDS(CPS_FS_BYTES_)); }                 \
  bool field_view(const std::string& field, int parity, long long count, std::pair<void*, long long>& out) { \
    FIELDS(CPS_FS_VIEW_)                                                                          \
    return false;                                                                                 \
  }                                                                                               \
  bool field_upload(Exec& ex, const std::string& field, const void* src, long long count, int parity) { \
    FIELDS(CPS_FS_UPLOAD_)                                                                        \
    return false;                                                                                 \
  }                                                                                               \
  FieldStore fields_;

// VIEWS of a kind with none
#define CPS_NO_FIELDS(X)

}  // namespace cps
