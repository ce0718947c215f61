// The wind tunnel's stages: functors over the particles (lanes of width 1: for_each) or one
// item per scene. Nothing here knows which backend runs it.
#pragma once
#include "corpuscle/core/atomics.h"
#include "corpuscle/scenes/wind_tunnel/model.h"
#include "corpuscle/spatial/allpairs.h"
#include "corpuscle/spatial/lbvh.h"

namespace cps::wt {


CPS_HD CPS_INLINE void add_count(long long* p, long long v) {
#ifdef __CUDA_ARCH__
  atomicAdd(reinterpret_cast<unsigned long long*>(p), static_cast<unsigned long long>(v));
#else
  __atomic_fetch_add(p, v, __ATOMIC_RELAXED);
#endif
}


// counter-based random numbers: a pure function of (seed, particle id, step, stream), so
// every backend and thread count draws the same ones (lowbias32, C. Wellons 2018)
CPS_HD CPS_INLINE uint32_t mix32(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352du;
  x ^= x >> 15;
  x *= 0x846ca68bu;
  x ^= x >> 16;
  return x;
}
// uniform in (0, 1)
CPS_HD CPS_INLINE float uniform01(unsigned seed, int id, long long step, int stream) {
  uint32_t h = mix32(seed ^ mix32(uint32_t(step) ^ mix32(uint32_t(step >> 32) + 0x9e3779b9u)));
  // streams 0..3 mix as (id, stream); higher ones add a block term (mix32(0) = 0: none for 0..3)
  h = mix32(h ^ mix32(uint32_t(id) * 4u + uint32_t(stream & 3)) ^ mix32(uint32_t(stream >> 2) * 0x9e3779b9u));
  return (float(h >> 8) + 0.5f) * (1.0f / 16777216.0f);
}

// The normal velocity of a particle crossing a plane into a drifting Maxwellian gas: the
// flux-weighted distribution f(z) ~ z exp(-(z - s)^2), z > 0, of z = u / c_m (c_m =
// sqrt(2 kT / m), s = U / c_m the speed ratio; Bird 1994, sec. 12.5, eq. 12.21 and Garcia &
// Wagner, J. Comput. Phys. 217, 693 (2006)). With w = z - s the density (s + w) exp(-w^2) on
// w > -s splits into three positive parts, drawn by composition:
//   w > 0:   s exp(-w^2)         weight s sqrt(pi) / 2           half-normal, exact
//   w > 0:   w exp(-w^2)         weight 1 / 2                    w = sqrt(-ln u), exact
//   -s<w<0:  (s - |w|) exp(-w^2) weight s sqrt(pi)/2 erf(s) - (1 - exp(-s^2)) / 2
//            rejection from t = |w| uniform on (0, s), accepted with (1 - t/s) exp(-t^2)
//            (acceptance >= 0.24 for every s; 48 tries, then the part's mean, never reached
//            in practice: probability < 1e-5)
// Random streams first_stream ... first_stream + 2 + 2 * 48 of (seed, id, step) are used.
CPS_HD CPS_INLINE float flux_weighted_speed_ratio(float s, unsigned seed, int id, long long step, int first) {
  const float sqpi2 = 0.88622692545f;  // sqrt(pi) / 2
  const float W1 = s * sqpi2, W2 = 0.5f;
  const float W3 = fmax2(s * sqpi2 * ferf(s) - 0.5f * (1.0f - fexp(-s * s)), 0.0f);
  const float pick = uniform01(seed, id, step, first) * (W1 + W2 + W3);
  const float a = uniform01(seed, id, step, first + 1), b = uniform01(seed, id, step, first + 2);
  float w;
  if (pick < W1) {
    const float c = fcos(2.0f * kPi * b);
    w = fsqrt(-flog(a)) * (c < 0.0f ? -c : c);
  } else if (pick < W1 + W2) {
    w = fsqrt(-flog(a));
  } else {
    w = -s / 3.0f;  // the part's mean (fallback)
    for (int k = 0; k < 48; ++k) {
      const float t = s * uniform01(seed, id, step, first + 3 + 2 * k);
      if (uniform01(seed, id, step, first + 4 + 2 * k) < (1.0f - t / s) * fexp(-t * t)) {
        w = -t;
        break;
      }
    }
  }
  return s + w;
}

// the fastest particle moves at most dt_fraction radii per step, and dt <= dt_max
CPS_HD CPS_INLINE float choose_dt(const Model& m, float vmax2) {
  float v = fsqrt(vmax2);
  float dt = m.dt_max;
  if (v > 0.0f) dt = fmin2(dt, m.dt_fraction * m.radius / v);
  return dt;
}

// stage 1: the current arrays gathered into cell order (order: sorted slot -> input slot;
// null: a plain copy, for a collisionless gas that needs no index)
struct ReorderStage {
  const int* order;
  Arrays a;
  CPS_HD void operator()(int j) const {
    int o = order ? order[j] : j;
    a.pos_alt[j] = a.pos[o];
    a.vel_alt[j] = a.vel[o];
    a.id_alt[j] = a.id[o];
    a.scattered_alt[j] = a.scattered[o];
  }
};

// the airfoil as the control pitches it: the built polygon turned nose up by u.pitch degrees
// about the quarter chord (clockwise for a flow along +x, as airfoils.place turns it). The
// contact is found in the polygon's built frame, x_b = q + R (x - q), R the counter-clockwise
// rotation by the pitch, and its force and point turned back; at zero pitch every map is the
// identity (no rounding: an unpitched run is bitwise what it was before the control existed)
struct AirfoilFrame {
  bool pitched;
  float c, s;  // cos, sin of the pitch
  Vec2 q;      // the pivot (the quarter chord)
  CPS_HD CPS_INLINE Vec2 dir_to_body(const Vec2& d) const {
    return pitched ? Vec2{{c * d[0] - s * d[1], s * d[0] + c * d[1]}} : d;
  }
  CPS_HD CPS_INLINE Vec2 dir_to_world(const Vec2& d) const {
    return pitched ? Vec2{{c * d[0] + s * d[1], -s * d[0] + c * d[1]}} : d;
  }
  CPS_HD CPS_INLINE Vec2 to_body(const Vec2& x) const { return pitched ? q + dir_to_body(x - q) : x; }
  CPS_HD CPS_INLINE Vec2 to_world(const Vec2& x) const { return pitched ? q + dir_to_world(x - q) : x; }
};
CPS_HD CPS_INLINE AirfoilFrame airfoil_frame(const Model& m, const Control& u) {
  AirfoilFrame f;
  f.pitched = u.pitch != 0.0f;
  const float a = u.pitch * (kPi / 180.0f);
  f.c = f.pitched ? fcos(a) : 1.0f;
  f.s = f.pitched ? fsin(a) : 0.0f;
  f.q = m.quarter_chord;
  return f;
}

// the contact force on particle i from the two walls and the airfoil; adds the reaction on
// the airfoil (force, moment about the quarter chord) to s
CPS_HD CPS_INLINE Vec2 boundary_forces(const Model& m, const AirfoilFrame& af, const Vec2& x, const Vec2& v,
                                       float& pressure, int& contacts, StepSums& s, int& scattered) {
  Vec2 F = Vec2::zero();
  Vec2 f;
  float mag;
  const Vec2 up{{0.0f, 1.0f}}, down{{0.0f, -1.0f}};
  if (wall_contact_force<2>(m.wall, x[1] - m.lo[1], up, v, m.radius, Vec2::zero(), f, mag)) {
    F += f;
    s.wall_force += f;
    pressure += mag;
    contacts += 1;
  }
  if (wall_contact_force<2>(m.wall, m.hi[1] - x[1], down, v, m.radius, Vec2::zero(), f, mag)) {
    F += f;
    s.wall_force += f;
    pressure += mag;
    contacts += 1;
  }
  const Vec2 xb = af.to_body(x);
  if (m.n_edges > 0 && box_distance2(m.bbox, xb) < m.radius * m.radius) {
    PolygonHit hit;
    if (polygon_contact_force(m.wing, m.airfoil_grid(), xb, af.dir_to_body(v), m.radius, f, mag, hit)) {
      f = af.dir_to_world(f);
      F += f;
      pressure += mag;
      contacts += 1;
      // the airfoil gets -f, applied at the contact point
      Vec2 fa = -f;
      Vec2 r = af.to_world(hit.closest) - m.quarter_chord;
      s.force += fa;
      s.moment += r[0] * fa[1] - r[1] * fa[0];
      s.contacts += 1;
      scattered = 1;
    }
  }
  return F;
}

// the number density around x: the particles in the 3 x 3 cells of `spec` around x's cell,
// itself excluded, over the block's area (cells inside the grid); from the cell ranges on
// the grid, by testing every particle's cell with the all-pairs index (the same count)
CPS_HD CPS_INLINE float block_density(const CellGridView<D>& grid, const CellGridSpec<D>&, const Vec2& x) {
  int count, cells;
  grid.block_count(x, count, cells);
  return float(count - 1) / (float(cells) * grid.spec.cell * grid.spec.cell);
}
CPS_HD CPS_INLINE float block_density(const AllPairsView<D>& all, const CellGridSpec<D>& spec, const Vec2& x) {
  int c[D], cj[D];
  spec.cell_of(x, c);
  int count = 0;
  for (int j = 0; j < all.n; ++j) {
    spec.cell_of(all.pos[j], cj);
    const int dx = cj[0] - c[0], dy = cj[1] - c[1];
    count += (dx >= -1 && dx <= 1 && dy >= -1 && dy <= 1) ? 1 : 0;
  }
  int cells = 0;
  for (int y = c[1] - 1; y <= c[1] + 1; ++y)
    for (int xx = c[0] - 1; xx <= c[0] + 1; ++xx)
      cells += (xx >= 0 && xx < spec.dims[0] && y >= 0 && y < spec.dims[1]) ? 1 : 0;
  return float(count - 1) / (float(cells) * spec.cell * spec.cell);
}

// the tree: one box query of the 3 x 3 cells (a little wider), each slot found counted when its
// cell is in the block. With a visitor (the contact gather), the same walk also visits every
// slot of the contact reach: the query box is the union of the block's and the reach's (the
// block holds the reach unless x lies outside the grid), a slot is a contact candidate when
// it lies in the reach's box (as in gather), and the walk meets those slots in the order
// gather would (the tree's order does not depend on the box): one walk instead of two, the
// same contacts summed in the same order
template <class Visit>
CPS_HD CPS_INLINE float tree_block_density(const LbvhView<D>& tree, const CellGridSpec<D>& spec, int i, const Vec2& x,
                                           Visit* contact) {
  int c[D], cj[D];
  spec.cell_of(x, c);
  float qlo[D], qhi[D], rlo[D], rhi[D];
  for (int k = 0; k < D; ++k) {
    qlo[k] = spec.origin[k] + float(c[k] - 1) * spec.cell - 1e-3f * spec.cell;
    qhi[k] = spec.origin[k] + float(c[k] + 2) * spec.cell + 1e-3f * spec.cell;
    rlo[k] = x[k] - tree.radius;
    rhi[k] = x[k] + tree.radius;
    if (contact) {
      qlo[k] = fmin2(qlo[k], rlo[k]);
      qhi[k] = fmax2(qhi[k], rhi[k]);
    }
  }
  const float r2 = tree.radius * tree.radius;
  int count = 0;
  tree.query_box(qlo, qhi, [&](int j) {
    const Vec2 pj = tree.pos[j];
    if (contact) {
      bool in = true;
      for (int k = 0; k < D; ++k) in = in && pj[k] >= rlo[k] && pj[k] <= rhi[k];
      if (in) {
        const Vec2 d = x - pj;
        const float rr = norm2(d);
        if (rr < r2) (*contact)(j, d, rr);
      }
    }
    spec.cell_of(pj, cj);
    const int dx = cj[0] - c[0], dy = cj[1] - c[1];
    count += (dx >= -1 && dx <= 1 && dy >= -1 && dy <= 1) ? 1 : 0;
  });
  (void)i;
  int cells = 0;
  for (int y = c[1] - 1; y <= c[1] + 1; ++y)
    for (int xx = c[0] - 1; xx <= c[0] + 1; ++xx)
      cells += (xx >= 0 && xx < spec.dims[0] && y >= 0 && y < spec.dims[1]) ? 1 : 0;
  return float(count - 1) / (float(cells) * spec.cell * spec.cell);
}
struct NoContactVisit {
  CPS_HD void operator()(int, const Vec2&, float) const {}
};
CPS_HD CPS_INLINE float block_density(const LbvhView<D>& tree, const CellGridSpec<D>& spec, const Vec2& x) {
  return tree_block_density(tree, spec, -1, x, static_cast<NoContactVisit*>(nullptr));
}

// the contacts by gather (visit(j, x - x_j, r2) for every slot of the contact reach, i
// included) and the number density around x: the index's gather, then its block count; the
// tree does both in one walk (tree_block_density)
template <class View, class Visit>
CPS_HD CPS_INLINE float gather_and_density(const View& view, const CellGridSpec<D>& spec, int i, const Vec2& x,
                                           Visit& visit) {
  view.gather(i, x, visit);
  return block_density(view, spec, x);
}
template <class Visit>
CPS_HD CPS_INLINE float gather_and_density(const LbvhView<D>& tree, const CellGridSpec<D>& spec, int i, const Vec2& x,
                                           Visit& visit) {
  return tree_block_density(tree, spec, i, x, &visit);
}

// the reflexive form, stage 2a: the per-particle contact sums zeroed
struct ZeroContactsStage {
  Arrays s;
  CPS_HD void operator()(int i) const {
    s.force[i] = Vec2::zero();
    s.pressure[i] = 0.0f;
    s.contacts[i] = 0;
  }
};

// the reaction (fx, fy), its magnitude and one contact added to particle j. Warp-aggregated
// (the seed's option, on the device): the lanes of a warp adding to the same j at this moment
// (__match_any_sync over j) sum their values by shuffles and one of them adds the sum, so a
// particle hit by several lanes takes one atomic per component instead of one per lane. On the
// CPU, and with aggregate off, one atomic each.
CPS_HD CPS_INLINE void add_reaction(const Arrays& s, int j, float fx, float fy, float mag, bool aggregate) {
#ifdef __CUDA_ARCH__
  if (aggregate) {
    const unsigned active = __activemask();
    const unsigned peers = __match_any_sync(active, j);
    const int lane = int(threadIdx.x & 31u);
    float sx = 0.0f, sy = 0.0f, sm = 0.0f;
    unsigned rest = peers;
    while (rest) {  // every peer runs the same loop: the shuffles see the whole group
      const int src = __ffs(int(rest)) - 1;
      rest &= rest - 1u;
      sx += __shfl_sync(peers, fx, src);
      sy += __shfl_sync(peers, fy, src);
      sm += __shfl_sync(peers, mag, src);
    }
    if (lane == __ffs(int(peers)) - 1) {
      atomicAdd(&s.force[j][0], sx);
      atomicAdd(&s.force[j][1], sy);
      atomicAdd(&s.pressure[j], sm);
      atomicAdd(&s.contacts[j], __popc(peers));
    }
    return;
  }
#endif
  (void)aggregate;
  atomic_add(&s.force[j][0], fx);
  atomic_add(&s.force[j][1], fy);
  atomic_add(&s.pressure[j], mag);
  atomic_add(&s.contacts[j], 1);
}

// stage 2b: each overlapping pair once, from its lower slot (view.pairs); the force on i is
// summed locally, the reaction on j and i's sum added with atomics (float atomics: the sums'
// order, and so their last bits, vary from run to run on parallel backends)
template <class View>
struct PairStage {
  const Model* model;
  const Scene* g;
  Arrays s;
  View view;
  CPS_HD void operator()(int i) const {
    if (halted(g)) return;
    const Model& m = *model;
    const Vec2 x = s.pos[i], v = s.vel[i];
    const float r = m.radius;
    Vec2 F = Vec2::zero();
    float pressure = 0.0f;
    int contacts = 0;
    view.pairs(i, x, [&](int j, const Vec2&, float) {
      Vec2 f;
      float mag;
      if (pair_contact_force<2>(m.pp, x, v, r, s.pos[j], s.vel[j], r, f, mag)) {
        F += f;
        pressure += mag;
        contacts += 1;
        add_reaction(s, j, -f[0], -f[1], mag, m.reflexive == 2);
      }
    });
    if (contacts > 0) {
      atomic_add(&s.force[i][0], F[0]);
      atomic_add(&s.force[i][1], F[1]);
      atomic_add(&s.pressure[i], pressure);
      atomic_add(&s.contacts[i], contacts);
    }
  }
};

// stage 2: contact forces by gather over the index (the cell grid, or every particle for
// the all-pairs reference; each particle sums its own: no atomics, the same sum in the same
// order on every backend), walls, airfoil; the per-particle items of the step's reductions
template <class View>
struct ForceStage {
  const Model* model;
  const Scene* g;
  const Control* ctl;
  Arrays s;
  View grid;
  CellGridSpec<D> spec;  // the cells the number density counts in
  CPS_HD void operator()(int i) const {
    if (halted(g)) return;  // the reduction of a step not taken is discarded
    const Model& m = *model;
    const Vec2 x = s.pos[i], v = s.vel[i];
    Vec2 F = Vec2::zero();
    float pressure = 0.0f;
    int contacts = 0;
    const Vec2* pos = s.pos;
    const Vec2* vel = s.vel;
    const float r = m.radius;
    const SpringDashpot law = m.pp;
    float density = 0.0f;
    auto pair = [&](int j, const Vec2&, float) {
      if (j == i) return;
      Vec2 f;
      float mag;
      if (pair_contact_force<2>(law, x, v, r, pos[j], vel[j], r, f, mag)) {
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
      density = gather_and_density(grid, spec, i, x, pair);
    }
    StepSums it = StepSums::identity();
    int scattered = s.scattered[i];
    F += boundary_forces(m, airfoil_frame(m, *ctl), x, v, pressure, contacts, it, scattered);
    s.scattered[i] = scattered;
    s.number_density[i] = density;
    it.total_force = F;
    it.vmax2 = norm2(v);
    it.ke = 0.5f * m.mass * it.vmax2;
    s.force[i] = F;
    s.pressure[i] = pressure;
    s.contacts[i] = contacts;
    s.items[i] = it;
  }
};

// the block averages: add this step's airfoil force over dt; a full block is closed, and
// when all kMaxBlocks are full adjacent pairs are merged and the block length doubles
// (batch means with a growing batch: the standard error stays honest for correlated series)
CPS_HD CPS_INLINE void accumulate_blocks(Scene& G, const StepSums& S, double dt) {
  G.cur_t += dt;
  G.cur_lift += double(S.force[1]) * dt;
  G.cur_drag += double(S.force[0]) * dt;
  G.cur_moment += double(S.moment) * dt;
  if (G.cur_t < G.block_len) return;
  if (G.nblocks == kMaxBlocks) {
    for (int k = 0; k < kMaxBlocks / 2; ++k) {
      G.blk_lift[k] = 0.5 * (G.blk_lift[2 * k] + G.blk_lift[2 * k + 1]);
      G.blk_drag[k] = 0.5 * (G.blk_drag[2 * k] + G.blk_drag[2 * k + 1]);
      G.blk_moment[k] = 0.5 * (G.blk_moment[2 * k] + G.blk_moment[2 * k + 1]);
    }
    G.nblocks = kMaxBlocks / 2;
    G.block_len *= 2.0;
    if (G.cur_t < G.block_len) return;
  }
  G.blk_lift[G.nblocks] = G.cur_lift / G.cur_t;
  G.blk_drag[G.nblocks] = G.cur_drag / G.cur_t;
  G.blk_moment[G.nblocks] = G.cur_moment / G.cur_t;
  G.nblocks += 1;
  G.cur_t = G.cur_lift = G.cur_drag = G.cur_moment = 0.0;
}

// stage 3 (one item per scene): dt, the block averages, the clock
struct FinalizeStage {
  const Model* model;
  Scene* g;
  CPS_HD void operator()(int) const {
    const Model& m = *model;
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
    if (!finite(S.vmax2) || !finite(S.force[0] + S.force[1] + S.moment)) {
      C.bad = kBadParticles;
      C.bad_step = C.step + 1;
      G.step_dt = 0.0f;
      return;
    }
    bool last;
    const float dt = clip_to_end(C, choose_dt(m, S.vmax2), last);
    G.sums = S;
    // the forces of this step's state act over [time, time + dt]
    if (C.time >= m.measure_start) accumulate_blocks(G, S, double(dt));
    G.step_dt = dt;
    advance_clock(C, dt, last);
  }
};

// a particle that left through the inflow or the outflow re-enters at the inflow as a new
// free-stream particle: it crossed the boundary a fraction `frac` of the step ago (from its
// last move), and enters the inflow plane at that time: y uniform across the channel (a
// radius from the walls), and the velocity of a particle crossing a plane into the free
// stream, so the gas inside is the free stream's drifting Maxwellian: the stream-wise
// component flux-weighted (flux_weighted_speed_ratio) at the speed ratio U / c_m, the cross
// component Gaussian of the thermal spread m.thermal U (1 + speed_scale) ... kept at
// m.thermal U (the temperature does not follow the speed control); cold beam (thermal 0):
// exactly (U, 0). x is the distance it moved in since it entered.
CPS_HD CPS_INLINE void reenter(const Model& m, const Control& u, int id, long long step, float dt, float frac, Vec2& x,
                               Vec2& v) {
  const float U = m.speed * (1.0f + u.speed_scale);
  const float u1 = uniform01(m.seed, id, step, 1);
  const float u2 = uniform01(m.seed, id, step, 2), u3 = uniform01(m.seed, id, step, 3);
  const float span = m.hi[1] - m.lo[1] - 2.0f * m.radius;
  const float sigma = m.thermal * m.speed;  // per component: sqrt(kT / m)
  float ux = U, uy = 0.0f;
  if (sigma > 0.0f) {
    const float cm = 1.41421356f * sigma;  // sqrt(2 kT / m)
    ux = cm * flux_weighted_speed_ratio(U / cm, m.seed, id, step, 4);
    uy = sigma * fsqrt(-2.0f * flog(u2)) * fcos(2.0f * kPi * u3);
  }
  const float in = fclamp(ux * frac * dt, 0.0f, m.hi[0] - m.lo[0]);
  x = Vec2{{m.lo[0] + in, m.lo[1] + m.radius + u1 * span}};
  v = Vec2{{ux, uy}};
}

// no particle ends a step inside the airfoil or outside the channel: a centre that got in is
// put back on the surface (a twentieth of a radius outside, along the signed-distance
// normal) with its normal velocity reflected; a centre past a wall is mirrored back. These
// are counted (pushouts): with the contact stiffness resolving the contacts, there are none
CPS_HD CPS_INLINE bool keep_out(const Model& m, const AirfoilFrame& af, Vec2& x, Vec2& v) {
  bool moved = false;
  if (x[1] < m.lo[1]) {
    x[1] = fmin2(2.0f * m.lo[1] - x[1], m.hi[1]);
    v[1] = v[1] < 0.0f ? -v[1] : v[1];
    moved = true;
  }
  if (x[1] > m.hi[1]) {
    x[1] = fmax2(2.0f * m.hi[1] - x[1], m.lo[1]);
    v[1] = v[1] > 0.0f ? -v[1] : v[1];
    moved = true;
  }
  // (in the airfoil's built frame: af)
  Vec2 xb = af.to_body(x);
  if (m.n_edges > 0 && box_distance2(m.bbox, xb) == 0.0f && polygon_contains(m.airfoil_grid(), xb)) {
    PolygonHit hit = polygon_sdf(m.airfoil_grid(), xb);
    float step = 0.05f * m.radius;
    for (int k = 0; k < 8; ++k) {
      xb = hit.closest + hit.normal * step;
      if (!polygon_contains(m.airfoil_grid(), xb)) break;
      step *= 2.0f;
    }
    x = af.to_world(xb);
    const Vec2 normal = af.dir_to_world(hit.normal);
    float vn = dot(v, normal);
    if (vn < 0.0f) v -= normal * (2.0f * vn);
    moved = true;
  }
  return moved;
}

// stage 4: integrate (forward or symplectic Euler), recycle at the outflow, keep every
// particle in the channel and out of the airfoil
struct IntegrateStage {
  const Model* model;
  Scene* g;
  const Control* ctl;
  Arrays s;
  CPS_HD void operator()(int i) const {
    const float dt = g->step_dt;
    if (!(dt > 0.0f)) return;  // a step not taken leaves the particles as they are
    const Model& m = *model;
    Vec2 x = s.pos[i], v = s.vel[i];
    const Vec2 a = s.force[i] * (1.0f / m.mass);
    if (m.integrator == kSymplecticEuler) {
      v += a * dt;
      x += v * dt;
    } else {
      x += v * dt;
      v += a * dt;
    }
    int scattered = s.scattered[i];
    const bool at_wall = x[1] - m.lo[1] < m.radius || m.hi[1] - x[1] < m.radius;
    if (m.recycle_scattered && scattered && at_wall && !(x[0] > m.hi[0] || x[0] < m.lo[0])) {
      // a scattered particle reaching a wall leaves (the free-molecular validation's open walls)
      reenter(m, *ctl, s.id[i], g->clock.step, dt, 0.0f, x, v);
      add_count(&g->recycled, 1);
      scattered = 0;
    } else if (x[0] > m.hi[0] || x[0] < m.lo[0]) {
      scattered = 0;
      // the fraction of the step since it crossed the boundary (from its move this step)
      const float x0 = s.pos[i][0], edge = x[0] > m.hi[0] ? m.hi[0] : m.lo[0];
      const float moved = x[0] - x0;
      const float frac = moved != 0.0f ? fclamp((x[0] - edge) / moved, 0.0f, 1.0f) : 0.0f;
      // the step counter is already the next step's: (id, step) is unique
      reenter(m, *ctl, s.id[i], g->clock.step, dt, frac, x, v);
      add_count(&g->recycled, 1);
    }
    if (keep_out(m, airfoil_frame(m, *ctl), x, v)) add_count(&g->pushouts, 1);
    if (!finite(x[0] + x[1] + v[0] + v[1])) raise_first(&g->clock.bad, kBadParticles);
    s.scattered[i] = scattered;
    s.pos[i] = x;
    s.vel[i] = v;
  }
};

}  // namespace cps::wt
