// Periodic axes of an index's domain: the minimum-image displacement every index applies to
// xi - xj, and the wrap of a position back into the period. An axis k is periodic when bit k
// of `mask` is set; its period is len[k] (the domain's extent along it). Positions are kept
// inside [lo, lo + len) by the stage that moves them (wrap), so one correction of +-len
// gives the minimum image (|xi - xj| < len). mask = 0: no axis wraps and displacement()
// returns d as it is (one uniform branch per pair).
#pragma once
#include "corpuscle/core/vec.h"

namespace cps {

template <int D>
struct Periodic {
  unsigned mask = 0;   // bit k: axis k wraps
  float lo[D] = {};    // the period's lower end per axis
  float len[D] = {};   // the period per axis (0 on axes that do not wrap)

  CPS_HD bool any() const { return mask != 0u; }
  CPS_HD bool on(int k) const { return (mask >> k) & 1u; }

  // the minimum image of a displacement d = xi - xj (both inside the period)
  CPS_HD Vec<D> displacement(Vec<D> d) const {
    if (mask == 0u) return d;
    for (int k = 0; k < D; ++k) {
      if (!on(k)) continue;
      const float half = 0.5f * len[k];
      if (d[k] > half) d[k] -= len[k];
      else if (d[k] < -half) d[k] += len[k];
    }
    return d;
  }
  // a position moved back into [lo, lo + len) along the periodic axes (moved by less than a
  // period since it was last inside)
  CPS_HD Vec<D> wrap(Vec<D> x) const {
    if (mask == 0u) return x;
    for (int k = 0; k < D; ++k) {
      if (!on(k)) continue;
      const float hi = lo[k] + len[k];
      if (x[k] >= hi) x[k] -= len[k];
      else if (x[k] < lo[k]) x[k] += len[k];
      // (rounding: x - len may land exactly on hi for x just above it)
      if (x[k] >= hi) x[k] = lo[k];
    }
    return x;
  }

  // periodic along the axes of `mask` over [lo, hi]
  static Periodic make(unsigned mask, const Vec<D>& lo, const Vec<D>& hi) {
    Periodic p;
    p.mask = mask & ((1u << D) - 1u);
    for (int k = 0; k < D; ++k) {
      p.lo[k] = lo[k];
      p.len[k] = p.on(k) ? hi[k] - lo[k] : 0.0f;
    }
    return p;
  }
};

}  // namespace cps
