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
constexpr int kBodyVelocity = 1, kBodyTable = 2, kBodyFree = 3;
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
  // free: the initial state is c0 (the centre of mass), a0, vel and omega; its mass (kg; 2-D:
  // per metre of depth) and inertia tensor about the centre of mass in the body's own frame
  // (row-major; 2-D: Izz I), and its particles' wall ids [w0, w0 + nw) (set_bodies)
  double mass;
  double inertia[9];
  int w0, nw;
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

// ---- free (floating) bodies: moved by the fluid's force and torque, gravity and the tank's
// contact (DualSPHysics's floating bodies; docs/sph_box.md) -----------------------------------
// a free body's state (the record's free_state, double, checkpointed): c (3), q (4: w, x, y, z,
// the rotation from the body's frame), v_c (3), w (3, rad/s, world axes)
constexpr int kFreeStateDoubles = 13;
// a free body's step sums (the record's body_force, double): the force and the torque about the
// centre of mass of the fluid and the contact on its particles (world axes)
constexpr int kBodyForceDoubles = 6;

// one body particle's share of its body's force and torque (the reduction's item)
struct BodyItem {
  double f[3], t[3];
  CPS_HD static BodyItem identity() {
    BodyItem s;
    for (int k = 0; k < 3; ++k) s.f[k] = s.t[k] = 0.0;
    return s;
  }
};
struct BodyItemOp {
  CPS_HD BodyItem operator()(const BodyItem& a, const BodyItem& b) const {
    BodyItem s;
    for (int k = 0; k < 3; ++k) {
      s.f[k] = a.f[k] + b.f[k];
      s.t[k] = a.t[k] + b.t[k];
    }
    return s;
  }
};

// the rotation matrix (row-major) of the unit quaternion q = (w, x, y, z)
CPS_HD CPS_INLINE void quat_matrix(const double q[4], double R[9]) {
  const double w = q[0], x = q[1], y = q[2], z = q[3];
  R[0] = 1.0 - 2.0 * (y * y + z * z); R[1] = 2.0 * (x * y - w * z);       R[2] = 2.0 * (x * z + w * y);
  R[3] = 2.0 * (x * y + w * z);       R[4] = 1.0 - 2.0 * (x * x + z * z); R[5] = 2.0 * (y * z - w * x);
  R[6] = 2.0 * (x * z - w * y);       R[7] = 2.0 * (y * z + w * x);       R[8] = 1.0 - 2.0 * (x * x + y * y);
}

// a * b (Hamilton product)
CPS_HD CPS_INLINE void quat_mul(const double a[4], const double b[4], double out[4]) {
  out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
  out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
  out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
  out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
}

// the rotation by |u| about u as a quaternion
CPS_HD CPS_INLINE void quat_axis_angle(const double u[3], double q[4]) {
  const double th = sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
  const double s = th > 0.0 ? sin(0.5 * th) / th : 0.5;
  q[0] = cos(0.5 * th);
  for (int k = 0; k < 3; ++k) q[1 + k] = s * u[k];
}

// the free body's state at t = 0 from its motion's c0, a0 (degrees, R = Rz Ry Rx), vel, omega
CPS_HD inline void free_body_start(const BodyMotion& b, double s[kFreeStateDoubles]) {
  const double ux[3] = {b.a0[0] * kDegToRad, 0.0, 0.0}, uy[3] = {0.0, b.a0[1] * kDegToRad, 0.0},
               uz[3] = {0.0, 0.0, b.a0[2] * kDegToRad};
  double qx[4], qy[4], qz[4], qzy[4];
  quat_axis_angle(ux, qx);
  quat_axis_angle(uy, qy);
  quat_axis_angle(uz, qz);
  quat_mul(qz, qy, qzy);
  quat_mul(qzy, qx, s + 3);
  for (int k = 0; k < 3; ++k) {
    s[k] = b.c0[k];
    s[7 + k] = b.vel[k];
    s[10 + k] = b.omega[k];
  }
}

// the pose (kBodyPoseFloats layout: c, R, v_c, w) of a free body's state
CPS_HD CPS_INLINE void free_body_pose(const double s[kFreeStateDoubles], double out[kBodyPoseFloats]) {
  quat_matrix(s + 3, out + 3);
  for (int k = 0; k < 3; ++k) {
    out[k] = s[k];
    out[12 + k] = s[7 + k];
    out[15 + k] = s[10 + k];
  }
}

// one step of a free body (rigid-body equations, double): the acceleration
//   a = F / M + g (g: gravity and the box's control acceleration),
//   alpha = I_w^-1 (T - w x I_w w),  I_w = R I_body R^T,
// taken with the fluid's position update (Verlet's x += v dt + a dt^2 / 2, v += a dt, one
// force evaluation a step as DualSPHysics moves its floating bodies; symplectic Euler: v += a dt,
// x += v dt), the rotation by the angle vector w dt + alpha dt^2 / 2 (symplectic: the new w dt)
// applied to q (renormalised). 2-D (D = 2): motion in x-y and rotation about z only.
CPS_HD inline void free_body_step(const BodyMotion& b, double s[kFreeStateDoubles], const double F[3],
                                  const double T[3], const double g[3], double dt, bool symplectic, int D) {
  double R[9], I[9], tmp[9], Rt[9];
  quat_matrix(s + 3, R);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) Rt[3 * r + c] = R[3 * c + r];
  matmul3(R, b.inertia, tmp);
  matmul3(tmp, Rt, I);
  const double* w = s + 10;
  const double Iw[3] = {I[0] * w[0] + I[1] * w[1] + I[2] * w[2], I[3] * w[0] + I[4] * w[1] + I[5] * w[2],
                        I[6] * w[0] + I[7] * w[1] + I[8] * w[2]};
  const double rhs[3] = {T[0] - (w[1] * Iw[2] - w[2] * Iw[1]), T[1] - (w[2] * Iw[0] - w[0] * Iw[2]),
                         T[2] - (w[0] * Iw[1] - w[1] * Iw[0])};
  // I^-1 rhs by cofactors (I symmetric positive definite)
  const double c00 = I[4] * I[8] - I[5] * I[7], c01 = I[5] * I[6] - I[3] * I[8], c02 = I[3] * I[7] - I[4] * I[6];
  const double c11 = I[0] * I[8] - I[2] * I[6], c12 = I[1] * I[6] - I[0] * I[7], c22 = I[0] * I[4] - I[1] * I[3];
  const double det = I[0] * c00 + I[1] * c01 + I[2] * c02;
  double alpha[3] = {(c00 * rhs[0] + c01 * rhs[1] + c02 * rhs[2]) / det,
                     (c01 * rhs[0] + c11 * rhs[1] + c12 * rhs[2]) / det,
                     (c02 * rhs[0] + c12 * rhs[1] + c22 * rhs[2]) / det};
  double a[3];
  for (int k = 0; k < 3; ++k) a[k] = F[k] / b.mass + g[k];
  if (D == 2) {
    a[2] = 0.0;
    alpha[0] = alpha[1] = 0.0;
  }
  double th[3];
  for (int k = 0; k < 3; ++k) {
    const double v0 = s[7 + k], w0 = s[10 + k];
    const double v1 = v0 + a[k] * dt, w1 = w0 + alpha[k] * dt;
    s[k] += symplectic ? v1 * dt : v0 * dt + 0.5 * a[k] * dt * dt;
    th[k] = symplectic ? w1 * dt : w0 * dt + 0.5 * alpha[k] * dt * dt;
    s[7 + k] = v1;
    s[10 + k] = w1;
  }
  double dq[4], q[4];
  quat_axis_angle(th, dq);
  quat_mul(dq, s + 3, q);
  const double n = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  for (int k = 0; k < 4; ++k) s[3 + k] = q[k] / n;
}

// the tank's contact on a free body's particle at x with velocity v (an acceleration): a
// spring-dashpot on its penetration pen = r0 - d past each wall's inner face (d its distance
// from the face, r0 = half a spacing: the body's surface at the face), a = (k pen - c v_n) n
// along the face's inward normal n, never pulling (DEM's penalty wall, physics/dem.h's form)
template <int D>
CPS_HD CPS_INLINE Vec<D> tank_contact(const Vec<D>& lo, const Vec<D>& hi, int periodic_mask, float r0, float k,
                                      float c, const Vec<D>& x, const Vec<D>& v) {
  Vec<D> a = Vec<D>::zero();
  for (int ax = 0; ax < D; ++ax) {
    if (periodic_mask & (1 << ax)) continue;
    const float pen_lo = r0 - (x[ax] - lo[ax]), pen_hi = r0 - (hi[ax] - x[ax]);
    if (pen_lo > 0.0f) {
      const float f = k * pen_lo - c * v[ax];
      if (f > 0.0f) a[ax] += f;
    }
    if (pen_hi > 0.0f) {
      const float f = k * pen_hi + c * v[ax];
      if (f > 0.0f) a[ax] -= f;
    }
  }
  return a;
}

}  // namespace cps::sph
