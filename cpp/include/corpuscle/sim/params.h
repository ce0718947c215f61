// Where a kind reads its parameters and initial arrays from (the bindings implement these
// over a Python dict; tests may implement them over anything), and what make_sim needs.
#pragma once
#include <memory>
#include <string>
#include <vector>

#include "corpuscle/core/vec.h"

namespace cps {

class ParamSource {
 public:
  virtual ~ParamSource() = default;
  virtual bool has(const std::string& key) const = 0;
  // each throws cps::Error naming the key when it is missing or of the wrong type
  virtual double number(const std::string& key) const = 0;
  virtual long long integer(const std::string& key) const = 0;
  virtual std::vector<double> numbers(const std::string& key) const = 0;
  virtual std::vector<std::unique_ptr<ParamSource>> tables(const std::string& key) const = 0;
  virtual std::unique_ptr<ParamSource> table(const std::string& key) const = 0;

  float f(const std::string& key) const { return float(number(key)); }
  Vec3 vec3(const std::string& key) const;
};

// an initial particle array: `count` items of `components` float32 values
struct ArrayView {
  const float* data = nullptr;
  long long count = 0;
  int components = 0;
};

class ArraySource {
 public:
  virtual ~ArraySource() = default;
  virtual bool has(const std::string& name) const = 0;
  virtual ArrayView get(const std::string& name) const = 0;
};

// a simulation to make: kind, backend ("serial", "cpu", "cuda"), index plug-in, device
struct SimRequest {
  std::string kind, backend, index;
  int device = 0;
  const ParamSource* params = nullptr;
  const ArraySource* arrays = nullptr;
};

}  // namespace cps
