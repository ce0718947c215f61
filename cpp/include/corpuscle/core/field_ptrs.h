// The device pointers of a field table's rows (sim/field_store.h has the tables and their
// storage): for each row X(name, C type, components, group, checkpointed, settable, recorded,
// moves), `name` (the current slots) and `name_alt` (the other buffer), and the reorder's
// copy gather(j, o): slot j of the other buffers takes slot o's moving fields.
#pragma once
#include <type_traits>

#include "corpuscle/core/vec.h"

namespace cps {

// the item of a field of `C` components of T (a vector: Vec<C> of floats)
template <class T, int C>
struct FieldItem {
  static_assert(std::is_same<T, float>::value, "vector fields are of float");
  using type = Vec<C>;
};
template <class T>
struct FieldItem<T, 1> {
  using type = T;
};

#define CPS_FS_ITEM_(T, comps) typename ::cps::FieldItem<T, comps>::type
#define CPS_FS_PTR_(name, T, comps, group, ckpt, settable, recorded, moves) \
  CPS_FS_ITEM_(T, comps) * name;                                            \
  CPS_FS_ITEM_(T, comps) * name##_alt;
#define CPS_FS_GATHER_(name, T, comps, group, ckpt, settable, recorded, moves) \
  if constexpr (moves) this->name##_alt[j] = this->name[o];

// the pointers of FIELDS' rows (members of a struct the stages take)
#define CPS_FIELD_MEMBERS(FIELDS) FIELDS(CPS_FS_PTR_)
// the reorder's copy of every moving field of FIELDS (the members may be inherited: a kind
// that extends a module's arrays gathers the module's fields and its own)
#define CPS_FIELD_GATHER(FIELDS) \
  CPS_HD void gather(int j, int o) const { FIELDS(CPS_FS_GATHER_) }
// both
#define CPS_FIELD_PTRS(FIELDS) \
  CPS_FIELD_MEMBERS(FIELDS)    \
  CPS_FIELD_GATHER(FIELDS)

}  // namespace cps
