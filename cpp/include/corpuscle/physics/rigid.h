// Rigid box bodies: signed distance, particle contact + drag coupling, and integration in
// the (possibly accelerating and rotating) container frame.
#pragma once
#include "corpuscle/core/quat.h"

namespace cps {

struct RigidBox {
  Vec3 half;     // half extents (m)
  float mass;    // kg
  Vec3 inertia;  // principal moments in the body frame (kg m^2)
  CPS_HD float volume() const { return 8.0f * half[0] * half[1] * half[2]; }
};

struct RigidState {
  Vec3 x, v;      // centre and velocity (container frame)
  Quat q;         // body -> container orientation
  Vec3 w_body;    // angular velocity in the body frame
};

// the container frame's inertial terms (Control applied to the container)
struct FrameMotion {
  Vec3 gravity;  // gravity expressed in the container frame
  Vec3 acc;      // container linear acceleration
  Vec3 alpha;    // container angular acceleration
  Vec3 omega;    // container angular velocity
};

// acceleration of a free point at x with velocity v, seen in the container frame:
// gravity minus the frame's linear, Euler, centrifugal and Coriolis terms
CPS_HD CPS_INLINE Vec3 frame_acceleration(const FrameMotion& f, const Vec3& x, const Vec3& v) {
  return f.gravity - f.acc - cross(f.alpha, x) - cross(f.omega, cross(f.omega, x)) - 2.0f * cross(f.omega, v);
}

// signed distance from body-frame point p to the box surface, with the outward normal
CPS_HD CPS_INLINE float box_sdf(const Vec3& half, const Vec3& p, Vec3& n) {
  Vec3 q, o;
  float qmax = -1e30f;
  int kmax = 0;
  for (int k = 0; k < 3; ++k) {
    float a = p[k] < 0.0f ? -p[k] : p[k];
    q[k] = a - half[k];
    o[k] = q[k] > 0.0f ? q[k] : 0.0f;
    if (q[k] > qmax) { qmax = q[k]; kmax = k; }
  }
  float out = norm(o);
  if (out > 0.0f) {
    for (int k = 0; k < 3; ++k) n[k] = (p[k] < 0.0f ? -o[k] : o[k]) / out;
    return out;
  }
  n = Vec3::zero();
  n[kmax] = p[kmax] < 0.0f ? -1.0f : 1.0f;
  return qmax;
}

struct ContactParams {
  float margin;     // contact when the signed distance is below this (m)
  float stiffness;  // spring acceleration per metre of penetration into the margin (1/s^2)
  float drag;       // relative-velocity drag rate inside the margin (1/s)
};

// acceleration of a particle at x, v from a body's contact spring (along the surface normal)
// and drag on the relative velocity; false when out of reach
CPS_HD CPS_INLINE bool body_contact(const ContactParams& c, const RigidBox& b, const RigidState& s, const Vec3& x,
                                    const Vec3& v, Vec3& acc) {
  Vec3 r = x - s.x;
  float reach = c.margin + norm(b.half);
  if (norm2(r) >= reach * reach) return false;
  Vec3 nl;
  float sd = box_sdf(b.half, qrotate_inv(s.q, r), nl);
  if (sd >= c.margin) return false;
  Vec3 n = qrotate(s.q, nl);
  Vec3 v_surface = s.v + cross(qrotate(s.q, s.w_body), r);
  acc = n * (c.stiffness * (c.margin - sd)) + (v_surface - v) * c.drag;
  return true;
}

struct BodyParams {
  float linear_damping;  // 1/s
  float angular_damping; // 1/s
  float restitution;     // against the container wall
};

// semi-implicit Euler for a box under the fluid's reaction force/torque (container frame),
// its weight in the frame's effective gravity, Coriolis, and damping. Buoyancy is not added:
// it arrives through the contact reactions of the fluid pressing on the body.
CPS_HD CPS_INLINE void integrate_box(const RigidBox& b, const BodyParams& p, const FrameMotion& f, const Vec3& force,
                                     const Vec3& torque, float dt, RigidState& s) {
  // effective gravity at the body centre (no Coriolis: it acts on the body's own velocity below)
  Vec3 g_eff = f.gravity - f.acc - cross(f.alpha, s.x) - cross(f.omega, cross(f.omega, s.x));
  Vec3 F = force + g_eff * b.mass - cross(f.omega, s.v) * (2.0f * b.mass) - s.v * (b.mass * p.linear_damping);
  s.v += F * (dt / b.mass);
  s.x += s.v * dt;
  // rotation: w_body is the angular velocity relative to the container (body frame). Euler's
  // equations hold for the absolute one, wa = w + Omega: I dwa/dt = tau - wa x (I wa); seen
  // from the container, dw/dt = dwa/dt - alpha - Omega x w (the frame's Euler and transport
  // terms). Damping acts on the rotation relative to the container (the fluid's drag)
  Vec3 w = s.w_body;
  Vec3 Om = qrotate_inv(s.q, f.omega);
  Vec3 al = qrotate_inv(s.q, f.alpha);
  Vec3 wa = w + Om;
  Vec3 Iwa{{b.inertia[0] * wa[0], b.inertia[1] * wa[1], b.inertia[2] * wa[2]}};
  Vec3 Iw{{b.inertia[0] * w[0], b.inertia[1] * w[1], b.inertia[2] * w[2]}};
  Vec3 tb = qrotate_inv(s.q, torque) - cross(wa, Iwa) - Iw * p.angular_damping;
  Vec3 transport = al + cross(Om, w);
  for (int k = 0; k < 3; ++k) w[k] += (tb[k] / b.inertia[k] - transport[k]) * dt;
  s.w_body = w;
  s.q = qintegrate_body(s.q, w, dt);
}

// push a box back inside a sphere of radius R about the origin (deepest corner) and
// reflect its outward velocity with restitution
CPS_HD CPS_INLINE void keep_box_in_sphere(const RigidBox& b, float R, float restitution, RigidState& s) {
  float worst = 0.0f;
  Vec3 wn = Vec3::zero();
  for (int c = 0; c < 8; ++c) {
    Vec3 corner{{(c & 1) ? b.half[0] : -b.half[0], (c & 2) ? b.half[1] : -b.half[1], (c & 4) ? b.half[2] : -b.half[2]}};
    Vec3 cw = s.x + qrotate(s.q, corner);
    float r = norm(cw);
    if (r - R > worst) { worst = r - R; wn = cw * (1.0f / r); }
  }
  if (worst <= 0.0f) return;
  s.x -= wn * worst;
  float vn = dot(s.v, wn);
  if (vn > 0.0f) s.v -= wn * ((1.0f + restitution) * vn);
}

}  // namespace cps
