// Tables a scene kind declares once (MuJoCo's mjxmacro.h is the model): its particle fields
// and the scalars of its per-scene record and control. An X-macro list per kind generates
// the enum, the names, dtypes and shapes, the views, the bindings and the frame layout.
#pragma once
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "corpuscle/core/atomics.h"

namespace cps {

enum class DType : uint8_t { F32, F64, I32, I64 };

inline size_t dtype_size(DType t) { return t == DType::F64 || t == DType::I64 ? 8 : 4; }
inline char dtype_kind(DType t) { return t == DType::F32 || t == DType::F64 ? 'f' : 'i'; }

template <class T> constexpr DType dtype_of();
template <> constexpr DType dtype_of<float>() { return DType::F32; }
template <> constexpr DType dtype_of<double>() { return DType::F64; }
template <> constexpr DType dtype_of<int>() { return DType::I32; }
template <> constexpr DType dtype_of<long long>() { return DType::I64; }

// a particle field: items of `components` values of `dtype`, counted per group
struct FieldInfo {
  std::string name;
  std::string group;   // "fluid", "ghost", ...: fields of a group have the same count
  DType dtype;
  int components;      // 1: scalar per particle; 2 or 3: a vector
  bool checkpointed;   // part of the state the next step reads
  bool settable;       // upload() accepts it
  bool recorded = false;  // every frame carries it (tables of sim/field_store.h say which)
};

// a scalar of the per-scene record or of the control: `count` values at `offset`
struct ScalarInfo {
  std::string name;
  DType dtype;
  int count;
  size_t offset;
  bool checkpointed;   // part of the state the next step reads
};

// The per-scene clock every kind's record starts with: time, end, step, dt and why the
// scene's steps are no-ops (done: end time reached; bad: the first instability reason)
struct Clock {
  double time;
  double end_time;     // steps after it are no-ops
  long long step;
  float dt;            // the dt of the last step taken
  int done;            // end_time reached
  int bad;             // why the run is unsound (a kind's code), 0 while it is sound
  long long bad_step;  // the step that went bad
};

// the clock's rows of a kind's scalar table (X(name, C type, count, member, checkpointed))
#define CPS_CLOCK_SCALARS(X)                       \
  X(time, double, 1, clock.time, true)             \
  X(end_time, double, 1, clock.end_time, false)    \
  X(step, long long, 1, clock.step, true)          \
  X(dt, float, 1, clock.dt, true)                  \
  X(done, int, 1, clock.done, false)               \
  X(bad, int, 1, clock.bad, false)                 \
  X(bad_step, long long, 1, clock.bad_step, false)

// a new scene's clock: time 0, no end, no step taken, sound
CPS_HD CPS_INLINE Clock start_clock() {
  Clock c{};
  c.time = 0.0;
  c.end_time = 1e300;
  c.step = 0;
  c.dt = 0.0f;
  c.bad_step = -1;
  return c;
}

// The clock's part of every kind's finalize: a step at or past the end time is not taken
// (the clock says done), a step that would pass it is shortened to land on it, and a step
// taken advances the clock (landing exactly on the end time, after which steps are no-ops)
CPS_HD CPS_INLINE bool clock_at_end(Clock& C) {
  if (!C.done && C.time < C.end_time) return false;
  C.done = 1;
  return true;
}
// dt, shortened to end on the end time; `last`: this step reaches it
CPS_HD CPS_INLINE float clip_to_end(const Clock& C, float dt, bool& last) {
  last = C.time + double(dt) >= C.end_time;
  return last ? float(C.end_time - C.time) : dt;
}
CPS_HD CPS_INLINE void advance_clock(Clock& C, float dt, bool last) {
  C.dt = dt;
  C.time = last ? C.end_time : C.time + double(dt);
  C.done = last ? 1 : 0;
  C.step += 1;
}

// a scene whose run is over (end time reached) or unsound: its steps are no-ops
template <class Record>
CPS_HD CPS_INLINE bool halted(const Record* g) {
  return g->clock.done != 0 || g->clock.bad != 0;
}

// raise an instability reason: the first one raised stays (each stage raises one reason, so
// the kept reason is that of the earliest stage that found a fault)
CPS_HD CPS_INLINE void raise_first(int* p, int code) { atomic_cas(p, 0, code); }

// a kind's three tables from its X-macro lists (inside its Pipeline: Record and Control are
// the per-scene record and the control; see scenes/magic8ball/tables.h for the columns)
#define CPS_KIND_TABLES(FIELDS, SCALARS, CONTROLS, Record, Control)                                             \
  static std::vector<FieldInfo> field_table() {                                                                 \
    std::vector<FieldInfo> t;                                                                                   \
    FIELDS(CPS_TABLE_FIELD_)                                                                                    \
    return t;                                                                                                   \
  }                                                                                                             \
  CPS_KIND_SCALAR_TABLES_(SCALARS, CONTROLS, Record, Control)
// the scalar and control tables (of CPS_KIND_TABLES and field_store.h's CPS_KIND_STORED_TABLES)
#define CPS_KIND_SCALAR_TABLES_(SCALARS, CONTROLS, Record, Control)                                             \
  static std::vector<ScalarInfo> scalar_table() {                                                               \
    std::vector<ScalarInfo> t;                                                                                  \
    Record s{};                                                                                                 \
    const char* base = reinterpret_cast<const char*>(&s);                                                       \
    SCALARS(CPS_TABLE_SCALAR_)                                                                                  \
    return t;                                                                                                   \
  }                                                                                                             \
  static std::vector<ScalarInfo> control_table() {                                                              \
    std::vector<ScalarInfo> t;                                                                                  \
    Control s{};                                                                                                \
    const char* base = reinterpret_cast<const char*>(&s);                                                       \
    CONTROLS(CPS_TABLE_CONTROL_)                                                                                \
    return t;                                                                                                   \
  }
#define CPS_TABLE_FIELD_(name, T, comps, group, ckpt, settable, storage, count) \
  t.push_back(FieldInfo{#name, group, dtype_of<T>(), comps, ckpt, settable});
#define CPS_TABLE_SCALAR_(name, T, count, member, ckpt) \
  t.push_back(ScalarInfo{#name, dtype_of<T>(), count, size_t(reinterpret_cast<const char*>(&s.member) - base), ckpt});
#define CPS_TABLE_CONTROL_(name, T, count, member) CPS_TABLE_SCALAR_(name, T, count, member, false)

}  // namespace cps
