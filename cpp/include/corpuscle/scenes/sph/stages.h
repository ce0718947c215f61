// The SPH box's stages: functors over the particles, the probes, or one item per scene.
// Nothing here knows which backend or which neighbour index runs it: the pair stage is a
// begin / visit / end stage (spatial/index.h) that every index runs.
#pragma once
#include "corpuscle/core/atomics.h"
#include "corpuscle/core/lanes.h"
#include "corpuscle/scenes/sph/probe.h"
#include "corpuscle/scenes/sph/tables.h"

namespace cps::sph {

CPS_HD CPS_INLINE void add_count(long long* p, long long v) {
#ifdef __CUDA_ARCH__
  atomicAdd(reinterpret_cast<unsigned long long*>(p), static_cast<unsigned long long>(v));
#else
  __atomic_fetch_add(p, v, __ATOMIC_RELAXED);
#endif
}

// stage 1: the current arrays gathered into cell order (order: sorted slot -> input slot),
// and the pressure of the sorted state from its density (Tait) with the pair loop's
// per-particle factors p / rho^2 and m / rho (the same operations the pair terms would do per
// pair: the same values). `lists`: on the steps that relist (*rebuild), the positions the
// lists are built from are kept in x_build; the other steps keep the order (slot j from slot
// j: their sort was skipped, and `order` is the last relisting's)
template <int D>
struct ReorderStage {
  const Model<D>* model;
  const int* order;
  Arrays<D> a;
  const int* rebuild = nullptr;  // `lists` only
  CPS_HD void operator()(int j) const {
    const int o = rebuild && *rebuild == 0 ? j : order[j];
    const Vec<D> x = a.position[o];
    const float rho = a.density[o];
    a.gather(j, o);  // every field that moves with the particle (tables.h)
    if (a.transport) a.transport_alt[j] = a.transport[o];  // (the transport velocity's, when on)
    const float p = tait_pressure(*model, rho);
    a.pressure[j] = p;
    const Vec<D> v = a.velocity[o];
    PairVel pv;
    for (int k = 0; k < 3; ++k) pv.v[k] = k < D ? v[k] : 0.0f;
    pv.pr2 = (p + model->p_back) / (rho * rho);  // (p_back: 0 unless fluid.background_pressure)
    VecA<D> x4 = VecA<D>::of(x);
    if constexpr (D == 3) x4.v[3] = rho;  // (the pair loop's rho_j: see InteractStage::visit)
    else a.pr[j] = PairRho{rho, model->mass / rho};
    a.rec[j] = PairRecord<D>{x4, pv};
    if (rebuild && *rebuild) a.x_build[j] = x;
  }
};

// `lists`: the next step relists (a new or replaced state, or grown lists)
struct RaiseRebuildStage {
  Scene* g;
  CPS_HD void operator()(int) const { g->rebuild = 1; }
};

// stage 2: the pair sums of particle i (the sorted arrays of `a`):
//   fluid i:  drho_i/dt = sum_j m_j v_ij . grad_i W_ij  (+ delta-SPH over fluid j)
//             dv_i/dt  = -sum_j m_j (p_i / rho_i^2 + p_j / rho_j^2) grad_i W_ij + viscosity + g
//             (Monaghan 1992, eqs. 2.7 and 3.3; the walls' particles are j like any other)
//   wall i:   drho_i/dt = sum_{fluid j} m_j v_ij . grad_i W_ij (DBC: Crespo et al. 2007), no motion
// Wall-wall pairs contribute nothing (neither moves). The per-particle items of the step's
// reductions are written here.
// the constants of the pair terms, copied out of the model (kernel parameters on CUDA: no
// load through the model's pointer per pair)
template <int D>
struct PairConsts {
  SphKernel<D> kern;  // the gradient kernel
  float mass, hs, c0;
  float eta2;  // 0.01 hs^2: the eta^2 of every pair term (mu_ij, both viscosities, the diffusion)
  int viscosity;
  ArtificialViscosity av;
  LaminarViscosity lv;
  DensityDiffusion dd;
  Vec<D> gravity;
  int shifting;  // grad C accumulated (particle shifting on)
  int moving_bodies;  // the walls' velocity enters the continuity equation (scenes with moving bodies)
  int tvf;       // the transport-velocity formulation (RuntimeTerms only)
  float tvf_pb;  // its background pressure
  static PairConsts make(const Model<D>& m) {
    // the terms were made from the same hs with the same expression (0.01f * hs * hs)
    if (m.av.eta2 != m.lv.eta2 || (m.dd.kind != DensityDiffusionKind::None && m.dd.eta2 != m.av.eta2) ||
        m.av.hs != m.hs)
      throw Error("sph: the pair terms' eta^2 or hs differ");
    return PairConsts{m.kernels.gradient, m.mass, m.hs, m.c0, m.av.eta2, m.viscosity, m.av, m.lv, m.dd, m.gravity,
                      m.shift_a > 0.0f ? 1 : 0, m.n_moving > 0 ? 1 : 0, m.tvf, m.tvf_pb};
  }
};

// the pair terms' choices: the model's, read per pair (RuntimeTerms: any model), or fixed at
// compile time to the default model's (DefaultTerms: Wendland C2, artificial viscosity,
// Fourtakas diffusion), which calls the same functions without the dispatch in the pair loop
struct RuntimeTerms {
  static constexpr bool kFixed = false;
};
struct DefaultTerms {
  static constexpr bool kFixed = true;
  template <int D>
  static bool matches(const Model<D>& m) {
    return m.kernels.gradient.kind == SphKernelKind::WendlandC2 && m.viscosity == kArtificialViscosity &&
           m.dd.kind == DensityDiffusionKind::Fourtakas && !(m.shift_a > 0.0f) && !m.tvf;
  }
};

// the pair sums the transport-velocity formulation adds (RuntimeTerms only: the fixed default
// terms' sums are an empty base, so their record and its lanes' shuffles are as without it)
template <int D, bool Fixed>
struct TvfSums {
  Vec<D> accb;   // the background pressure's push (sph_pair_terms.h, tvf_background_acc)
  Vec<D> dvt_i;  // v~_i - v_i, loaded in begin
};
template <int D>
struct TvfSums<D, true> {};

template <int D, class Terms = RuntimeTerms>
struct InteractStage {
  PairConsts<D> m;
  const Control* ctl;
  Arrays<D> a;
  int nf;
  // per wall particle (its id less nf): 1 for a free body's particle, which sums the fluid's
  // pressure and viscous terms as a fluid particle would (its acceleration: the fluid's force on
  // it over its mass, bodies.h); null without free bodies
  const int* free_wall = nullptr;

  // the sums of particle i, and what the pair loop reads of i (loaded once, in begin)
  struct Acc : TvfSums<D, Terms::kFixed> {
    Vec<D> acc;
    float drho;
    float mu_max;
    int nbrs;
    Vec<D> vel_i;
    float rho_i, pr2_i;
    Vec<D> gradc;  // sum_j V_j grad W_ij (particle shifting only)
    bool free_i;   // i is a free body's particle
  };

  CPS_HD Acc begin(int i) const {
    Acc s;
    s.acc = Vec<D>::zero();
    s.drho = 0.0f;
    s.mu_max = 0.0f;
    s.nbrs = 0;
    s.vel_i = a.velocity[i];
    s.rho_i = a.density[i];
    s.pr2_i = a.rec[i].pv.pr2;
    s.gradc = Vec<D>::zero();
    s.free_i = i >= nf && free_wall != nullptr && free_wall[a.id[i] - nf] != 0;
    if constexpr (!Terms::kFixed) {
      s.accb = Vec<D>::zero();
      s.dvt_i = m.tvf && i < nf ? a.transport[i] : Vec<D>::zero();
    }
    return s;
  }

  // (the square root and the divisions are the fast forms of core/hd.h: exact on the host)
  CPS_HD void visit(Acc& s, int i, int j, const Vec<D>& d, float r2) const {
    if (j == i) return;
    const bool fi = i < nf, fj = j < nf;
    if (!fi && !fj) return;
    const float r = fsqrt_fast(r2);
    Vec<D> gw;
    if constexpr (Terms::kFixed) gw = KernelFormula<D, SphKernelKind::WendlandC2>::grad(m.kern.k, d, r);
    else gw = m.kern.grad(d, r);
    const PairVel pv = a.rec[j].pv;  // (one vector load, from the sector the walk loaded)
    Vec<D> dv, dvc;
    for (int k = 0; k < D; ++k) {
      dv[k] = s.vel_i[k] - pv.v[k];
      // the continuity equation sees the particles' motion: a wall particle's is zero (a moving
      // wall's prescribed velocity, a lid sliding in its own plane, enters the viscous terms
      // only; for walls at rest the same values), except in scenes with moving bodies, whose
      // particles do move (bodies.h; such scenes have no sliding lids, and their walls at rest
      // carry zero)
      dvc[k] = (fi || m.moving_bodies ? s.vel_i[k] : 0.0f) - (fj || m.moving_bodies ? pv.v[k] : 0.0f);
    }
    // the transport-velocity formulation: the particles move with v~ = v + dv~ (the walls' dv~ is 0)
    [[maybe_unused]] Vec<D> dvt_j;
    if constexpr (!Terms::kFixed) {
      if (m.tvf) {
        dvt_j = fj ? a.transport[j] : Vec<D>::zero();
        dvc += s.dvt_i - dvt_j;
      }
    }
    s.drho += m.mass * dot(dvc, gw);
    if (!fi && !s.free_i) return;  // (a free body's particle: j is fluid, the walls gather the fluid only)
    s.nbrs += 1;
    // rho_j and V_j = m / rho_j: in 3-D rho_j rides in the padding of j's position (a line the
    // lists' walk has just loaded: one neighbour load fewer) and V_j is computed here with the
    // reorder's expression (an IEEE division on both backends: the same value); in 2-D both
    // come from PairRho
    float rho_j, vol_j;
    if constexpr (D == 3) {
      rho_j = a.rec[j].x.v[3];
      vol_j = m.mass / rho_j;
    } else {
      const PairRho pr = a.pr[j];
      rho_j = pr.rho;
      vol_j = pr.vol;
    }
    if constexpr (!Terms::kFixed)
      if (m.shifting) s.gradc += gw * vol_j;
    const float rho_i = s.rho_i;
    // 1 / (r^2 + eta^2) and v_ij . r_ij, once for every term (each term's eta^2 is the same
    // 0.01 hs^2, PairConsts::make: so this is the value each would compute)
    const float den = r2 + m.eta2;
    const float inv_den = sph_inv_den(r2, m.eta2);
    const float vr = dot(dv, d);
    const float mu = sph_mu_inv(m.hs, vr, inv_den);
    s.mu_max = fmax2(s.mu_max, mu < 0.0f ? -mu : mu);
    if (fi && fj) {
      if constexpr (Terms::kFixed)
        s.drho += density_diffusion_rate_k<D, DensityDiffusionKind::Fourtakas>(m.dd, d, inv_den, rho_i, rho_j, vol_j, gw);
      else
        s.drho += density_diffusion_rate_v<D>(m.dd, d, inv_den, rho_i, rho_j, vol_j, gw);
    }
    // p_i / rho_i^2 + p_j / rho_j^2 (each computed once per particle, in the reorder)
    const float pterm = s.pr2_i + pv.pr2;
    s.acc -= gw * (m.mass * pterm);
    if (Terms::kFixed || m.viscosity == kArtificialViscosity)
      s.acc += artificial_viscosity_acc_mu<D>(m.av, vr, mu, m.c0, m.c0, rho_i, rho_j, m.mass, gw);
    else
      s.acc += laminar_viscosity_acc_den<D>(m.lv, d, dv, den, rho_i, rho_j, m.mass, gw);
    if constexpr (!Terms::kFixed) {
      if (m.tvf) {
        const float vol_i = m.mass / rho_i;
        Vec<D> v_j;
        for (int k = 0; k < D; ++k) v_j[k] = pv.v[k];
        s.acc += tvf_stress_acc<D>(rho_i, s.vel_i, s.dvt_i, rho_j, v_j, dvt_j, vol_i, vol_j, m.mass, gw);
        s.accb += tvf_background_acc<D>(m.tvf_pb, vol_i, vol_j, m.mass, gw);
      }
    }
  }

  // b's pair sums added to a's (lanes sharing a particle's list: a holds the lower lane's)
  CPS_HD void merge(Acc& a, const Acc& b) const {
    a.acc += b.acc;
    a.drho += b.drho;
    a.mu_max = fmax2(a.mu_max, b.mu_max);
    a.nbrs += b.nbrs;
    a.gradc += b.gradc;
    if constexpr (!Terms::kFixed) a.accb += b.accb;
  }

  CPS_HD void end(int i, Acc& s) const {
    StepSums it = StepSums::identity();
    it.p_max = a.pressure[i];
    if (i < nf) {
      Vec<D> acc = s.acc + m.gravity;
      for (int k = 0; k < D; ++k) acc[k] += ctl->acc[k];
      a.acceleration[i] = acc;
      if (m.shifting) a.shift_grad[i] = s.gradc;
      if constexpr (!Terms::kFixed)
        if (m.tvf) a.transport_acc[i] = s.accb;
      const Vec<D> v = s.vel_i;
      it.amax2 = norm2(acc);
      it.vmax2 = norm2(v);
      it.mu_max = s.mu_max;
      it.ke = 0.5f * m.mass * it.vmax2;
      it.rho_min = it.rho_max = s.rho_i;
      it.nbrs = s.nbrs;
      if (!finite(it.amax2 + s.drho)) it.bad = 1;
    } else {
      a.acceleration[i] = s.free_i ? s.acc : Vec<D>::zero();  // (a free body's: the fluid's alone)
      if (!finite(s.drho + (s.free_i ? norm2(s.acc) : 0.0f))) it.bad = 1;
    }
    a.density_rate[i] = s.drho;
    // a halo slot (a copy of another rank's particle: scenes/sph/ranks.h) adds nothing to the
    // step's reductions: its owner counts it
    a.items[i] = a.halo[i] ? StepSums::identity() : it;
  }
};

// the pair stage through the cell grid, one thread per particle (GatherStageFn of
// spatial/index.h, except that a wall particle gathers from the fluid's cells only: wall-wall
// pairs contribute nothing, so the sums and their order are those of the full walk)
template <int D, class Stage>
struct GridGatherFn {
  CellGridView<D> view;
  Stage stage;
  int nf;
  int base;  // the first slot: the fluid and the walls run as two loops, each spread evenly over
             // the threads (one loop over both would give one thread the fluid, another the walls)
  CPS_HD void operator()(int k) const {
    const int i = base + k;
    auto acc = stage.begin(i);
    const CellGridView<D> v = i < nf ? view : view.tags(kTagFluid, kTagFluid + 1);
    v.gather(i, v.position(i), [&](int j, const Vec<D>& d, float r2) { stage.visit(acc, i, j, d, r2); });
    stage.end(i, acc);
  }
};

// the pair stage through the `lists` index (slot lists, spatial/neighbor_list.h), one thread per
// slot from `base` (the fluid and the walls as two loops, as GridGatherFn)
template <class View, class Stage>
struct ListGatherFn {
  View view;
  Stage stage;
  int base;
  CPS_HD void operator()(int k) const {
    const int i = base + k;
    auto acc = stage.begin(i);
    view.gather(i, view.position(i), [&](int j, const Vec<View::kDim>& d, float r2) { stage.visit(acc, i, j, d, r2); });
    stage.end(i, acc);
  }
};

// the same with G lanes per slot (G = 2, 4 or 8; `sph.lanes`): lane l walks the list entries
// l, l + G, ... of the slot (SlotListView::gather_lane) into its own partial sums, and the G
// partial sums are merged in a fixed butterfly (offsets G/2, G/4, ..., 1; lane l takes lane
// l + o's at offset o), so a slot's sums are the same on every run. On CUDA the G lanes are G
// threads of a warp and the butterfly is made of shuffles; the CPU runs the G lanes one after
// another and merges them in the same order (so the CPU and CUDA sum the same terms in the
// same order, up to the device's fast square root and divisions).
template <int G, class View, class Stage>
struct ListGatherLanesFn {
  static_assert(G >= 2 && G <= 32 && (G & (G - 1)) == 0, "lanes per slot: a power of two from 2 to 32");
  View view;
  Stage stage;
  int base;
  // lane l's partial sums of slot i
  CPS_HD auto partial(int i, int l) const {
    auto acc = stage.begin(i);
    view.template gather_lane<G>(i, view.position(i), l,
                                 [&](int j, const Vec<View::kDim>& d, float r2) { stage.visit(acc, i, j, d, r2); });
    return acc;
  }
  // the CPU: the G lanes in turn, merged in the butterfly's order
  CPS_HD void operator()(int k, const SingleLane&) const {
    const int i = base + k;
    decltype(stage.begin(i)) acc[G];
    for (int l = 0; l < G; ++l) acc[l] = partial(i, l);
    for (int o = G / 2; o > 0; o >>= 1)
      for (int l = 0; l < o; ++l) stage.merge(acc[l], acc[l + o]);
    stage.end(i, acc[0]);
  }
#ifdef __CUDACC__
  // CUDA: G threads of a warp, merged by shuffles (lane 0 ends the slot)
  __device__ void operator()(int k, const SubWarpLanes<G>& L) const {
    const int i = base + k;
    auto acc = partial(i, L.lane());
    for (int o = G / 2; o > 0; o >>= 1) stage.merge(acc, L.shfl_xor(acc, o));
    if (L.leader()) stage.end(i, acc);
  }
#endif
};

// stage 3 (one thread per probe): pressure and velocity of each probe (probe.h's
// probe_reading: Shepard's kernel interpolation over the fluid at the point, or averaged over
// the face's sample points; DualSPHysics's MeasureTool); no fluid within the support: 0
// (probe_w = 0 says so)
template <int D, class View>
struct ProbeStage {
  const Model<D>* model;
  Scene* g;
  Arrays<D> a;
  View view;  // over the sorted positions
  int nf;
  CPS_HD void operator()(int k) const {
    float p, v[3], w;
    probe_reading(*model, view, a, nf, k, p, v, w);
    g->probe_w[k] = w;
    g->probe_p[k] = p;
    for (int c = 0; c < 3; ++c) g->probe_v[3 * k + c] = v[c];
    if (k == 0) g->probe_time = g->clock.time;
  }
};

// stage 4 (one item per scene): the CFL dt (choose_dt_cfl), the clock
template <int D>
struct FinalizeStage {
  const Model<D>* model;
  Scene* g;
  bool lists = false;  // `lists`: count the step's relisting and lower the flag for the next one
  CPS_HD void operator()(int) const {
    const Model<D>& m = *model;
    Scene& G = *g;
    Clock& C = G.clock;
    if (clock_at_end(C)) {
      G.step_dt = 0.0f;
      return;
    }
    if (C.bad) {
      if (C.bad_step < 0) C.bad_step = C.step;
      G.step_dt = 0.0f;
      return;
    }
    const StepSums& S = G.pending;
    if (S.bad != 0 || !finite(S.amax2 + S.mu_max + S.vmax2)) {
      C.bad = kBadParticles;
      C.bad_step = C.step + 1;
      G.step_dt = 0.0f;
      return;
    }
    bool last;
    const float dt = clip_to_end(C, choose_dt_cfl(m.cfl, m.hs, fsqrt(S.amax2), m.c0, S.mu_max, m.laminar_nu(), m.dt_min, m.dt_max),
                                 last);
    G.sums = S;
    if (G.outside > G.outside_max) G.outside_max = G.outside;
    G.outside = 0;
    G.step_dt = dt;
    if (lists) {
      G.rebuilds += G.rebuild != 0 ? 1 : 0;
      G.rebuild = 0;  // this step's readers are done with it; the integration may raise it again
    }
    advance_clock(C, dt, last);
  }
};

// the moving bodies' poses at the clock's time (one item a scene; bodies.h, in double)
template <int D>
struct BodyPoseStage {
  const Model<D>* model;
  Scene* g;
  const float* table;  // the motion tables' rows (kBodyTableCols floats each)
  CPS_HD void operator()(int) const {
    const Model<D>& m = *model;
    for (int b = 0; b < m.n_moving; ++b) {
      double p[kBodyPoseFloats];
      if (m.motion[b].kind == kBodyFree) free_body_pose(g->free_state + b * kFreeStateDoubles, p);
      else body_pose(m.motion[b], table, g->clock.time, p);
      for (int k = 0; k < kBodyPoseFloats; ++k) g->body_pose[b * kBodyPoseFloats + k] = float(p[k]);
    }
  }
};

// a moving body's particles (wall slots) at its pose: position, velocity (and the previous
// step's, unused by the walls' integration). `body` and `local` are indexed by the wall's id
// (its slot at the build, less n_fluid): the body (-1: a tank wall or a fixed body) and the
// offset in the body's frame. `lists`: a particle moved more than skin h / 2 since the build
// raises the next step's relisting, as the integration does for the fluid
template <int D>
struct BodyParticlesStage {
  const Model<D>* model;
  Scene* g;
  Arrays<D> a;
  const int* body;
  const float* local;
  int nf;
  CPS_HD void operator()(int k) const {
    const int i = nf + k;
    const int w = a.id[i] - nf;
    const int b = body[w];
    if (b < 0) return;
    Vec<D> x, v;
    body_point<D>(g->body_pose + b * kBodyPoseFloats, local + 3 * w, x, v);
    a.position[i] = x;
    a.velocity[i] = v;
    a.velocity_prev[i] = v;
    const Model<D>& m = *model;
    if (a.x_build && norm2(m.per.displacement(x - a.x_build[i])) > m.rebuild_disp2 && g->rebuild == 0)
      atomic_max(&g->rebuild, 1);
  }
};

// a free body's particles' shares of its force and torque (wall slots; `body` by the wall's id):
// item w = (m a, (x - c) x m a), a the fluid's acceleration on the particle (the pair stage)
// plus the tank's contact (tank_contact), c the body's centre of mass; reduced per body over its
// wall ids [w0, w0 + nw) (the pipeline's body_forces: in the walls' build order, so the sums do
// not depend on the sort)
template <int D>
struct BodyForceStage {
  const Model<D>* model;
  const Scene* g;
  Arrays<D> a;
  const int* body;
  BodyItem* items;
  int nf;
  CPS_HD void operator()(int k) const {
    const int i = nf + k;
    const int w = a.id[i] - nf;
    const int b = body[w];
    const Model<D>& m = *model;
    if (b < 0 || m.motion[b].kind != kBodyFree) return;
    const Vec<D> x = a.position[i];
    const Vec<D> acc =
        a.acceleration[i] + tank_contact<D>(m.lo, m.hi, int(m.per.mask), m.contact_r0, m.contact_k, m.contact_c, x, a.velocity[i]);
    const double* st = g->free_state + b * kFreeStateDoubles;
    double f[3] = {0.0, 0.0, 0.0}, q[3] = {0.0, 0.0, 0.0};
    for (int c = 0; c < D; ++c) {
      f[c] = double(m.mass) * double(acc[c]);
      q[c] = double(x[c]) - st[c];
    }
    BodyItem it;
    for (int c = 0; c < 3; ++c) it.f[c] = f[c];
    it.t[0] = q[1] * f[2] - q[2] * f[1];
    it.t[1] = q[2] * f[0] - q[0] * f[2];
    it.t[2] = q[0] * f[1] - q[1] * f[0];
    items[w] = it;
  }
};

// the free bodies' step (one item a scene; bodies.h's free_body_step with the step's dt), after
// the fluid's integration: their force and torque of this step's state, gravity and the box's
// control acceleration
template <int D>
struct FreeBodyStage {
  const Model<D>* model;
  Scene* g;
  const Control* ctl;
  CPS_HD void operator()(int) const {
    const double dt = double(g->step_dt);
    if (!(dt > 0.0)) return;
    const Model<D>& m = *model;
    double gv[3] = {0.0, 0.0, 0.0};
    for (int k = 0; k < D; ++k) gv[k] = double(m.gravity[k]) + double(ctl->acc[k]);
    for (int b = 0; b < m.n_moving; ++b) {
      if (m.motion[b].kind != kBodyFree) continue;
      double* st = g->free_state + b * kFreeStateDoubles;
      const double* F = g->body_force + b * kBodyForceDoubles;
      free_body_step(m.motion[b], st, F, F + 3, gv, dt, m.integrator == kSymplecticEuler, D);
      double sum = 0.0;
      for (int k = 0; k < kFreeStateDoubles; ++k) sum += st[k];
      if (!(sum - sum == 0.0)) raise_first(&g->clock.bad, kBadParticles);
    }
  }
};

// stage 5: the Verlet scheme (Monaghan 1994; DualSPHysics's default, Crespo et al. 2015, eqs. 17-19)
//   v^{n+1} = v^{n-1} + 2 dt a^n,  x^{n+1} = x^n + dt v^n + dt^2 a^n / 2,  rho^{n+1} = rho^{n-1} + 2 dt drho^n
// with an Euler step (v^{n+1} = v^n + dt a^n, rho^{n+1} = rho^n + dt drho^n) every verlet_steps
// steps, which keeps the two interleaved solutions together; or symplectic Euler (v += a dt,
// x += v dt, rho += drho dt). Walls: their density only, never below rho0 (DBC). Fluid outside
// the box is counted.
template <int D>
struct IntegrateStage {
  const Model<D>* model;
  Scene* g;
  Arrays<D> a;
  int nf;
  CPS_HD void operator()(int i) const {
    const float dt = g->step_dt;
    if (!(dt > 0.0f)) return;  // a step not taken leaves the particles as they are
    if (a.halo[i]) return;     // a halo slot is its owner's to move (scenes/sph/ranks.h)
    const Model<D>& m = *model;
    // the step counter is already this step's (finalize advanced it): steps 1, 1 + N, ... are Euler
    const bool euler = m.integrator == kSymplecticEuler || (g->clock.step - 1) % m.verlet_steps == 0;
    const float rho0 = a.density[i], rhom = a.density_prev[i];
    float rho = euler ? rho0 + a.density_rate[i] * dt : rhom + 2.0f * dt * a.density_rate[i];
    if (i >= nf) {
      a.density_prev[i] = rho0;
      a.density[i] = rho < m.rho0 ? m.rho0 : rho;
      return;
    }
    const Vec<D> v0 = a.velocity[i], acc = a.acceleration[i];
    Vec<D> v, x;
    if (m.integrator == kSymplecticEuler) {
      v = v0 + acc * dt;
      x = a.position[i] + v * dt;
    } else {
      v = euler ? v0 + acc * dt : a.velocity_prev[i] + acc * (2.0f * dt);
      x = a.position[i] + v0 * dt + acc * (0.5f * dt * dt);
    }
    if (m.tvf) {  // the transport velocity: the background push over the step (dv~ = dt / 2 a~)
      const Vec<D> dvt = a.transport_acc[i] * (0.5f * dt);
      x += dvt * dt;
      a.transport[i] = dvt;
    }
    if (m.shift_a > 0.0f)  // particle shifting: -A hs |v| dt grad C
      x -= a.shift_grad[i] * (m.shift_a * m.hs * fsqrt(norm2(v0)) * dt);
    x = m.per.wrap(x);  // periodic axes: back into the box
    a.velocity_prev[i] = v0;
    a.density_prev[i] = rho0;
    a.velocity[i] = v;
    a.position[i] = x;
    a.density[i] = rho;
    bool out = false;
    float sum = rho;
    for (int k = 0; k < D; ++k) {
      out = out || x[k] < m.lo[k] || x[k] > m.hi[k];
      sum += x[k] + v[k];
    }
    if (out) add_count(&g->outside, 1);
    // `lists`: moved more than skin h / 2 since the build (the minimum image across a periodic
    // face): the next step relists
    if (a.x_build && norm2(m.per.displacement(x - a.x_build[i])) > m.rebuild_disp2 && g->rebuild == 0)
      atomic_max(&g->rebuild, 1);
    if (!finite(sum)) raise_first(&g->clock.bad, kBadParticles);
  }
};

}  // namespace cps::sph
