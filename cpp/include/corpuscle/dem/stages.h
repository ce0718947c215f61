// The DEM module's stages: functors over the particles (lanes of width 1: for_each) or one
// item per scene, templated on the dimension D, the index view and the kind's hooks. Nothing
// here knows which backend runs it, nor which kind: the kind's walls and bodies, extra fields,
// outflow and per-scene bookkeeping come in through the hooks (each a small functor of plain
// data the kind constructs on the host with its device pointers):
//
//   reorder hook    extra(j, o): the kind's other reordered fields, field_alt[j] = field[o]
//   force hook      F = boundary(i, x, v, pressure, contacts, item): the force on particle i
//                   from the kind's walls and bodies (added to the pair contacts; it adds its
//                   contact magnitudes to pressure, counts to contacts and its reactions to
//                   the kind's per-step sums item)
//   finalize hook   begin(G) (every step, first), sums_finite(S) (the kind's sums sound?),
//                   taken(G, S, dt) (a step of dt is taken: the kind's own bookkeeping)
//   integrate hook  after(i, dt, x, v): the kind's boundaries on the moved sphere (outflow,
//                   re-entry, projections; s.position[i] still holds the old position)
//
// The kind's per-step sums type (`Sums`) has identity() and combine() and the members vmax2,
// ke (filled here) and total_force; its record (`Record`) has clock, pending, sums and step_dt.
#pragma once
#include "corpuscle/dem/contact.h"
#include "corpuscle/sim/table.h"

namespace cps::dem {

// a 64-bit counter in the per-scene record (recycled particles, push-outs, ...)
CPS_HD CPS_INLINE void add_count(long long* p, long long v) {
#ifdef __CUDA_ARCH__
  atomicAdd(reinterpret_cast<unsigned long long*>(p), static_cast<unsigned long long>(v));
#else
  __atomic_fetch_add(p, v, __ATOMIC_RELAXED);
#endif
}

// a finalize hook for a kind with no per-scene bookkeeping of its own
struct NoBookkeeping {
  template <class Record>
  CPS_HD void begin(Record&) const {}
  template <class Sums>
  CPS_HD bool sums_finite(const Sums&) const { return true; }
  template <class Record, class Sums>
  CPS_HD void taken(Record&, const Sums&, float) const {}
};

// an integrate hook that leaves the moved sphere as it is (walls act through forces only)
struct FreeFlight {
  template <int D>
  CPS_HD void after(int, float, Vec<D>&, Vec<D>&) const {}
};

// stage 1: the current arrays gathered into the index's order (order: sorted slot -> input
// slot; null: a plain copy, for a collisionless gas that needs no index): every field that
// moves with its sphere, the module's and the kind's (A: the kind's arrays, dem::Arrays or one
// derived from it with CPS_FIELD_GATHER over its whole table)
template <class A>
struct ReorderStage {
  const int* order;
  A a;
  CPS_HD void operator()(int j) const { a.gather(j, order ? order[j] : j); }
};

// the reflexive form, stage 2a: the per-particle contact sums zeroed
template <int D>
struct ZeroContactsStage {
  Arrays<D> s;
  CPS_HD void operator()(int i) const {
    s.force[i] = Vec<D>::zero();
    s.pressure[i] = 0.0f;
    s.contacts[i] = 0;
  }
};

// stage 2b: each overlapping pair once, from its lower slot (view.pairs); the force on i is
// summed locally, the reaction on j and i's sum added with atomics (float atomics: the sums'
// order, and so their last bits, vary from run to run on parallel backends)
// (D = 3 with periodic_z: and the pairs through the periodic span, from the lower slot as well)
template <int D, class View, class Record>
struct PairStage {
  const SoftSpheres<D>* model;
  const Record* g;
  Arrays<D> s;
  View view;
  CPS_HD void operator()(int i) const {
    if (halted(g)) return;
    const SoftSpheres<D>& m = *model;
    const Vec<D> x = s.position[i], v = s.velocity[i];
    const float r = m.radius;
    Vec<D> F = Vec<D>::zero();
    float pressure = 0.0f;
    int contacts = 0;
    // the pair (i, j), j's displacement seen from i's image x + shift e_z (shift 0: x itself)
    auto touch = [&](int j, float shift) {
      Vec<D> f;
      float mag;
      if (pair_contact_force_d<D>(m.pp, image_displacement(x, s.position[j], shift), v, r, s.velocity[j], r, f, mag)) {
        F += f;
        pressure += mag;
        contacts += 1;
        add_reaction(s, j, -f, mag, m.reflexive == 2);
      }
    };
    view.pairs(i, x, [&](int j, const Vec<D>&, float) { touch(j, 0.0f); });
    if constexpr (D == 3) {
      const float shift = span_image(m, x[2], image_reach(m));
      if (shift != 0.0f) {
        Vec<D> xq = x;
        xq[2] += shift;
        widened(view, image_reach(m)).pairs(i, xq, [&](int j, const Vec<D>&, float) { touch(j, shift); });
      }
    }
    if (contacts > 0) {
      for (int k = 0; k < D; ++k) atomic_add(&s.force[i][k], F[k]);
      atomic_add(&s.pressure[i], pressure);
      atomic_add(&s.contacts[i], contacts);
    }
  }
};

// stage 2: contact forces by gather over the index (the cell grid, the tree, or every particle
// for the all-pairs reference; each particle sums its own: no atomics, the same sum in the same
// order on every backend; reflexive: the sums PairStage left), the number density, then the
// kind's walls and bodies (the boundary hook); the per-particle item of the step's sums
// (D = 3 with periodic_z: and the contacts through the periodic span)
template <int D, class View, class Record, class Sums, class Boundary>
struct ForceStage {
  const SoftSpheres<D>* model;
  const Record* g;
  Arrays<D> s;
  Sums* items;           // where operator() stores its item (for a reduction after the stage)
  View grid;
  CellGridSpec<D> spec;  // the cells the number density counts in
  Boundary boundary;
  // the stage storing its sums item (the reduction reads it after)
  CPS_HD void operator()(int i) const { items[i] = eval(i); }
  // the stage, returning its sums item (Exec::for_each_reduce_then: never stored)
  CPS_HD Sums eval(int i) const {
    if (halted(g)) return Sums::identity();  // the reduction of a step not taken is discarded
    const SoftSpheres<D>& m = *model;
    const Vec<D> x = s.position[i], v = s.velocity[i];
    Vec<D> F = Vec<D>::zero();
    float pressure = 0.0f;
    int contacts = 0;
    const Vec<D>* pos = s.position;
    const Vec<D>* vel = s.velocity;
    const float r = m.radius;
    const SpringDashpot law = m.pp;
    float density = 0.0f;
    // the pair (i, j), j's displacement seen from i's image x + shift e_z (shift 0: x itself)
    auto touch = [&](int j, float shift) {
      Vec<D> f;
      float mag;
      if (pair_contact_force_d<D>(law, image_displacement(x, pos[j], shift), v, r, vel[j], r, f, mag)) {
        F += f;
        pressure += mag;
        contacts += 1;
      }
    };
    if (m.collide && m.reflexive) {
      // the pairs were summed by PairStage
      F = s.force[i];
      pressure = s.pressure[i];
      contacts = s.contacts[i];
      density = block_density(grid, spec, x);
    } else if (m.collide) {
      // the gather and the number density (one walk of the tree for both)
      auto pair = [&](int j, const Vec<D>&, float) {
        if (j == i) return;
        touch(j, 0.0f);
      };
      density = gather_and_density(grid, spec, i, x, pair);
      if constexpr (D == 3) {
        const float shift = span_image(m, x[2], image_reach(m));
        if (shift != 0.0f) {
          Vec<D> xq = x;
          xq[2] += shift;
          widened(grid, image_reach(m)).gather(i, xq, [&](int j, const Vec<D>&, float) { touch(j, shift); });
        }
      }
    }
    Sums it = Sums::identity();
    F += boundary(i, x, v, pressure, contacts, it);
    s.number_density[i] = density;
    it.total_force = F;
    it.vmax2 = norm2(v);
    it.ke = 0.5f * m.mass * it.vmax2;
    s.force[i] = F;
    s.pressure[i] = pressure;
    s.contacts[i] = contacts;
    return it;
  }
};

// ForceStage as the item function of a fused reduction
template <class Stage>
struct EvalOf {
  Stage stage;
  CPS_HD auto operator()(int i) const { return stage.eval(i); }
};

// no per-scene update after a reduction (a state evaluated, not stepped)
struct NoFinalize {
  CPS_HD void operator()(int) const {}
};

// stage 3 (one item per scene): dt from the fastest sphere (choose_dt), clipped to the end
// time, the kind's bookkeeping (the finalize hook), the clock; a step not taken (the end
// reached, a fault raised, sums not finite) has step_dt 0
template <int D, class Record, class Hook>
struct FinalizeStage {
  const SoftSpheres<D>* model;
  Record* g;
  Hook hook;
  CPS_HD void operator()(int) const {
    const SoftSpheres<D>& m = *model;
    Record& G = *g;
    Clock& C = G.clock;
    hook.begin(G);
    if (clock_at_end(C)) {
      G.step_dt = 0.0f;
      return;
    }
    if (C.bad) {
      if (C.bad_step < 0) C.bad_step = C.step;
      G.step_dt = 0.0f;
      return;
    }
    const auto& S = G.pending;
    if (!finite(S.vmax2) || !hook.sums_finite(S)) {
      C.bad = kBadParticles;
      C.bad_step = C.step + 1;
      G.step_dt = 0.0f;
      return;
    }
    bool last;
    const float dt = clip_to_end(C, choose_dt(m, S.vmax2), last);
    G.sums = S;
    // the forces of this step's state act over [time, time + dt]
    hook.taken(G, S, dt);
    G.step_dt = dt;
    advance_clock(C, dt, last);
  }
};

// stage 4: integrate (forward or symplectic Euler) in place, then the kind's boundaries (the
// integrate hook), the periodic span, the finite check
template <int D, class Record, class Hook>
struct IntegrateStage {
  const SoftSpheres<D>* model;
  Record* g;
  Arrays<D> s;
  Hook hook;
  CPS_HD void operator()(int i) const {
    const float dt = g->step_dt;
    if (!(dt > 0.0f)) return;  // a step not taken leaves the particles as they are
    const SoftSpheres<D>& m = *model;
    Vec<D> x = s.position[i], v = s.velocity[i];
    euler_step(m, s.force[i], dt, x, v);
    hook.after(i, dt, x, v);
    wrap_span(m, x);
    if constexpr (D == 2) {
      if (!finite(x[0] + x[1] + v[0] + v[1])) raise_first(&g->clock.bad, kBadParticles);
    } else {
      if (!finite(x[0] + x[1] + x[2] + v[0] + v[1] + v[2])) raise_first(&g->clock.bad, kBadParticles);
    }
    s.position[i] = x;
    s.velocity[i] = v;
  }
};

}  // namespace cps::dem
