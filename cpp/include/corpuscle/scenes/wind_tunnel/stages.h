// The wind tunnel's own stages and hooks: the random numbers of re-entry, the Maxwellian
// inflow, the airfoil (its frame under the pitch control, its contact and push-out), the
// channel's walls, the block averages of the airfoil's force, the inflow conveyor, and the
// hooks through which the DEM module's generic stages (dem/stages.h: reorder, contacts by
// gather or pairs, number density, dt, integration) see this kind. Nothing here knows which
// backend runs it. Every function is a template on the dimension D (model.h): the x-y plane
// holds the channel's walls and the airfoil section; D = 3 adds the periodic span z (the DEM
// module's periodic_z: contacts across it through periodic images, dem::span_image).
#pragma once
#include "corpuscle/core/atomics.h"
#include "corpuscle/dem/stages.h"
#include "corpuscle/scenes/wind_tunnel/tables.h"

namespace cps::wt {

using dem::add_count;
using dem::choose_dt;
using dem::wrap_span;

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

// the x-y components of a vector (the plane of the airfoil section), and a vector with its
// x-y components replaced (z kept); for D = 2 both are the vector itself
template <int D>
CPS_HD CPS_INLINE Vec2 xy(const Vec<D>& a) {
  if constexpr (D == 2) return a;
  else return Vec2{{a[0], a[1]}};
}
template <int D>
CPS_HD CPS_INLINE void set_xy(Vec<D>& a, const Vec2& b) {
  if constexpr (D == 2) a = b;
  else {
    a[0] = b[0];
    a[1] = b[1];
  }
}
// the x-y vector b as a D-vector (z = 0)
template <int D>
CPS_HD CPS_INLINE Vec<D> from_xy(const Vec2& b) {
  if constexpr (D == 2) return b;
  else return Vec<D>{{b[0], b[1], 0.0f}};
}

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
template <int D>
CPS_HD CPS_INLINE AirfoilFrame airfoil_frame(const Model<D>& m, const Control& u) {
  AirfoilFrame f;
  f.pitched = u.pitch != 0.0f;
  const float a = u.pitch * (kPi / 180.0f);
  f.c = f.pitched ? fcos(a) : 1.0f;
  f.s = f.pitched ? fsin(a) : 0.0f;
  f.q = m.quarter_chord;
  return f;
}

// the contact force on particle i from the two walls and the airfoil; adds the reaction on
// the airfoil (force, moment about the quarter chord) to s. D = 3: the airfoil is the section
// extruded along z, its contact the 2-D one of the particle's x-y components (its normal has
// no z component, so the particle's z velocity does not enter)
template <int D>
CPS_HD CPS_INLINE Vec<D> boundary_forces(const Model<D>& m, const AirfoilFrame& af, const Vec<D>& x, const Vec<D>& v,
                                         float& pressure, int& contacts, StepSums<D>& s, int& scattered) {
  Vec<D> F = Vec<D>::zero();
  Vec<D> f;
  float mag;
  const Vec<D> up = from_xy<D>(Vec2{{0.0f, 1.0f}}), down = from_xy<D>(Vec2{{0.0f, -1.0f}});
  if (wall_contact_force<D>(m.wall, x[1] - m.lo[1], up, v, m.radius, Vec<D>::zero(), f, mag)) {
    F += f;
    s.wall_force += f;
    pressure += mag;
    contacts += 1;
  }
  if (wall_contact_force<D>(m.wall, m.hi[1] - x[1], down, v, m.radius, Vec<D>::zero(), f, mag)) {
    F += f;
    s.wall_force += f;
    pressure += mag;
    contacts += 1;
  }
  const Vec2 xb = af.to_body(xy(x));
  if (m.n_edges > 0 && box_distance2(m.bbox, xb) < m.radius * m.radius) {
    PolygonHit hit;
    Vec2 f2;
    if (polygon_contact_force(m.wing, m.airfoil_grid(), xb, af.dir_to_body(xy(v)), m.radius, f2, mag, hit)) {
      f2 = af.dir_to_world(f2);
      F += from_xy<D>(f2);
      pressure += mag;
      contacts += 1;
      // the airfoil gets -f, applied at the contact point
      Vec2 fa = -f2;
      Vec2 r = af.to_world(hit.closest) - m.quarter_chord;
      s.force += from_xy<D>(fa);
      s.moment += r[0] * fa[1] - r[1] * fa[0];
      s.contacts += 1;
      scattered = 1;
    }
  }
  if constexpr (D == 3) {
    // the mesh body (model.h): the signed distance to its triangles through their tree; the
    // body gets -f at the closest point (force; moment about z and the whole torque about body_ref)
    MeshHit hit;
    Vec3 f3;
    if (m.n_tris > 0 && mesh_contact_force(m.wing, m.body, x, v, m.radius, f3, mag, hit)) {
      F += f3;
      pressure += mag;
      contacts += 1;
      const Vec3 fa = -f3, r = hit.closest - m.body_ref;
      s.force += fa;
      s.moment += r[0] * fa[1] - r[1] * fa[0];
      s.torque += cross(r, fa);
      s.contacts += 1;
      scattered = 1;
    }
  }
  return F;
}

// the block averages: add this step's airfoil force over dt; a full block is closed, and
// when all kMaxBlocks are full adjacent pairs are merged and the block length doubles
// (batch means with a growing batch: the standard error stays honest for correlated series)
template <int D>
CPS_HD CPS_INLINE void accumulate_blocks(Scene<D>& G, const StepSums<D>& S, double dt) {
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

// the free stream's speed this step: U (1 + the control's speed_scale), at which particles
// re-enter and the inflow conveyor's slots move in
template <int D>
CPS_HD CPS_INLINE float stream_speed(const Model<D>& m, const Control& u) {
  return m.speed * (1.0f + u.speed_scale);
}

// a particle that left through the inflow or the outflow re-enters at the inflow as a new
// free-stream particle: it crossed the boundary a fraction `frac` of the step ago (from its
// last move), and enters the inflow plane at that time: y uniform across the channel (a
// radius from the walls), and the velocity of a particle crossing a plane into the free
// stream, so the gas inside is the free stream's drifting Maxwellian: the stream-wise
// component flux-weighted (flux_weighted_speed_ratio) at the speed ratio U / c_m, the cross
// component Gaussian of the thermal spread m.thermal U (1 + speed_scale) ... kept at
// m.thermal U (the temperature does not follow the speed control); cold beam (thermal 0):
// exactly (U, 0). x is the distance it moved in since it entered. D = 3: z uniform across the
// periodic span, and the two cross components (y, z) the two Gaussians of one Box-Muller pair
// (so the gas inside is the 3-D drifting Maxwellian; cold beam: (U, 0, 0)).
template <int D>
CPS_HD CPS_INLINE void reenter(const Model<D>& m, const Control& u, int id, long long step, float dt, float frac,
                               Vec<D>& x, Vec<D>& v) {
  const float U = stream_speed(m, u);
  const float u1 = uniform01(m.seed, id, step, 1);
  const float u2 = uniform01(m.seed, id, step, 2), u3 = uniform01(m.seed, id, step, 3);
  const float span = m.hi[1] - m.lo[1] - 2.0f * m.radius;
  const float sigma = m.thermal * m.speed;  // per component: sqrt(kT / m)
  float ux = U, uy = 0.0f, uz = 0.0f;
  if (sigma > 0.0f) {
    const float cm = 1.41421356f * sigma;  // sqrt(2 kT / m)
    ux = cm * flux_weighted_speed_ratio(U / cm, m.seed, id, step, 4);
    uy = sigma * fsqrt(-2.0f * flog(u2)) * fcos(2.0f * kPi * u3);
    if constexpr (D == 3) uz = sigma * fsqrt(-2.0f * flog(u2)) * fsin(2.0f * kPi * u3);
  }
  const float in = fclamp(ux * frac * dt, 0.0f, m.hi[0] - m.lo[0]);
  if constexpr (D == 2) {
    (void)uz;
    x = Vec2{{m.lo[0] + in, m.lo[1] + m.radius + u1 * span}};
    v = Vec2{{ux, uy}};
  } else {
    // stream 200: beyond those of flux_weighted_speed_ratio (4 ... 102)
    const float u4 = uniform01(m.seed, id, step, 200);
    x = Vec<D>{{m.lo[0] + in, m.lo[1] + m.radius + u1 * span, m.lo[2] + u4 * (m.hi[2] - m.lo[2])}};
    wrap_span(m, x);  // u4 < 1, but lo + u4 L may round up to hi
    v = Vec<D>{{ux, uy, uz}};
  }
}

// The inflow conveyor (a cold beam with contacts, m.conv_rows > 0). A particle re-entering at
// a uniformly random height lands on another one about 4 times the solid fraction of the time
// (40% at the default 0.1): the overlap's spring energy heats the stream, which then is no
// longer the cold free stream the initial lattice is. So the free stream enters as the start
// does, as a lattice: slots in conv_rows rows (dy apart) and columns dx apart moving in at the
// stream's speed. Slot (r, c) lies at x = lo + inflow_x + phase_r - c dx (plus a fixed jitter,
// the start lattice's), so the column in the inlet's first dx is
// c_now = floor((inflow_x + phase_r) / dx), and a row is free while its next column
// conv_next[r] <= c_now (D = 3: a row is a height in one layer of the span). The slots exceed the flux by the start's 10% vacancies, so a free row
// is found among a few hashed tries. Two particles may pick one row in a step: the smallest id
// gets it (atomic min, then a second pass), whatever the threads' order, so every backend
// places the same particles in the same slots; a particle that finds no free row in
// kConveyorAttempts rounds of kConveyorTries keeps the random-height entry it was given.
constexpr int kConveyorTries = 64;
constexpr int kConveyorAttempts = 2;
constexpr int kConveyorThreads = 1024;  // the claim and place passes loop over the leaving list
constexpr int kNoClaim = 0x7fffffff;

// the row's phase: a golden-ratio sequence, so neighbouring rows' columns do not line up
template <int D>
CPS_HD CPS_INLINE double conveyor_phase(const Model<D>& m, int r) {
  const double g = double(r) * 0.6180339887498949;
  return double(m.conv_dx) * (g - floor(g));
}
template <int D>
CPS_HD CPS_INLINE long long conveyor_column(const Model<D>& m, double inflow_x, int r) {
  return (long long)floor((inflow_x + conveyor_phase(m, r)) / double(m.conv_dx));
}
// the first of the particle's hashed rows whose inlet slot is free, and that slot; -1: none
template <int D>
CPS_HD CPS_INLINE int conveyor_row(const Model<D>& m, const Scene<D>& G, int id, long long step, int attempt,
                                   long long& column) {
  for (int j = 0; j < kConveyorTries; ++j) {
    int r = int(uniform01(m.seed, id, step, 1000 + attempt * kConveyorTries + j) * float(m.conv_rows));
    r = r < m.conv_rows ? r : m.conv_rows - 1;
    const long long c = conveyor_column(m, G.inflow_x, r);
    if (G.conv_next[r] <= c && c < 0x7ffffffe) {  // (2^31 columns: billions of steps)
      column = c;
      return r;
    }
  }
  return -1;
}
// the position of slot (r, c): the start lattice's jitter, 0.45 of the gap each way, keeps
// neighbouring slots more than a diameter apart; never upstream of the inlet. Row r is height
// r mod conv_ny; D = 3: in the span's layer r / conv_ny
template <int D>
CPS_HD CPS_INLINE Vec<D> conveyor_slot(const Model<D>& m, double inflow_x, int r, long long c) {
  const int ry = r % m.conv_ny;
  const float jx = (2.0f * uniform01(m.seed, r, c, 2000) - 1.0f) * 0.45f * (m.conv_dx - 2.0f * m.radius);
  const float jy = (2.0f * uniform01(m.seed, r, c, 2001) - 1.0f) * 0.45f * (m.conv_dy - 2.0f * m.radius);
  const double x = double(m.lo[0]) + inflow_x + conveyor_phase(m, r) - double(c) * double(m.conv_dx) + double(jx);
  Vec<D> p;
  p[0] = fmax2(float(x), m.lo[0]);
  p[1] = m.conv_y0 + float(ry) * m.conv_dy + jy;
  if constexpr (D == 3) {
    const float jz = (2.0f * uniform01(m.seed, r, c, 2002) - 1.0f) * 0.45f * (m.conv_dz - 2.0f * m.radius);
    p[2] = m.conv_z0 + float(r / m.conv_ny) * m.conv_dz + jz;
    wrap_span(m, p);
  }
  return p;
}
// an attempt's claim: the particle's row, if it found a free one (the smallest id wins it)
template <int D>
CPS_HD CPS_INLINE void conveyor_claim(const Model<D>& m, Scene<D>* g, int id, int attempt) {
  long long c;
  const int r = conveyor_row(m, *g, id, g->clock.step, attempt, c);
  if (r >= 0) atomic_min(&g->conv_claim[r], id);
}
// pass 1 of a later attempt: each unplaced leaving particle claims its row (the first
// attempt's claims are made by the integration)
template <int D>
struct ConveyorClaimStage {
  const Model<D>* model;
  Scene<D>* g;
  Arrays<D> s;
  int attempt;
  CPS_HD void operator()(int t) const {
    const Model<D>& m = *model;
    if (!(g->step_dt > 0.0f)) return;
    const int count = g->n_leaving;
    for (int k = t; k < count; k += kConveyorThreads) {
      const int i = s.leaving[k];
      if (i >= 0) conveyor_claim(m, g, s.id[i], attempt);
    }
  }
};
// pass 2: the winners take their slots (the rows they claimed are still free: only a winner
// writes its row), reset the claim, and enter at the stream's velocity
template <int D>
struct ConveyorPlaceStage {
  const Model<D>* model;
  Scene<D>* g;
  const Control* ctl;
  Arrays<D> s;
  int attempt;
  CPS_HD void operator()(int t) const {
    const Model<D>& m = *model;
    if (!(g->step_dt > 0.0f)) return;
    const int count = g->n_leaving;
    for (int k = t; k < count; k += kConveyorThreads) {
      const int i = s.leaving[k];
      if (i < 0) continue;
      const int id = s.id[i];
      long long c;
      const int r = conveyor_row(m, *g, id, g->clock.step, attempt, c);
      if (r < 0 || g->conv_claim[r] != id) continue;  // no free row, or a smaller id got it
      g->conv_claim[r] = kNoClaim;
      g->conv_next[r] = int(c + 1);
      s.position[i] = conveyor_slot(m, g->inflow_x, r, c);
      Vec<D> v = Vec<D>::zero();
      v[0] = stream_speed(m, *ctl);
      s.velocity[i] = v;
      s.leaving[k] = -1;
    }
  }
};

// the conveyor's passes in one tile of kConveyorThreads lanes (one CUDA block, its barrier
// between the passes): attempt 0's placing (its claims were made by the integration), then
// for each later attempt the claims and the placing
template <int D>
struct ConveyorStage {
  const Model<D>* model;
  Scene<D>* g;
  const Control* ctl;
  Arrays<D> s;
  template <class Tile>
  CPS_HD void operator()(int, Tile& tile) const {
    for (int attempt = 0; attempt < kConveyorAttempts; ++attempt) {
      if (attempt > 0) {
        tile.lanes([&](int t) { ConveyorClaimStage<D>{model, g, s, attempt}(t); });
        tile.sync();
      }
      tile.lanes([&](int t) { ConveyorPlaceStage<D>{model, g, ctl, s, attempt}(t); });
      tile.sync();
    }
  }
};

// no particle ends a step inside the airfoil or outside the channel: a centre that got in is
// put back on the surface (a twentieth of a radius outside, along the signed-distance
// normal) with its normal velocity reflected; a centre past a wall is mirrored back. These
// are counted (pushouts): with the contact stiffness resolving the contacts, there are none
// (D = 3: the airfoil test on the x-y components, z untouched)
template <int D>
CPS_HD CPS_INLINE bool keep_out(const Model<D>& m, const AirfoilFrame& af, Vec<D>& x, Vec<D>& v) {
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
  Vec2 xb = af.to_body(xy(x));
  if (m.n_edges > 0 && box_distance2(m.bbox, xb) == 0.0f && polygon_contains(m.airfoil_grid(), xb)) {
    PolygonHit hit = polygon_sdf(m.airfoil_grid(), xb);
    float step = 0.05f * m.radius;
    for (int k = 0; k < 8; ++k) {
      xb = hit.closest + hit.normal * step;
      if (!polygon_contains(m.airfoil_grid(), xb)) break;
      step *= 2.0f;
    }
    set_xy(x, af.to_world(xb));
    const Vec2 normal = af.dir_to_world(hit.normal);
    Vec2 v2 = xy(v);
    float vn = dot(v2, normal);
    if (vn < 0.0f) v2 -= normal * (2.0f * vn);
    set_xy(v, v2);
    moved = true;
  }
  if constexpr (D == 3) {
    // the mesh body: a centre that got inside is put back on its surface (dem/mesh_body.h)
    if (m.n_tris > 0 && mesh_keep_out(m.body, m.radius, x, v)) moved = true;
  }
  return moved;
}

// The hooks of the DEM module's stages (dem/stages.h)

// the force hook: the two walls and the airfoil (boundary_forces), the reaction on the
// airfoil into the step's sums item, the airfoil flag set on a contact
template <int D>
struct Boundary {
  const Model<D>* model;
  const Control* ctl;
  int* scattered;
  CPS_HD Vec<D> operator()(int i, const Vec<D>& x, const Vec<D>& v, float& pressure, int& contacts,
                           StepSums<D>& it) const {
    const Model<D>& m = *model;
    int sc = scattered[i];
    const Vec<D> F = boundary_forces(m, airfoil_frame(m, *ctl), x, v, pressure, contacts, it, sc);
    scattered[i] = sc;
    return F;
  }
};

// the finalize hook: this step's leaving list emptied, the airfoil's force and moment checked,
// and for a step taken the block averages (from measure_start on) and the conveyor's phase
template <int D>
struct Finalize {
  const Model<D>* model;
  const Control* ctl;
  CPS_HD void begin(Scene<D>& G) const { G.n_leaving = 0; }  // this step's list (filled by the integration)
  CPS_HD bool sums_finite(const StepSums<D>& S) const {
    return finite(S.force[0] + S.force[1] + S.moment + S.torque[0] + S.torque[1] + S.torque[2]);
  }
  CPS_HD void taken(Scene<D>& G, const StepSums<D>& S, float dt) const {
    const Model<D>& m = *model;
    if (G.clock.time >= m.measure_start) accumulate_blocks(G, S, double(dt));
    G.inflow_x += double(stream_speed(m, *ctl)) * double(dt);  // the conveyor's slots move in
  }
};

// the integrate hook: recycle at the outflow (and, recycle_scattered, a scattered particle at a
// wall), keep every particle in the channel and out of the airfoil (the periodic span is the
// DEM stage's)
template <int D>
struct Outflow {
  const Model<D>* model;
  Scene<D>* g;
  const Control* ctl;
  Arrays<D> s;
  CPS_HD void after(int i, float dt, Vec<D>& x, Vec<D>& v) const {
    const Model<D>& m = *model;
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
      const float x0 = s.position[i][0], edge = x[0] > m.hi[0] ? m.hi[0] : m.lo[0];
      const float moved = x[0] - x0;
      const float frac = moved != 0.0f ? fclamp((x[0] - edge) / moved, 0.0f, 1.0f) : 0.0f;
      // the step counter is already the next step's: (id, step) is unique
      reenter(m, *ctl, s.id[i], g->clock.step, dt, frac, x, v);
      add_count(&g->recycled, 1);
      // a cold beam's conveyor may move it to a lattice slot (the passes after this stage);
      // the first attempt's claim is made here
      if (m.conv_rows > 0) {
        s.leaving[atomic_add(&g->n_leaving, 1)] = i;
        conveyor_claim(m, g, s.id[i], 0);
      }
    }
    if (keep_out(m, airfoil_frame(m, *ctl), x, v)) add_count(&g->pushouts, 1);
    s.scattered[i] = scattered;
  }
};

}  // namespace cps::wt
