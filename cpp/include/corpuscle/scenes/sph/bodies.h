// Moving bodies of the SPH box (issue 29): a body's boundary particles (DBC, joined to the
// walls) follow its pose, a rigid motion about its reference point (the `position` of its
// [[bodies]] entry):
//   x_i(t) = c(t) + R(t) r_i,   v_i(t) = v_c(t) + w(t) x (R(t) r_i)
// r_i the particle's offset in the body's own frame (fixed at the build). The pose is
// prescribed:
//   velocity  c(t) = c0 + v t, R(t) = Rot(w t) R0 (w a constant angular velocity about the
//             fixed axes through c(t); 2-D: about z)
//   table     rows t, x, y, z, rx, ry, rz (degrees; R = Rz Ry Rx as geometry.rotation_matrix),
//             the position and the angles interpolated linearly in t (held at the first row
//             before it and at the last after it, at rest); the angular velocity is the one of
//             the interpolated angles' rates: w = rz' e_z + ry' Rz e_y + rx' Rz Ry e_x
// The poses are evaluated in double (one item a step: BodyPoseStage) from the clock's time and
// kept in the per-scene record (recorded, drawn at their pose); the particles are set from
// them (BodyParticlesStage) after each step's integration, so a state's body particles are
// always at the pose of its time. The velocity enters the pair terms as a wall particle's (the
// viscous terms and, for scenes with moving bodies, the continuity equation).
#pragma once
#include <cmath>

#include "corpuscle/core/vec.h"
#include "corpuscle/sim/table.h"

namespace cps::sph {

constexpr int kMaxMovingBodies = 16;  // moving bodies per scene (fixed bodies are plain walls)
constexpr int kBodyVelocity = 1, kBodyTable = 2;
constexpr int kBodyTableCols = 7;  // t, x, y, z, rx, ry, rz (degrees)
constexpr int kBodyPoseFloats = 18;  // c (3), R (9, row-major), v_c (3), w (3)

// one moving body's prescribed motion (Model)
struct BodyMotion {
  int kind;          // kBodyVelocity / kBodyTable
  int row0, rows;    // table: its rows in the model's table buffer
  double c0[3];      // velocity: the reference point at t = 0
  double a0[3];      // velocity: the rotation at t = 0 (degrees, R0 = Rz Ry Rx)
  double vel[3];     // velocity: m/s
  double omega[3];   // velocity: the angular velocity (rad/s, world axes)
};

constexpr double kDegToRad = 3.14159265358979323846 / 180.0;

// R = Rz(c) Ry(b) Rx(a) of angles a, b, c (radians), row-major
CPS_HD CPS_INLINE void euler_matrix(double a, double b, double c, double R[9]) {
  const double ca = cos(a), sa = sin(a), cb = cos(b), sb = sin(b), cc = cos(c), sc = sin(c);
  R[0] = cc * cb; R[1] = cc * sb * sa - sc * ca; R[2] = cc * sb * ca + sc * sa;
  R[3] = sc * cb; R[4] = sc * sb * sa + cc * ca; R[5] = sc * sb * ca - cc * sa;
  R[6] = -sb;     R[7] = cb * sa;                R[8] = cb * ca;
}

CPS_HD CPS_INLINE void matmul3(const double A[9], const double B[9], double C[9]) {
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) C[3 * r + c] = A[3 * r] * B[c] + A[3 * r + 1] * B[3 + c] + A[3 * r + 2] * B[6 + c];
}

// the rotation by the angle |u| about u (Rodrigues), row-major
CPS_HD CPS_INLINE void axis_angle_matrix(const double u[3], double R[9]) {
  const double th = sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
  double k[3] = {0.0, 0.0, 0.0};
  if (th > 0.0)
    for (int i = 0; i < 3; ++i) k[i] = u[i] / th;
  const double s = sin(th), c1 = 1.0 - cos(th);
  const double K[9] = {0.0, -k[2], k[1], k[2], 0.0, -k[0], -k[1], k[0], 0.0};
  double K2[9];
  matmul3(K, K, K2);
  for (int i = 0; i < 9; ++i) R[i] = (i % 4 == 0 ? 1.0 : 0.0) + s * K[i] + c1 * K2[i];
}

// the pose of a moving body at time t (double): c, R, v_c, w (the layout of kBodyPoseFloats)
CPS_HD inline void body_pose(const BodyMotion& b, const float* table, double t, double out[kBodyPoseFloats]) {
  double* c = out;
  double* R = out + 3;
  double* v = out + 12;
  double* w = out + 15;
  if (b.kind == kBodyVelocity) {
    double R0[9], Rw[9];
    euler_matrix(b.a0[0] * kDegToRad, b.a0[1] * kDegToRad, b.a0[2] * kDegToRad, R0);
    const double u[3] = {b.omega[0] * t, b.omega[1] * t, b.omega[2] * t};
    axis_angle_matrix(u, Rw);
    matmul3(Rw, R0, R);
    for (int k = 0; k < 3; ++k) {
      c[k] = b.c0[k] + b.vel[k] * t;
      v[k] = b.vel[k];
      w[k] = b.omega[k];
    }
    return;
  }
  // table: the segment [t_k, t_k+1) holding t (binary search), or a held end
  const float* T = table + size_t(b.row0) * kBodyTableCols;
  const int n = b.rows;
  double p[6], rate[6];
  if (t <= double(T[0]) || t >= double(T[(n - 1) * kBodyTableCols])) {
    const float* row = t <= double(T[0]) ? T : T + (n - 1) * kBodyTableCols;
    for (int k = 0; k < 6; ++k) {
      p[k] = double(row[1 + k]);
      rate[k] = 0.0;
    }
  } else {
    int lo = 0, hi = n - 1;  // T[lo] <= t < T[hi]
    while (hi - lo > 1) {
      const int mid = (lo + hi) / 2;
      if (double(T[mid * kBodyTableCols]) <= t) lo = mid;
      else hi = mid;
    }
    const float* r0 = T + lo * kBodyTableCols;
    const float* r1 = T + hi * kBodyTableCols;
    const double t0 = double(r0[0]), dt = double(r1[0]) - t0;
    const double s = (t - t0) / dt;
    for (int k = 0; k < 6; ++k) {
      const double a = double(r0[1 + k]), d = double(r1[1 + k]) - a;
      p[k] = a + s * d;
      rate[k] = d / dt;
    }
  }
  const double ax = p[3] * kDegToRad, ay = p[4] * kDegToRad, az = p[5] * kDegToRad;
  euler_matrix(ax, ay, az, R);
  // w = rz' e_z + ry' Rz e_y + rx' Rz Ry e_x (R's first column is Rz Ry e_x)
  const double rx = rate[3] * kDegToRad, ry = rate[4] * kDegToRad, rz = rate[5] * kDegToRad;
  const double ey[3] = {-sin(az), cos(az), 0.0};
  for (int k = 0; k < 3; ++k) {
    c[k] = p[k];
    v[k] = rate[k];
    w[k] = (k == 2 ? rz : 0.0) + ry * ey[k] + rx * R[3 * k];
  }
}

// a body particle's position and velocity from the pose (floats of the record) and its offset
// r in the body's frame
template <int D>
CPS_HD CPS_INLINE void body_point(const float* pose, const float r[3], Vec<D>& x, Vec<D>& v) {
  float q[3];
  for (int k = 0; k < 3; ++k) q[k] = pose[3 + 3 * k] * r[0] + pose[4 + 3 * k] * r[1] + pose[5 + 3 * k] * r[2];
  const float* w = pose + 15;
  const float wq[3] = {w[1] * q[2] - w[2] * q[1], w[2] * q[0] - w[0] * q[2], w[0] * q[1] - w[1] * q[0]};
  for (int k = 0; k < D; ++k) {
    x[k] = pose[k] + q[k];
    v[k] = pose[12 + k] + wq[k];
  }
}

}  // namespace cps::sph
