// The DEM module's parameters read from a kind's ParamSource (the keys its Python builder
// writes, in SI units): n, integrator, radius, mass, k and c (the pair law), cell, lbvh_stack,
// collide, reflexive, dt_fraction, dt_max. The domain (lo, hi) and periodic_z are the kind's to
// set: only it knows its geometry's keys.
#pragma once
#include <string>

#include "corpuscle/core/error.h"
#include "corpuscle/dem/model.h"
#include "corpuscle/sim/params.h"
#include "corpuscle/spatial/lbvh.h"

namespace cps::dem {

template <int D>
inline void read_spheres(const ParamSource& p, const std::string& kind, SoftSpheres<D>& m) {
  m.n = int(p.integer("n"));
  m.integrator = int(p.integer("integrator"));
  if (m.integrator != kForwardEuler && m.integrator != kSymplecticEuler)
    throw Error(kind + ": integrator must be 0 (forward Euler) or 1 (symplectic Euler)");
  m.radius = p.f("radius");
  m.cell = p.has("cell") ? p.f("cell") : 0.0f;
  if (!(m.cell >= 0.0f) || !finite(m.cell)) throw Error(kind + ": cell must be finite and not negative");
  m.lbvh_stack = p.has("lbvh_stack") ? int(p.integer("lbvh_stack")) : kLbvhStack;
  if (m.lbvh_stack < 1 || m.lbvh_stack > kLbvhMaxStack)
    throw Error(kind + ": lbvh_stack must be 1 to " + std::to_string(kLbvhMaxStack) + ", got " +
                std::to_string(m.lbvh_stack));
  m.mass = p.f("mass");
  m.collide = p.has("collide") ? int(p.integer("collide") != 0) : 1;
  m.reflexive = p.has("reflexive") ? int(p.integer("reflexive")) : 0;
  if (m.reflexive < 0 || m.reflexive > 2) throw Error(kind + ": reflexive must be 0, 1 or 2");
  m.pp = SpringDashpot{p.f("k"), p.f("c")};
  m.dt_fraction = p.f("dt_fraction");
  m.dt_max = p.f("dt_max");
}

}  // namespace cps::dem
