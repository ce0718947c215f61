// Tables a scene kind declares once (MuJoCo's mjxmacro.h is the model): its particle fields
// and the scalars of its per-scene record and control. An X-macro list per kind generates
// the enum, the names, dtypes and shapes, the views, the bindings and the frame layout.
#pragma once
#include <cstddef>
#include <cstdint>
#include <string>

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

}  // namespace cps
