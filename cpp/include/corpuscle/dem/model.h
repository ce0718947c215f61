// The DEM module: soft spheres of one radius and one mass, touching through the linear
// spring-dashpot law of physics/dem.h, sorted into an index every step (the cell grid, the
// LBVH or all pairs), integrated by forward or symplectic Euler. It sits between physics (the
// formulas) and scenes (the kinds): its stages (dem/stages.h) and its pipeline glue
// (dem/step.h) are generic over the dimension D, the index view and the kind, which plugs in
// through small hooks (its walls and bodies, its extra per-particle fields, its outflow and
// per-scene bookkeeping). A DEM kind writes its Model (deriving from SoftSpheres<D>), its
// record, its hooks and its pipeline; docs/architecture.md, "A new DEM kind, worked example".
//
// This file: the spheres' constant parameters, the arrays every DEM pipeline has, the
// fault codes, the integrators and the dt rule.
#pragma once
#include "corpuscle/core/field_ptrs.h"
#include "corpuscle/core/vec.h"
#include "corpuscle/physics/dem.h"

namespace cps::dem {

constexpr int kForwardEuler = 0;     // x += v dt, v += a dt (the wind tunnel seed's)
constexpr int kSymplecticEuler = 1;  // v += a dt, x += v dt

constexpr int kBadParticles = 1;  // a particle position or velocity went non-finite
constexpr int kBadTraversal = 2;  // an LBVH traversal stack would have overflowed

// The spheres' constant parameters: a DEM kind's Model derives from it (so the stages read
// m.radius, m.pp, ... whatever the kind adds) and its build.h fills it.
template <int D>
struct SoftSpheres {
  static_assert(D == 2 || D == 3, "soft spheres are 2-D or 3-D");
  int n;                 // particles
  int integrator;        // kForwardEuler / kSymplecticEuler
  float radius, mass;
  int collide;           // particle-particle contacts on (1) or off (0: a collisionless gas)
  int reflexive;         // 0: gather (each particle sums its own contacts: reproducible);
                         // 1: reflexive (each pair once, the reaction added by atomics);
                         // 2: reflexive with warp-aggregated atomics on the device
  int periodic_z;        // D = 3: z periodic over [lo[2], hi[2]) (contacts through the images,
                         // positions wrapped after the move); D = 2: unused
  SpringDashpot pp;      // particle-particle
  Vec<D> lo, hi;         // the domain the index covers (particles outside it are still found:
                         // the grid clamps, the tree's box is its own)
  float cell;            // the broad-phase grid's cell edge (m), at least a contact diameter
  int lbvh_stack;        // LBVH traversal stack entries per thread (shared memory on the device)
  float dt_fraction;     // the fastest particle moves at most this fraction of the radius per step
  float dt_max;
};

// The fields every DEM kind has, rows of its field table (sim/field_store.h; D: the kind's
// dimension), in two parts so that a kind's own moving fields can sit between them:
//   position, velocity, id: the spheres, moved with them by every reorder;
//   pressure (the sum of contact-force magnitudes: the wind tunnel seed's "pressure"),
//   number_density (particles per unit area, D = 3: volume, around each: its cell block),
//   force (the contact force this step), contacts (overlapping neighbours, walls and bodies):
//   written by the force stage every step.
// X(name, C type, components, group, checkpointed, settable, recorded, moves)
#define CPS_DEM_MOVING_FIELDS(X)                          \
  X(position, float, D, "fluid", true, true, true, true)  \
  X(velocity, float, D, "fluid", true, true, false, true) \
  X(id, int, 1, "fluid", true, false, true, true)
#define CPS_DEM_STEP_FIELDS(X)                                    \
  X(pressure, float, 1, "fluid", false, false, true, false)       \
  X(number_density, float, 1, "fluid", false, false, true, false) \
  X(force, float, D, "fluid", false, false, false, false)         \
  X(contacts, int, 1, "fluid", false, false, false, false)
#define CPS_DEM_FIELDS(X) CPS_DEM_MOVING_FIELDS(X) CPS_DEM_STEP_FIELDS(X)

// The arrays every DEM pipeline gives its stages: those fields' pointers (`name`: the current
// buffers, `name_alt`: the other ones, which the reorder writes). A kind's Arrays derives from
// it, adding its own fields' pointers and a gather over all of its table (the stages take this
// part; the reorder takes the kind's).
template <int D>
struct Arrays {
  CPS_FIELD_PTRS(CPS_DEM_FIELDS)
};

// the fastest particle moves at most dt_fraction radii per step, and dt <= dt_max
template <int D>
CPS_HD CPS_INLINE float choose_dt(const SoftSpheres<D>& m, float vmax2) {
  float v = fsqrt(vmax2);
  float dt = m.dt_max;
  if (v > 0.0f) dt = fmin2(dt, m.dt_fraction * m.radius / v);
  return dt;
}

// one Euler step of a sphere under the force F (the integrator of m)
template <int D>
CPS_HD CPS_INLINE void euler_step(const SoftSpheres<D>& m, const Vec<D>& F, float dt, Vec<D>& x, Vec<D>& v) {
  const Vec<D> a = F * (1.0f / m.mass);
  if (m.integrator == kSymplecticEuler) {
    v += a * dt;
    x += v * dt;
  } else {
    x += v * dt;
    v += a * dt;
  }
}

// D = 3, the periodic span: the shift (+L or -L, L the span; 0: none) that takes z to its
// image beyond the other end of the span when z lies within `reach` of this end; the pairs a
// particle has with particles near the other end are found by a second search of the index
// around x + shift e_z (a span of at least two reaches, which the kind's build.h asks for, has
// at most one such image and never the particle itself or a particle found directly)
template <int D>
CPS_HD CPS_INLINE float span_image(const SoftSpheres<D>& m, float z, float reach) {
  if constexpr (D == 2) {
    return 0.0f;
  } else {
    if (!m.periodic_z) return 0.0f;
    const float L = m.hi[2] - m.lo[2];
    return z - m.lo[2] < reach ? L : (m.hi[2] - z < reach ? -L : 0.0f);
  }
}
// the displacement x_j - (x_i + shift e_z), as (x_j - x_i) - shift in z: the two particles of a
// pair meeting through the periodic boundary see exactly opposite displacements
template <int D>
CPS_HD CPS_INLINE Vec<D> image_displacement(const Vec<D>& xi, const Vec<D>& xj, float shift) {
  Vec<D> d = xj - xi;
  if constexpr (D == 3) d[2] = d[2] - shift;
  return d;
}
// the search reach around an image point: a contact diameter and a rounding margin
template <int D>
CPS_HD CPS_INLINE float image_reach(const SoftSpheres<D>& m) { return 2.0f * m.radius * (1.0f + 1e-5f); }

// D = 3 with periodic_z: z taken back into the span [lo, hi) (a particle may cross it more
// than once a step when the span is a few radii)
template <int D>
CPS_HD CPS_INLINE void wrap_span(const SoftSpheres<D>& m, Vec<D>& x) {
  if constexpr (D == 3) {
    if (m.periodic_z) {
      const float L = m.hi[2] - m.lo[2];
      const float t = (x[2] - m.lo[2]) / L;
      if (t < 0.0f || t >= 1.0f) {
        x[2] -= L * ffloor(t);
        if (!(x[2] < m.hi[2]) || !(x[2] >= m.lo[2])) x[2] = m.lo[2];  // rounding at the ends
      }
    }
  }
  (void)m;
  (void)x;
}

}  // namespace cps::dem
