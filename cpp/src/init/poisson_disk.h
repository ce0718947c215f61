// Poisson-disk sampling inside a sphere, excluding a rigid box, to a target particle count.
//
// Random sequential adsorption ("dart throwing") steered to the uncovered space by adaptive
// refinement (Ebeida et al. 2012), so the fill is near-maximal, run in parallel (OpenMP) in
// batches whose conflicts are settled by random priorities (the greedy maximal independent
// set, which equals the sequential result). Every random number comes from a hash of
// (seed, batch, fragment), so the points do not depend on the number of threads.
// poisson_disk.cpp explains the algorithm and its guarantees.
#pragma once
#include <cstdint>
#include <vector>

#include "corpuscle/core/quat.h"
#include "corpuscle/core/vec.h"

namespace cps {

// the fill region: inside the sphere |p| <= radius (centred at the origin) and at least
// `clearance` outside the box of half extents box_half at box_center, rotated by box_q
struct SphereMinusBox {
  float radius;
  Vec3 box_center, box_half;
  Quat box_q;  // normalised
  float clearance;

  bool contains(const Vec3& p) const;  // the exact test every sample passes
  float box_distance(const Vec3& p) const;  // signed distance to the box (negative inside)
  double volume() const;  // sphere minus box (the box assumed inside the sphere; clearance ignored)
};

// samples with minimum distance r inside the region: near-maximal (see poisson_disk.cpp),
// isotropic, and the same for every thread count
std::vector<Vec3> poisson_disk(const SphereMinusBox& region, float r, uint64_t seed);

// exactly `count` samples: r is tuned so a near-maximal sampling holds at least count, then
// the surplus is removed at random; returns the spacing used through *r_used
std::vector<Vec3> poisson_disk_count(const SphereMinusBox& region, int count, uint64_t seed, float* r_used);

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
