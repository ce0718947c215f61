// Poisson-disk sampling (Bridson 2007, "Fast Poisson disk sampling in arbitrary dimensions")
// inside a sphere, excluding a rigid box, to a target particle count.
#pragma once
#include <cstdint>
#include <functional>
#include <vector>

#include "corpuscle/core/vec.h"

namespace cps {

// samples with minimum distance r inside the region `inside` (bounded by the sphere of radius R)
std::vector<Vec3> poisson_disk(float R, float r, const std::function<bool(const Vec3&)>& inside, uint64_t seed,
                               int attempts = 30);

// exactly `count` samples: r is tuned so a maximal sampling holds at least count, then the
// surplus is removed at random; returns the spacing used through *r_used
std::vector<Vec3> poisson_disk_count(float R, int count, const std::function<bool(const Vec3&)>& inside,
                                     double volume, uint64_t seed, float* r_used);

// splitmix64: a small portable generator so every platform draws the same numbers
struct SplitMix64 {
  uint64_t s;
  uint64_t next() {
    uint64_t z = (s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
  }
  double uniform() { return double(next() >> 11) * (1.0 / 9007199254740992.0); }
};

}  // namespace cps
