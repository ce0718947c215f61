"""Shaking on the real core: a shake window inside the run acts only within it, exactly as a
Python control switched on and off at the same times; the container shell's spin follows
its closed form; the rotating-frame terms on the fluid and on the die match a float64
reference of the container-frame equations (physics/rigid.h).

Times are binary fractions (0.125 s, 0.25 s, 0.375 s): the schedule stores its windows in
float32 and the clock is a double, so these compare equal in both.
"""

import math

import numpy as np
import pytest

pytest.importorskip("corpuscle._core")

from corpuscle import Simulation

BACKEND = "cpu"
T1, T2, T_END = 0.125, 0.25, 0.375  # the window [T1, T2) lies inside the run [0, T_END]
ACC = (4.0, 0.0, -2.0)  # m/s^2
TORQUE = (0.06, -0.04, 0.12)  # N m: |tau| / I = 7 rad/s^2 on the scene's 0.02 kg m^2 shell
EPS32 = float(np.finfo(np.float32).eps)


def make(schedule=(), particles=300, **overrides):
    return Simulation.from_scene("magic8ball", backend=BACKEND, particles=particles, seed=2,
                                 overrides={"shake": list(schedule), **overrides})


def advance(sim, until, record=None):
    """Step one at a time until the clock reaches `until` (the last step is shortened to land
    on it), recording (time, dt, shell angular velocity, shell orientation) after each."""
    sim.set_end_time(until)
    while sim.time < until:
        sim.step(1)
        if record is not None:
            st = sim.state()
            record.append((st["time"], st["dt"], np.array(st["shell_angular_velocity"], dtype=np.float64),
                           np.array(st["shell_orientation"], dtype=np.float64)))
    assert sim.time == until


def snapshot(sim):
    fields = {name: sim.field(name, copy=True) for name in ("position", "velocity", "density", "pressure", "id",
                                                            "ghost_position")}
    return fields, sim.state()


def assert_same(a, b):
    fa, sa = a
    fb, sb = b
    for name in fa:
        assert fa[name].tobytes() == fb[name].tobytes(), name
    assert sa == sb


WINDOW = [{"start": T1, "end": T2, "acceleration": list(ACC), "torque": list(TORQUE)}]


@pytest.fixture(scope="module")
def window_runs():
    """The same start three ways: a shake window [T1, T2) in the schedule; no schedule but a
    Python control switched on at T1 and off at T2; no shaking at all. Each stops at T1, T2
    and T_END (the same core calls in the same order), with a snapshot at each stop."""
    runs = {}
    for name in ("schedule", "control", "still"):
        sim = make(WINDOW if name == "schedule" else ())
        snaps, record = [], []
        advance(sim, T1, record)
        snaps.append(snapshot(sim))
        if name == "control":
            sim.set_control(acceleration=ACC, torque=TORQUE)
        advance(sim, T2, record)
        snaps.append(snapshot(sim))
        if name == "control":
            sim.set_control()
        advance(sim, T_END, record)
        snaps.append(snapshot(sim))
        runs[name] = {"sim": sim, "snaps": snaps, "record": record}
    return runs


def test_nothing_is_applied_before_the_window(window_runs):
    # up to T1 the scheduled run is the unshaken run, bit for bit, shell at rest
    sched, still = window_runs["schedule"], window_runs["still"]
    assert_same(sched["snaps"][0], still["snaps"][0])
    st = sched["snaps"][0][1]
    assert st["shell_angular_velocity"] == [0.0, 0.0, 0.0]
    assert st["shell_orientation"] == [1.0, 0.0, 0.0, 0.0]


def test_window_acts_exactly_like_a_control_switched_on_and_off(window_runs):
    # the schedule and set_control feed the same frame terms: from T1 to T2 (control on) and
    # from T2 on (control off, window over) the two runs agree bit for bit. A schedule that
    # ignored its start would differ from T1 (it would have acted before), one that ignored
    # its end from T2 on.
    sched, ctrl = window_runs["schedule"], window_runs["control"]
    for k in range(3):
        assert_same(sched["snaps"][k], ctrl["snaps"][k])


def test_the_window_does_shake(window_runs):
    # ... and the window really acts: after it the fluid, the die and the shell differ from
    # the unshaken run. The fluid's centre of mass moves against the 4 m/s^2 push along +x: in
    # the container frame the effective gravity tilts by atan(4 / 9.81) = 22 degrees for
    # 0.125 s, and the fluid's settling (its centre of mass drops ~1.5 cm at this resolution)
    # follows it, ~0.4 x 1.5 cm toward -x; measured -7.5 mm at T_END, bound -2 mm
    sched, still = window_runs["schedule"], window_runs["still"]
    xs = sched["snaps"][2][0]["position"].astype(np.float64).mean(axis=0)
    xu = still["snaps"][2][0]["position"].astype(np.float64).mean(axis=0)
    assert xs[0] - xu[0] < -2e-3, (xs, xu)
    assert np.linalg.norm(sched["snaps"][2][1]["shell_angular_velocity"]) > 0.1
    assert still["snaps"][2][1]["shell_angular_velocity"] == [0.0, 0.0, 0.0]


def spin_closed_form(t, tau_over_i, k):
    """The shell's spin |omega| and angle for d omega/dt = tau/I - k omega inside [T1, T2),
    -k omega outside, from rest: omega = s (1 - e^{-k (t - T1)}) in the window (s = tau/(I k)),
    then omega(T2) e^{-k (t - T2)}; the angle is its integral."""
    s = tau_over_i / k
    if t <= T1:
        return 0.0, 0.0
    if t <= T2:
        u = t - T1
        return s * (1 - math.exp(-k * u)), s * (u - (1 - math.exp(-k * u)) / k)
    w2, th2 = spin_closed_form(T2, tau_over_i, k)
    u = t - T2
    return w2 * math.exp(-k * u), th2 + w2 * (1 - math.exp(-k * u)) / k


def test_shell_spin_follows_its_closed_form(window_runs):
    # the shell: I d omega/dt = tau - I k omega (container frame), integrated by explicit Euler
    # (omega += (tau/I - k omega) dt) and the orientation by q <- q (1, omega dt / 2),
    # normalised, with the updated omega. Under a torque of fixed direction from rest, omega
    # stays along tau and the shell turns about that fixed axis, so it is the scalar problem
    # of spin_closed_form.
    # Discretisation error of Euler on this linear problem: each step's local error is at most
    # dt^2/2 max|omega''| with |omega''| = k |omega'| <= k tau/I (in the window and in the decay
    # after it, since omega <= tau/(I k)); the scheme damps earlier errors (|1 - k dt| < 1), so
    # after n steps |omega_n - omega(t_n)| <= (k tau/I / 2) sum dt^2. The angle sums
    # omega_{n+1} dt (a right-endpoint rule: <= dt^2/2 max|omega'| <= dt^2/2 tau/I a step) plus
    # the omega errors times dt; 2 atan(omega dt / 2) instead of omega dt is 1e-10 here.
    # float32 rounding: a few eps of omega (and of the angle) a step, 4 n eps in all.
    # Both the window's start and end are at step boundaries (the run lands on them), so no
    # step straddles a switch.
    rec = window_runs["schedule"]["record"]
    sim = window_runs["schedule"]["sim"]
    inertia, k = sim.params["shell_inertia"], sim.params["spin_damping"]
    tau = np.asarray(TORQUE, dtype=np.float64)
    axis = tau / np.linalg.norm(tau)
    a = np.linalg.norm(tau) / inertia
    w_max = a / k
    sum_dt2 = 0.0
    err_w_int = 0.0  # sum over steps of dt times the omega error bound
    t_prev = 0.0
    worst = (0.0, 0.0)
    for n, (t, dt, w, q) in enumerate(rec, start=1):
        assert dt == pytest.approx(t - t_prev, rel=1e-6, abs=1e-12)
        sum_dt2 += dt * dt
        w_exact, th_exact = spin_closed_form(t, a, k)
        bound_w = 0.5 * k * a * sum_dt2 + 4 * n * EPS32 * w_max
        err_w_int += dt * bound_w
        bound_th = err_w_int + 0.5 * a * sum_dt2 + 4 * n * EPS32
        # angular velocity: along the torque, of the closed-form size
        err_w = np.linalg.norm(w - w_exact * axis)
        assert err_w <= bound_w, (t, w, w_exact * axis, bound_w)
        # orientation: a rotation by the closed-form angle about the torque's axis
        qv = q[1:]
        angle = 2 * math.atan2(np.linalg.norm(qv), q[0])
        assert abs(angle - th_exact) <= bound_th, (t, angle, th_exact, bound_th)
        if np.linalg.norm(qv) > 1e-3:
            assert np.linalg.norm(qv / np.linalg.norm(qv) - axis) < 1e-4, (t, qv)
        worst = max(worst, (err_w / max(bound_w, 1e-30), abs(angle - th_exact) / bound_th))
        t_prev = t
    # the run covered the rest, the spin-up and the decay (0.77 rad/s at T2, decayed by
    # e^{-0.25} to 0.60 rad/s; turned 0.136 rad), and the bounds are far tighter than the
    # effects they guard: a missing damping would put omega 13% off at T2, a lost torque 100%
    assert rec[-1][0] == T_END
    w_end, th_end = spin_closed_form(T_END, a, k)
    assert w_end > 0.5 and th_end > 0.1
    assert 0.5 * k * a * sum_dt2 < 0.01 * w_end


# --------------------------------------------------------------------------------------
# the container-frame terms against a float64 reference
# --------------------------------------------------------------------------------------
def quat_matrix(q):
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def spun_up(particles=200, **overrides):
    """A simulation whose shell has been spun up (0.1 s under a 1 N m torque about a tilted
    axis: ~6 rad/s, turned ~0.3 rad, so gravity in the container frame is tilted too)."""
    sim = make(particles=particles, **overrides)
    sim.set_control(torque=(1.0, 0.6, 0.8))
    advance(sim, 0.0625)
    sim.set_end_time(math.inf)
    return sim


def frame_reference(sim, control_acc, control_torque):
    """This step's container-frame terms from the shell state and the control (magic8ball.h
    prepare_frame): gravity rotated into the container frame, the container's linear
    acceleration, its angular acceleration tau/I - k omega and angular velocity."""
    st = sim.state()
    p = sim.params
    omega = np.asarray(st["shell_angular_velocity"], dtype=np.float64)
    rot = quat_matrix(st["shell_orientation"])  # container -> lab
    g = rot.T @ np.asarray(p["gravity"], dtype=np.float64)
    alpha = np.asarray(control_torque, dtype=np.float64) / p["shell_inertia"] - p["spin_damping"] * omega
    return g, np.asarray(control_acc, dtype=np.float64), alpha, omega


def test_rotating_frame_terms_on_the_fluid():
    # a particle at x with velocity v in the container frame feels gravity (rotated into the
    # frame) minus the frame's linear acceleration A, the Euler term alpha x x, the
    # centrifugal term omega x (omega x x) and the Coriolis term 2 omega x v. The SPH forces
    # of the same particle state are the same with the shell at rest or spinning, so the
    # difference of the two evaluations is the frame terms minus plain gravity.
    acc_c, torque_c = (1.5, -2.0, 0.5), (0.3, -0.2, 0.1)
    spun = spun_up()
    rest = make(particles=200)
    rng = np.random.default_rng(7)
    pos = rest.field("position", copy=True)  # the Poisson-disk start
    vel = (rng.normal(size=pos.shape) * 0.3).astype(np.float32)
    spun.set_control(acceleration=acc_c, torque=torque_c)
    g, A, alpha, omega = frame_reference(spun, acc_c, torque_c)
    assert np.linalg.norm(omega) > 3 and np.linalg.norm(g - np.asarray(rest.params["gravity"])) > 1
    out = []
    for sim in (spun, rest):
        sim.set_particles(pos, vel)
        sim.set_die(position=(0.0, 0.0, 0.0), orientation=(1.0, 0.0, 0.0, 0.0), velocity=(0.0, 0.0, 0.0),
                    angular_velocity=(0.0, 0.0, 0.0))
        sim.evaluate()
        order = np.argsort(sim.field("id", copy=True))
        out.append(sim.field("acceleration", copy=True)[order].astype(np.float64))
    x, v = pos.astype(np.float64), vel.astype(np.float64)
    terms = [np.broadcast_to(g, x.shape), -np.broadcast_to(A, x.shape), -np.cross(alpha, x),
             -np.cross(omega, np.cross(omega, x)), -2 * np.cross(omega, v)]
    expected = sum(terms) - np.asarray(rest.params["gravity"], dtype=np.float64)
    # float32: each acceleration is the SPH sum plus the frame terms, rounded: a few eps of
    # |a| for either evaluation, plus a few eps of the terms' sizes
    scale = (np.linalg.norm(out[0], axis=1) + np.linalg.norm(out[1], axis=1)
             + sum(np.linalg.norm(t, axis=1) for t in terms))
    err = np.linalg.norm(out[0] - out[1] - expected, axis=1)
    assert np.all(err <= 8 * EPS32 * scale), (err / scale).max()
    # every term is far above that tolerance, so each one is checked (a missing or
    # wrong-signed term would be off by twice its size)
    for t in terms[1:]:
        assert np.median(np.linalg.norm(t, axis=1)) > 100 * np.median(8 * EPS32 * scale)


def die_alone(spun):
    """Put the die at (0, 0, 0.04), tilted and moving, with every fluid particle beyond its
    contact reach (0.056 m half diagonal + margin), so only the frame acts on it."""
    rng = np.random.default_rng(3)
    centre = np.array([0.0, 0.0, 0.04])
    pts = np.empty((0, 3))
    while len(pts) < spun.n_particles:
        c = rng.uniform(-0.149, 0.149, size=(4000, 3))
        c = c[(np.linalg.norm(c, axis=1) < 0.149) & (np.linalg.norm(c - centre, axis=1) > 0.08)]
        pts = np.concatenate([pts, c])
    pos = pts[:spun.n_particles].astype(np.float32)
    spun.set_particles(pos, np.zeros_like(pos))
    q = np.array([0.9, 0.2, -0.3, 0.25])
    q /= np.linalg.norm(q)
    spun.set_die(position=centre, orientation=q, velocity=(0.05, -0.1, 0.08), angular_velocity=(0.0, 0.0, 0.0))


def test_rotating_frame_terms_on_the_die():
    # the die (no particle in reach, so no fluid force) in one step of fixed dt: semi-implicit
    # Euler of m dv/dt = m g_eff - 2 m omega x v - m c v, with g_eff = g - A - alpha x X -
    # omega x (omega x X) at its centre X (rigid.h integrate_box), then X += v' dt
    dt = 1e-3
    acc_c, torque_c = (1.5, -2.0, 0.5), (0.3, -0.2, 0.1)
    spun = spun_up(**{"timestep.dt_min": dt, "timestep.dt_max": dt, "die.linear_damping": 0.7})
    die_alone(spun)
    spun.set_control(acceleration=acc_c, torque=torque_c)
    g, A, alpha, omega = frame_reference(spun, acc_c, torque_c)
    d0 = {k: np.asarray(v, dtype=np.float64) for k, v in spun.state()["die"].items()}
    assert spun.evaluate()["die_contacts"] == 0
    spun.step(1)
    assert spun.dt == pytest.approx(dt, rel=1e-7)
    d1 = {k: np.asarray(v, dtype=np.float64) for k, v in spun.state()["die"].items()}
    X, V = d0["position"], d0["velocity"]
    g_eff = g - A - np.cross(alpha, X) - np.cross(omega, np.cross(omega, X))
    v1 = V + dt * (g_eff - 2 * np.cross(omega, V) - 0.7 * V)
    x1 = X + v1 * dt
    # float32 of values ~0.1 m/s and ~0.05 m: 1e-7 absolute leaves room for a few roundings;
    # the frame terms change v by ~1e-2 m/s in this step, so each is checked
    np.testing.assert_allclose(d1["velocity"], v1, rtol=0, atol=1e-7)
    np.testing.assert_allclose(d1["position"], x1, rtol=0, atol=1e-8)
    assert np.linalg.norm(dt * (np.cross(alpha, X) + np.cross(omega, np.cross(omega, X)))) > 1e-4
    assert np.linalg.norm(dt * 2 * np.cross(omega, V)) > 1e-4


def test_die_rotation_sees_the_spinning_frame():
    # A die with no torque on it keeps its angular velocity in the lab frame. Seen from the
    # container, which spins at omega with angular acceleration alpha, its relative angular
    # velocity w obeys dw/dt = tau/I - alpha - omega x w (isotropic inertia, container frame
    # components): from w = 0 one step gives w' = -alpha dt (a die that turned with the
    # container instead, w' = 0, would fail).
    dt = 1e-3
    acc_c, torque_c = (0.0, 0.0, 0.0), (0.3, -0.2, 0.1)
    spun = spun_up(**{"timestep.dt_min": dt, "timestep.dt_max": dt})
    die_alone(spun)
    spun.set_control(acceleration=acc_c, torque=torque_c)
    _, _, alpha, _ = frame_reference(spun, acc_c, torque_c)
    assert spun.evaluate()["die_contacts"] == 0
    spun.step(1)
    w1 = np.asarray(spun.state()["die"]["angular_velocity"], dtype=np.float64)
    np.testing.assert_allclose(w1, -alpha * dt, rtol=1e-3, atol=1e-6)
