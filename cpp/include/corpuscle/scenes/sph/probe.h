// The SPH box's probes as the experiments have them (written once for every backend and index):
// a point, or a face (a disc or a square of a given size, with a unit normal: a pressure
// transducer's membrane on a wall) whose pressure is the average over sample points spread
// evenly over its area of the kernel interpolation at each point; and the series each probe
// keeps, sampled on its own interval (every step by default), in a ring of kProbeSeries
// samples per probe in the per-scene record that the host drains (no per-step host sync).
//
// The interpolation at a point x is Shepard's over the fluid (DualSPHysics's MeasureTool):
//   f(x) = sum_j f_j W(x - x_j) V_j / sum_j W(x - x_j) V_j,  V_j = m_j / rho_j,
// over fluid particles only. The wall's dynamic boundary particles (DBC) are left out: their
// pressure is the numerical repulsion that keeps the fluid a kernel's width off the wall (it
// peaks in that gap and follows the wall particles' own continuity density, not the fluid's
// pressure), and the Shepard normalisation makes the fluid half of a support cut by the wall
// an extrapolation of the fluid's pressure to the point (docs/sph_box.md, "probes").
// A sample point with no fluid within the support reads 0 (gauge: a dry patch of the
// membrane feels the air), so a face half wet reads half its wet part's pressure.
#pragma once
#include "corpuscle/scenes/sph/tables.h"

namespace cps::sph {

constexpr int kProbePoint = 0, kProbeDisc = 1, kProbeSquare = 2, kProbeGauge = 3;
constexpr int kMaxProbeSamples = 4096;   // sample points of one face

// two unit tangents of the face with unit normal n (3-D; 2-D: t1 only, the normal turned
// by +90 degrees), from the axis least aligned with n
CPS_HD CPS_INLINE void probe_tangents(const float* n, int D, float* t1, float* t2) {
  if (D == 2) {
    t1[0] = -n[1];
    t1[1] = n[0];
    return;
  }
  const float ax = n[0] < 0 ? -n[0] : n[0], ay = n[1] < 0 ? -n[1] : n[1], az = n[2] < 0 ? -n[2] : n[2];
  float a[3] = {0.0f, 0.0f, 0.0f};
  a[(ax <= ay && ax <= az) ? 0 : (ay <= az ? 1 : 2)] = 1.0f;
  // t1 = normalize(a - (a.n) n), t2 = n x t1
  const float an = a[0] * n[0] + a[1] * n[1] + a[2] * n[2];
  float t[3] = {a[0] - an * n[0], a[1] - an * n[1], a[2] - an * n[2]};
  const float inv = 1.0f / sqrtf(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]);
  for (int c = 0; c < 3; ++c) t1[c] = t[c] * inv;
  t2[0] = n[1] * t1[2] - n[2] * t1[1];
  t2[1] = n[2] * t1[0] - n[0] * t1[2];
  t2[2] = n[0] * t1[1] - n[1] * t1[0];
}

// sample point s (0 <= s < samples) of a probe centred at c with unit normal n, each point
// standing for an equal share of the face's area:
//   point: c (samples = 1);
//   gauge: `samples` points from c to c + size n (a vertical line: n is its axis);
//   2-D disc or square: a segment of length `size` across the normal, at the midpoints of
//     `samples` equal parts;
//   3-D square (side `size`): the centres of a k x k grid, samples = k^2;
//   3-D disc (diameter `size`): Vogel's spiral, r_s = (size / 2) sqrt((s + 1/2) / samples),
//     angle s * the golden angle: equal areas, no preferred direction.
template <int D>
CPS_HD CPS_INLINE void probe_sample_point(const float* c, const float* n, int shape, float size, int samples, int s,
                                          float* out) {
  for (int k = 0; k < D; ++k) out[k] = c[k];
  if (shape == kProbePoint || samples < 1) return;
  if (shape == kProbeGauge) {  // along the axis n from c, both ends included
    const float t = samples > 1 ? size * float(s) / float(samples - 1) : 0.0f;
    for (int k = 0; k < D; ++k) out[k] += t * n[k];
    return;
  }
  float t1[3] = {0.0f, 0.0f, 0.0f}, t2[3] = {0.0f, 0.0f, 0.0f};
  probe_tangents(n, D, t1, t2);
  float u = 0.0f, v = 0.0f;
  if (D == 2) {
    u = size * ((float(s) + 0.5f) / float(samples) - 0.5f);
  } else if (shape == kProbeSquare) {
    int k = int(sqrtf(float(samples)) + 0.5f);
    if (k < 1) k = 1;
    u = size * ((float(s % k) + 0.5f) / float(k) - 0.5f);
    v = size * ((float(s / k) + 0.5f) / float(k) - 0.5f);
  } else {
    const float r = 0.5f * size * sqrtf((float(s) + 0.5f) / float(samples));
    const float a = 2.39996322972865332f * float(s);  // pi (3 - sqrt 5)
    u = r * cosf(a);
    v = r * sinf(a);
  }
  for (int k = 0; k < D; ++k) out[k] += u * t1[k] + v * t2[k];
}

// Shepard's sums at a point: sum W V, sum p W V, sum v W V over the fluid (slots < nf)
template <int D>
struct ProbeSums {
  float w, p;
  Vec<D> v;
};
template <int D, class View>
CPS_HD CPS_INLINE ProbeSums<D> probe_shepard(const Model<D>& m, const View& view, const Arrays<D>& a, int nf,
                                             const Vec<D>& x) {
  const SphKernel<D> w = m.kernels.density;
  ProbeSums<D> s{0.0f, 0.0f, Vec<D>::zero()};
  view.gather(-1, x, [&](int j, const Vec<D>&, float r2) {
    if (j >= nf) return;  // fluid only: the DBC wall particles are left out (see the header)
    const float wv = w.w_r2(r2) * (m.mass / a.density[j]);
    s.w += wv;
    s.p += a.pressure[j] * wv;
    s.v += a.velocity[j] * wv;
  });
  return s;
}

// A water-level gauge (kProbeGauge; DualSPHysics's GaugeSWL, a wave gauge of a flume): a line
// from the probe's position along its unit axis (the `normal`: up) of length `size`, sampled at
// `samples` points from end to end. The filling at a point is the kernel sum over the fluid AND
// the wall particles, C(x) = sum_j W(x - x_j) V_j: about 1 inside the water and inside the
// walls' layers (the DBC particles fill the floor under a gauge that starts on it), 1/2 at a
// free surface, 0 in the air. The level is where C first falls below 1/2 walking up from the
// lower end, linearly interpolated between the two samples around the crossing: 0 when the
// lower end is dry, `size` when the line is wet to its top. Spray above the first crossing is
// not counted, as a resistance or acoustic gauge would not.
template <int D, class View>
CPS_HD CPS_INLINE float gauge_fill(const Model<D>& m, const View& view, const Arrays<D>& a, const Vec<D>& x) {
  const SphKernel<D> w = m.kernels.density;
  float c = 0.0f;
  view.gather(-1, x, [&](int j, const Vec<D>&, float r2) { c += w.w_r2(r2) * (m.mass / a.density[j]); });
  return c;
}
template <int D, class View>
CPS_HD CPS_INLINE float gauge_level(const Model<D>& m, const View& view, const Arrays<D>& a, int k, float& bottom) {
  const int ns = m.probe_samples[k];
  const float len = m.probe_size[k];
  const float ds = ns > 1 ? len / float(ns - 1) : 0.0f;
  auto at = [&](int s) {
    float xs[D];
    probe_sample_point<D>(m.probes + k * D, m.probe_normal + k * D, kProbeGauge, len, ns, s, xs);
    Vec<D> x;
    for (int q = 0; q < D; ++q) x[q] = xs[q];
    return gauge_fill(m, view, a, x);
  };
  float prev = at(0);
  bottom = prev;
  if (!(prev >= 0.5f)) return 0.0f;
  for (int s = 1; s < ns; ++s) {
    const float f = at(s);
    if (f < 0.5f) return ds * (float(s - 1) + (prev - 0.5f) / (prev - f));
    prev = f;
  }
  return len;
}

// probe k's reading: the mean over its sample points of the interpolated pressure and
// velocity (a dry point reads 0), and the mean Shepard sum (0: no point saw fluid); a gauge:
// its level in p, its lower end's filling in weight, no velocity
template <int D, class View>
CPS_HD CPS_INLINE void probe_reading(const Model<D>& m, const View& view, const Arrays<D>& a, int nf, int k, float& p,
                                     float* vel, float& weight) {
  if (m.probe_shape[k] == kProbeGauge) {  // the level (m along the axis) in the pressure's place
    p = gauge_level(m, view, a, k, weight);
    for (int q = 0; q < 3; ++q) vel[q] = 0.0f;
    return;
  }
  const int ns = m.probe_shape[k] == kProbePoint ? 1 : m.probe_samples[k];
  const float* c = m.probes + k * D;
  const float* n = m.probe_normal + k * D;
  float sp = 0.0f, sw = 0.0f;
  Vec<D> sv = Vec<D>::zero();
  for (int s = 0; s < ns; ++s) {
    Vec<D> x;
    float xs[D];
    probe_sample_point<D>(c, n, m.probe_shape[k], m.probe_size[k], ns, s, xs);
    for (int q = 0; q < D; ++q) x[q] = xs[q];
    const ProbeSums<D> r = probe_shepard(m, view, a, nf, x);
    const float inv = r.w > 0.0f ? 1.0f / r.w : 0.0f;
    sp += r.p * inv;
    sv += r.v * inv;
    sw += r.w;
  }
  const float share = ns > 1 ? 1.0f / float(ns) : 1.0f;
  p = ns > 1 ? sp * share : sp;
  for (int q = 0; q < 3; ++q) vel[q] = q < D ? (ns > 1 ? sv[q] * share : sv[q]) : 0.0f;
  weight = ns > 1 ? sw * share : sw;
}

// one item per scene, after the step's finalize: a step that is taken (step_dt > 0) appends
// the reading of each probe that is due (its interval passed since its last sample; interval
// 0: every step) to the probe's ring, with the time of the state it read
template <int D>
struct ProbeSeriesStage {
  const Model<D>* model;
  Scene* g;
  CPS_HD void operator()(int) const {
    const Model<D>& m = *model;
    Scene& G = *g;
    if (!(G.step_dt > 0.0f)) return;
    const double t = G.probe_time;
    for (int k = 0; k < m.n_probes; ++k) {
      if (t < G.series_next[k]) continue;
      const int slot = int(G.series_n[k] % kProbeSeries);
      G.series_t[k * kProbeSeries + slot] = t;
      G.series_p[k * kProbeSeries + slot] = G.probe_p[k];
      G.series_n[k] += 1;
      const double dt = double(m.probe_interval[k]);
      G.series_next[k] = dt > 0.0 ? (floor(t / dt) + 1.0) * dt : t;
    }
  }
};

}  // namespace cps::sph
