// Which CUDA devices this build can use (empty list plus a reason when none).
#pragma once
#include <string>
#include <vector>

namespace cps {

struct GpuInfo {
  std::string name;
  int major = 0, minor = 0;
  double memory_gib = 0.0;
  int multiprocessors = 0;
};

std::vector<GpuInfo> cuda_device_list(std::string& error);

}  // namespace cps
