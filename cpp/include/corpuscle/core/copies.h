// A copy from backend memory to host memory, for the Execs' to_host_many (a frame's fields
// in one batch: one wait on a device)
#pragma once
#include <cstddef>

namespace cps {

struct HostCopy {
  void* dst;
  const void* src;
  size_t bytes;
};

}  // namespace cps
