"""The container wall on the real core: a particle that a step carries past the wall is put
back on it and, when it was moving outward, reflected with restitution and friction
(physics/boundary.h ``reflect_at_wall``):

    x' = n R (1 - 1e-5),  n = x / |x|                      (x: the drifted position)
    v' = (1 - f) v_t - e v_n n    when v_n = v . n > 0     (v_t = v - v_n n)
    v' = v                        otherwise

with e = ``container.restitution`` ("fraction of normal wall velocity kept on contact") and
f = ``container.friction`` ("fraction of tangential wall velocity removed on contact").

The check is one step with a fixed dt of particles placed at the wall with random velocities,
against a float64 NumPy version of that formula applied to the core's own drift. XSPH is
off, so the drift is x + (v + a dt) dt exactly, with a the core's acceleration of the same
state (``evaluate``); viscosity is off and the fluid is made almost pressureless, so a is
essentially gravity and the velocities placed are the ones that meet the wall.
"""

import numpy as np
import pytest

pytest.importorskip("corpuscle._core")

from corpuscle import Simulation

N = 200  # the scene schema's minimum
R = 0.15
DT = 1e-3
G = (0.0, 0.0, -9.81)  # the scene's gravity


def make(restitution, friction):
    ovr = {"sph.scale_h": False, "shake": [], "fluid.xsph": 0.0, "fluid.viscosity": 0.0, "fluid.stiffness": 1e-6,
           "timestep.dt_min": DT, "timestep.dt_max": DT,
           "container.restitution": restitution, "container.friction": friction}
    return Simulation.from_scene("magic8ball", backend="cpu", particles=N, seed=1, overrides=ovr)


def by_id(sim, name):
    ids = sim.field("id", copy=True)
    out = np.empty_like(sim.field(name, copy=True))
    out[ids] = sim.field(name, copy=True)
    return out.astype(np.float64)


def wall_state(rng):
    """Particles at the wall: 150 up to 3 mm inside it moving mostly outward (0 to 6 m/s
    normal: up to 6 mm in one step, so most cross), 30 just beyond the clamp radius
    R (1 - 1e-5) moving slowly inward (clamped, not reflected), 20 well inside (beyond the
    reach of the die at the centre)."""
    d = rng.normal(size=(N, 3))
    n = d / np.linalg.norm(d, axis=1)[:, None]
    r = np.empty(N)
    r[:150] = R - rng.uniform(1e-5, 3e-3, size=150)
    r[150:180] = R * (1 - 0.5e-5)
    r[180:] = rng.uniform(0.08, 0.12, size=20)  # beyond the die's reach
    pos = n * r[:, None]
    tang = rng.normal(size=(N, 3))
    tang -= np.einsum("ij,ij->i", tang, n)[:, None] * n
    vn = np.empty(N)
    vn[:150] = rng.uniform(-1.0, 6.0, size=150)
    vn[150:180] = -rng.uniform(1e-5, 1e-4, size=30)  # stays beyond the clamp radius in one step
    vn[180:] = rng.uniform(-1.0, 1.0, size=20)
    vel = vn[:, None] * n + tang * rng.uniform(0.0, 2.0, size=(N, 1))
    # the clamped ones move straight inward once gravity has acted for the step
    vel[150:180] = vn[150:180, None] * n[150:180] - np.asarray(G) * DT
    return pos.astype(np.float32), vel.astype(np.float32)


@pytest.mark.parametrize("restitution, friction", [(0.3, 0.1), (0.0, 0.0), (1.0, 1.0), (0.65, 0.4)])
def test_wall_reflection_follows_the_formula(restitution, friction):
    sim = make(restitution, friction)
    rng = np.random.default_rng(int(restitution * 100) * 7 + int(friction * 100))
    pos, vel = wall_state(rng)
    sim.set_particles(pos, vel)
    sim.set_die(position=(0.0, 0.0, 0.0))  # the die keeps clear of the wall band (its reach is 0.064 m)
    st = sim.evaluate()
    assert st["die_contacts"] == 0
    a = by_id(sim, "acceleration")
    # almost pressureless, inviscid: the acceleration is gravity up to a few 1e-3 m/s^2
    assert np.abs(a - np.asarray(sim.params["gravity"])).max() < 0.1
    sim.step(1)
    assert sim.dt == pytest.approx(DT, rel=1e-7)
    x1, v1 = by_id(sim, "position"), by_id(sim, "velocity")

    # the core's drift, then the formula (float64)
    v = vel.astype(np.float64) + a * DT
    x = pos.astype(np.float64) + v * DT
    r = np.linalg.norm(x, axis=1)
    lim = R * (1 - 1e-5)
    n = x / r[:, None]
    vn = np.einsum("ij,ij->i", v, n)
    # leave out particles whose drifted radius or normal speed is within float32 rounding of a
    # branch point (none expected with these random inputs, so the counts below still hold)
    clear = (np.abs(r - lim) > 1e-7) & ((r <= lim) | (np.abs(vn) > 1e-6))
    hit = clear & (r > lim)
    out = hit & (vn > 0)
    clamped = hit & (vn <= 0)
    free = clear & (r <= lim)
    assert out.sum() >= 80 and clamped.sum() >= 25 and free.sum() >= 40, (out.sum(), clamped.sum(), free.sum())

    vt = v - vn[:, None] * n
    v_exp = v.copy()
    v_exp[out] = (1 - friction) * vt[out] - restitution * vn[out, None] * n[out]
    x_exp = x.copy()
    x_exp[hit] = n[hit] * lim
    # float32: a handful of roundings of positions ~0.15 m (1e-8 m each) and of velocities
    # up to ~6 m/s (4e-7 m/s each)
    np.testing.assert_allclose(x1[clear], x_exp[clear], rtol=0, atol=1e-7)
    tol = 2e-6 * (1 + np.linalg.norm(v, axis=1))
    err = np.linalg.norm(v1 - v_exp, axis=1)
    assert np.all(err[clear] <= tol[clear]), err[clear].max()

    # the same, read as the documented fractions: every reflected particle keeps -e of its
    # normal velocity and 1 - f of its tangential velocity; clamped ones keep their velocity
    vn1 = np.einsum("ij,ij->i", v1, n)
    assert np.all(np.abs(vn1[out] + restitution * vn[out]) <= tol[out])
    vt1 = v1 - vn1[:, None] * n
    assert np.all(np.linalg.norm(vt1[out] - (1 - friction) * vt[out], axis=1) <= tol[out])
    np.testing.assert_allclose(v1[clamped], v[clamped], rtol=0, atol=1e-6)
    # and every particle ends inside the wall
    assert np.linalg.norm(x1, axis=1).max() <= R * (1 - 1e-5) * (1 + 1e-6)


def test_reflected_particles_move_inward_and_lose_energy():
    # with the scene's e = 0.3 and f = 0.1 a reflected particle heads back in, and its speed
    # is at most that of the particle that hit (every factor is <= 1): a wall that kept
    # or amplified the outward velocity would fail
    sim = make(0.3, 0.1)
    pos, vel = wall_state(np.random.default_rng(3))
    sim.set_particles(pos, vel)
    sim.set_die(position=(0.0, 0.0, 0.0))
    sim.step(1)
    x1, v1 = by_id(sim, "position"), by_id(sim, "velocity")
    r1 = np.linalg.norm(x1, axis=1)
    on_wall = r1 > R * (1 - 2e-5)
    n1 = x1 / r1[:, None]
    vn1 = np.einsum("ij,ij->i", v1, n1)
    started_out = np.einsum("ij,ij->i", vel.astype(np.float64), pos / np.linalg.norm(pos, axis=1)[:, None]) > 0.5
    sel = on_wall & started_out
    assert sel.sum() >= 50
    assert np.all(vn1[sel] < 0)
    # (+ |g| dt: gravity acts for one step before the wall)
    assert np.all(np.linalg.norm(v1[sel], axis=1) <= np.linalg.norm(vel[sel], axis=1) + 9.81 * DT * 1.01)


def test_steps_after_the_end_time_leave_wall_particles_alone():
    # Simulation.step: "steps after a run's end time are no-ops". Particles placed exactly where
    # the wall clamp puts them (x = n lim in float32) whose float32 radius rounds above lim:
    # a no-op step must leave them where they are.
    sim = make(0.3, 0.1)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(N, 3))
    n = (d / np.linalg.norm(d, axis=1)[:, None]).astype(np.float32)
    lim = np.float32(R * (1 - 1e-5))
    x = n * lim
    r32 = np.sqrt((x * x).sum(axis=1, dtype=np.float32))
    assert (r32 > lim).sum() >= 3  # some of them round outside the clamp radius (9 of these 200)
    sim.set_particles(x, np.zeros_like(x))
    sim.set_die(position=(0.0, 0.0, 0.0))
    sim.set_end_time(0.0)
    sim.step(1)
    assert sim.time == 0.0 and sim.dt == 0.0
    np.testing.assert_array_equal(by_id(sim, "position"), x.astype(np.float64))
