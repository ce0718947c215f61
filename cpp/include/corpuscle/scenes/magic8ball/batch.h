// The Magic 8-Ball's stages outside a step, for a batch of scenes: the reset cache (every
// scene's fluid slots and record, kept on the device), the restore of chosen scenes from it
// (optionally turned by a symmetry, see SceneTurn) and the per-scene observations written
// into arrays of their own (shared with Python without copies).
#pragma once
#include "corpuscle/scenes/magic8ball/stages.h"

namespace cps::m8 {

// how a restored scene is placed: the whole scene (fluid, die) turned by `turn` about the
// container's centre, and the die by `sym` in its body frame. For a settled scene in a
// container at rest, a turn about gravity is a symmetry of the physics (the sphere is round),
// and a rotation that maps the die's box onto itself (a cube has 24) changes only which face
// is where: both give another settled state, exactly as sound as the cached one. Identity
// quaternions restore the cached state bit for bit.
struct SceneTurn {
  Quat turn;
  Quat sym;
  int scene;
};

CPS_HD CPS_INLINE bool is_identity(const Quat& q) {
  return q.w == 1.0f && q.x == 0.0f && q.y == 0.0f && q.z == 0.0f;
}

// keep fluid slot i of the current state (positions, velocities, ids)
struct CacheFluidStage {
  Arrays a;
  Vec3 *pos, *vel;
  int* id;
  CPS_HD void operator()(int i) const {
    pos[i] = a.position[i];
    vel[i] = a.velocity[i];
    id[i] = a.id[i];
  }
};

// keep scene s's record with its clock restarted (time and step zero, sound, not done)
struct CacheRecordStage {
  const Scene* g;
  Scene* out;
  CPS_HD void operator()(int s) const {
    Scene r = g[s];
    r.clock.time = 0.0;
    r.clock.step = 0;
    r.clock.done = 0;
    r.clock.bad = 0;
    r.clock.bad_step = -1;
    out[s] = r;
  }
};

// restore fluid slot (item % n_fluid) of the scene of turns[item / n_fluid] from the cache, and
// key it for the next step (which sorts and relists that scene)
struct RestoreFluidStage {
  const Model* model;
  const Scene* cached;
  const SceneTurn* turns;
  Arrays a;
  const Vec3 *pos, *vel;
  const int* id;
  CPS_HD void operator()(int item) const {
    const Model& m = *model;
    const SceneTurn& t = turns[item / m.n_fluid];
    const int local = item % m.n_fluid, i = t.scene * m.n_fluid + local;
    Vec3 x = pos[i], v = vel[i];
    if (!is_identity(t.turn)) {
      x = qrotate(t.turn, x);
      v = qrotate(t.turn, v);
    }
    a.position[i] = x;
    a.velocity[i] = v;
    a.id[i] = id[i];
    write_keys(m, a, i, x, local < cached[t.scene].phys.n_active);
    a.ghost_of[i] = -1;
  }
};

// restore the record of the scene of turns[q] (its end time stays), turned like its fluid
struct RestoreRecordStage {
  Scene* g;
  const Scene* cached;
  const SceneTurn* turns;
  CPS_HD void operator()(int q) const {
    const SceneTurn& t = turns[q];
    Scene r = cached[t.scene];
    r.clock.end_time = g[t.scene].clock.end_time;
    r.clock.done = r.clock.time >= r.clock.end_time ? 1 : 0;
    if (!is_identity(t.turn) || !is_identity(t.sym)) {
      RigidState& d = r.die;
      d.x = qrotate(t.turn, d.x);
      d.v = qrotate(t.turn, d.v);
      d.q = qnormalize(qmul(qmul(t.turn, d.q), t.sym));
      d.w_body = qrotate_inv(t.sym, d.w_body);  // the same angular velocity, in the new body axes
      r.sums.force = qrotate(t.turn, r.sums.force);
      r.sums.torque = qrotate(t.turn, r.sums.torque);
    }
    // the next step sorts and relists this scene (as a restored state's first step does)
    r.rebuild[0] = r.rebuild[1] = 0;
    r.rebuild[r.clock.step & 1] = 1;
    r.moved[0] = r.moved[1] = 0;
    r.pending = r.sums;
    r.step_dt = 0.0f;
    g[t.scene] = r;
  }
};

// the observations of scene s: die pose and velocities (container frame), the face toward
// the window, the clock
struct ObserveStage {
  const Scene* g;
  float *pos, *quat, *vel, *omega;
  int *face, *done, *bad;
  double* time;
  CPS_HD void operator()(int s) const {
    const Scene& r = g[s];
    const Vec3 w = qrotate(r.die.q, r.die.w_body);
    for (int k = 0; k < 3; ++k) {
      pos[3 * s + k] = r.die.x[k];
      vel[3 * s + k] = r.die.v[k];
      omega[3 * s + k] = w[k];
    }
    quat[4 * s + 0] = r.die.q.w;
    quat[4 * s + 1] = r.die.q.x;
    quat[4 * s + 2] = r.die.q.y;
    quat[4 * s + 3] = r.die.q.z;
    face[s] = window_face(r.die.q);
    done[s] = r.clock.done;
    bad[s] = r.clock.bad;
    time[s] = r.clock.time;
  }
};

}  // namespace cps::m8
