"""Backends against each other: serial and OpenMP give bit-identical runs (reductions have a
fixed order by design), runs are reproducible from their seed, and CUDA matches the CPU path
on the same input (``gpu`` mark: skipped where ``Simulation.cuda_available()`` is False).
"""

import ctypes
import hashlib
import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from corpuscle import Simulation

FIELDS = ("position", "velocity", "density", "pressure", "id", "acceleration", "ghost_position", "ghost_velocity")

# the CUDA tests: `gpu` mark, skipped cleanly without a usable device
CUDA = Simulation.cuda_available()
requires_cuda = pytest.mark.skipif(not CUDA, reason="no usable CUDA backend (build or device)")


def make(backend, particles=1000, seed=1, **overrides):
    return Simulation.from_scene("magic8ball", backend=backend, particles=particles, seed=seed, overrides=overrides)


def snapshot(sim):
    """Every field (host copies) and the state's scalars."""
    out = {name: sim.field(name, copy=True) for name in FIELDS}
    st = sim.state()
    die = st.pop("die")
    for k, v in die.items():
        st["die_" + k] = v
    out["state"] = st
    return out


def assert_identical(a, b):
    for name in FIELDS:
        assert a[name].dtype == b[name].dtype and a[name].shape == b[name].shape, name
        # bitwise: compare the raw bytes (NaN-safe, -0.0 vs 0.0 counts as a difference)
        assert a[name].tobytes() == b[name].tobytes(), f"{name} differs"
    assert a["state"] == b["state"]


def shaken_run(backend, steps=20, seed=1):
    """A short run that goes through every stage: ghosts, die contacts, an API control."""
    sim = make(backend, seed=seed)
    sim.set_control(acceleration=(2.0, -1.0, 0.5), torque=(0.0, 0.0, 0.01))
    sim.step(steps)
    return sim


# --------------------------------------------------------------------------------------
# CPU backends
# --------------------------------------------------------------------------------------
def test_serial_and_openmp_are_bitwise_identical():
    a, b = shaken_run("serial"), shaken_run("cpu")
    sa, sb = snapshot(a), snapshot(b)
    assert sa["state"]["n_ghost"] > 0 and sa["state"]["step"] == 20
    assert_identical(sa, sb)
    # and after an evaluation of the same state
    a.evaluate()
    b.evaluate()
    assert_identical(snapshot(a), snapshot(b))


def _digest_script(steps):
    # a child process that runs the shaken run on the OpenMP backend and prints a digest
    return (
        "import hashlib, sys\n"
        f"sys.path.insert(0, {os.path.dirname(__file__)!r})\n"
        "from test_backends import shaken_run, FIELDS\n"
        f"s = shaken_run('cpu', steps={steps})\n"
        "h = hashlib.sha256()\n"
        "for f in FIELDS: h.update(s.field(f, copy=True).tobytes())\n"
        "h.update(repr(s.state()).encode())\n"
        "print(h.hexdigest())\n"
    )


def test_openmp_result_does_not_depend_on_thread_count():
    # the same run with 1 and 3 OpenMP threads (3 > cores here: oversubscribed) in child
    # processes gives the same digest as the serial backend in this process
    steps = 20
    s = shaken_run("serial", steps=steps)
    h = hashlib.sha256()
    for f in FIELDS:
        h.update(s.field(f, copy=True).tobytes())
    h.update(repr(s.state()).encode())
    digests = set()
    for threads in ("1", "3"):
        env = dict(os.environ, OMP_NUM_THREADS=threads)
        out = subprocess.run([sys.executable, "-c", _digest_script(steps)], env=env, capture_output=True, text=True,
                             timeout=120)
        assert out.returncode == 0, out.stderr
        digests.add(out.stdout.strip())
    assert digests == {h.hexdigest()}


@pytest.mark.parametrize("backend", ["serial", "cpu"])
def test_same_seed_same_run(backend):
    assert_identical(snapshot(shaken_run(backend)), snapshot(shaken_run(backend)))


def test_different_seeds_different_starts():
    a, b = make("cpu", seed=1), make("cpu", seed=2)
    pa, pb = a.field("position", copy=True), b.field("position", copy=True)
    assert pa.shape == pb.shape
    # no particle in the same place: the Poisson-disk samples differ
    assert np.abs(pa - pb).max(axis=1).min() > 0
    # the die's random orientation comes from the seed as well
    assert a.state()["die"]["orientation"] != b.state()["die"]["orientation"]
    # while the same seed gives the same start
    np.testing.assert_array_equal(pa, make("cpu", seed=1).field("position", copy=True))


def test_cpu_field_view_is_numpy():
    # field(name) without copy: a zero-copy NumPy view of the core's storage on the CPU
    # (Simulation.field docstring). A copy would pass an equality check too, so the test
    # writes through the view and reads the change back from the core (download), and
    # checks that views of the same field share memory while a copy does not.
    sim = make("cpu", particles=200)
    sim.step(1)
    for name in ("position", "density", "id"):
        view = sim.field(name)
        assert isinstance(view, np.ndarray) and not view.flags.owndata
        copy = sim.field(name, copy=True)
        assert view.shape == copy.shape and view.dtype == copy.dtype
        np.testing.assert_array_equal(view, copy)
        assert np.shares_memory(view, sim.field(name))
        assert not np.shares_memory(copy, sim.field(name))
        changed = copy.copy()
        changed[0] = changed[0] + 1
        view[0] = changed[0]
        np.testing.assert_array_equal(sim.field(name, copy=True), changed)
        view[0] = copy[0]  # put it back
        np.testing.assert_array_equal(sim.field(name, copy=True), copy)
    assert sim.positions.dtype == np.float32 and sim.positions.shape == (200, 3)


@pytest.mark.parametrize("backend", ["serial", "cpu"])
def test_stage_times_time_real_steps(backend):
    # Simulation.stage_times(n): milliseconds per step of each pipeline stage, in pipeline
    # order, over n steps that really advance the run (the same state as n plain steps)
    sim, ref = make(backend, particles=500), make(backend, particles=500)
    for s in (sim, ref):
        s.step(2)
    n = 6
    t0 = time.perf_counter()
    stages = sim.stage_times(n)
    wall = time.perf_counter() - t0
    assert list(stages) == ["sort+reorder", "density", "forces+reduce+finalize", "integrate+keys"]
    assert all(math.isfinite(v) and v > 0 for v in stages.values()), stages
    # per step and in milliseconds: n times their sum is the time of the profiled steps, which
    # is nearly all of the call (a total, or seconds, would be off by n or 1000)
    total = sum(stages.values()) * n / 1000.0
    assert 0.5 * wall < total <= wall, (total, wall)
    ref.set_end_time(math.inf)  # what stage_times does first
    ref.step(n)
    assert sim.steps == ref.steps == 2 + n
    assert_identical(snapshot(sim), snapshot(ref))


# --------------------------------------------------------------------------------------
# CUDA against the CPU
# --------------------------------------------------------------------------------------
def by_id(sim, name):
    return sim.field(name, copy=True)[np.argsort(sim.field("id", copy=True))]


def same_state_pair(particles=3500, seed=3, **overrides):
    """A CPU and a CUDA simulation holding the same state: the scene's start with random
    velocities and a moving, tilted die near the centre (so contacts and the density
    renormalisation take part)."""
    cpu, cuda = make("cpu", particles, seed, **overrides), make("cuda", particles, seed, **overrides)
    rng = np.random.default_rng(seed)
    pos = cpu.field("position", copy=True)
    vel = (rng.normal(size=pos.shape) * 0.2).astype(np.float32)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    for sim in (cpu, cuda):
        sim.set_particles(pos, vel)
        sim.set_die(position=(0.0, 0.0, 0.0), orientation=q, velocity=(0.02, 0.0, -0.01),
                    angular_velocity=(0.5, 0.0, 1.0))
    return cpu, cuda


def ghosts_by_source(sim):
    """(ids of the fluid particles that have a ghost, their ghosts' positions, velocities),
    ordered by id. Ghosts are stored by cell, without an id: each is mapped back through the
    mirror (radius 2R - r -> r) to the fluid particle it images."""
    R = sim.params["radius"]
    g = sim.field("ghost_position", copy=True).astype(np.float64)
    gv = sim.field("ghost_velocity", copy=True).astype(np.float64)
    x = by_id(sim, "position").astype(np.float64)
    rg = np.linalg.norm(g, axis=1)
    back = g * ((2 * R - rg) / rg)[:, None]
    src = np.empty(len(g), dtype=np.int64)
    for lo in range(0, len(g), 256):  # nearest fluid particle, in blocks
        d = np.linalg.norm(back[lo:lo + 256, None, :] - x[None, :, :], axis=2)
        src[lo:lo + 256] = d.argmin(axis=1)
        assert d.min(axis=1).max() < 1e-5  # a mirror image of a particle, not of a gap
    order = np.argsort(src)
    assert len(np.unique(src)) == len(src)  # one ghost per particle
    return src[order], g[order], gv[order]


def assert_pressures_close(sim_a, sim_b, rho_rtol):
    # Tait pressure amplifies a density difference gamma-fold:
    # dp = gamma B (rho/rho0)^gamma drho/rho, so densities within rho_rtol give pressures within
    # rho_rtol gamma B (rho/rho0)^gamma
    p = sim_a.params
    rho = by_id(sim_a, "density").astype(np.float64)
    pa, pb = by_id(sim_a, "pressure").astype(np.float64), by_id(sim_b, "pressure").astype(np.float64)
    tol = rho_rtol * p["gamma"] * p["stiffness"] * (rho / p["rest_density"]) ** p["gamma"]
    assert np.all(np.abs(pa - pb) <= tol), np.max(np.abs(pa - pb) / tol)
    assert np.all(pb >= 0)


def test_gpu_tests_skip_cleanly_without_cuda():
    # the CUDA tests below are skipped, not errors, where no device is usable; where one is,
    # `cuda` must be a working backend
    if CUDA:
        assert make("cuda", particles=200).backend == "cuda"
    else:
        from corpuscle.simulation import BackendError

        with pytest.raises(BackendError):
            make("cuda", particles=200)


def test_ghost_matching_and_pressure_helpers_on_the_cpu():
    # the helpers the CUDA comparisons use, checked where they can run: the serial and
    # OpenMP backends give the same bits, so every ghost finds its twin, and a perturbed
    # pressure is caught
    a, b = make("serial", particles=500), make("cpu", particles=500)
    a.step(3)
    b.step(3)
    sa, ga, va = ghosts_by_source(a)
    sb, gb, vb = ghosts_by_source(b)
    assert len(sa) == a.n_ghosts > 50
    np.testing.assert_array_equal(sa, sb)
    np.testing.assert_array_equal(ga, gb)
    np.testing.assert_array_equal(va, vb)
    assert_pressures_close(a, b, 1e-6)
    b.field("pressure")[np.argmax(b.field("pressure", copy=True))] *= 1.01
    with pytest.raises(AssertionError):
        assert_pressures_close(a, b, 1e-6)


@pytest.mark.gpu
@requires_cuda
def test_cuda_evaluate_matches_cpu():
    cpu, cuda = same_state_pair()
    sc, sg = cpu.evaluate(), cuda.evaluate()
    assert sc["die_contacts"] > 0 and sc["n_ghost"] > 0
    # densities: the same float32 terms summed in another order (warp lanes): ~1e-6 relative
    # (measured on an H200: 6e-7); rel 1e-4 is the state tolerance
    np.testing.assert_allclose(by_id(cuda, "density"), by_id(cpu, "density"), rtol=1e-4)
    # pressures: the Tait law of those densities (gamma-fold amplification of rel 1e-4)
    assert_pressures_close(cpu, cuda, 1e-4)
    # accelerations: sums with cancellation, so compared with the typical (RMS) magnitude:
    # summation order moves a_i by ~1e-6 of the sum of its terms' sizes, which for the few
    # particles pressed into the die is far above the RMS (measured worst: 1.4e-4 of the
    # RMS); 1e-3 of the RMS; chosen_dt rel 1e-4 (measured 5e-7)
    ac, ag = by_id(cpu, "acceleration"), by_id(cuda, "acceleration")
    rms = np.sqrt((ac**2).sum(axis=1).mean())
    assert np.linalg.norm(ag - ac, axis=1).max() < 1e-3 * rms
    assert sg["n_ghost"] == sc["n_ghost"] and sg["die_contacts"] == sc["die_contacts"]
    assert sg["chosen_dt"] == pytest.approx(sc["chosen_dt"], rel=1e-4)
    assert sg["mean_density"] == pytest.approx(sc["mean_density"], rel=1e-5)
    # the other reductions: the largest speed is a max of the same inputs (exact up to the
    # float32 square root), the kinetic energy a sum of them (order only: 1e-5), the largest
    # acceleration moves at most by the acceleration tolerance (1e-3 of the RMS <= 1e-3 of
    # the largest), the density error by the density tolerance
    assert sg["vmax"] == pytest.approx(sc["vmax"], rel=1e-6)
    assert sg["kinetic_energy"] == pytest.approx(sc["kinetic_energy"], rel=1e-5)
    assert sg["amax"] == pytest.approx(sc["amax"], rel=1e-3)
    rho_max = float(by_id(cpu, "density").max()) / cpu.params["rest_density"]
    assert sg["density_error"] == pytest.approx(sc["density_error"], abs=1e-4 * rho_max)
    # ghosts: the mirror images of the same particles (every particle within the list radius
    # of the wall), from the same float32 positions: the formula's few roundings (~1e-7 m at
    # 0.15 m; velocities of ~0.2-1 m/s: ~1e-7 m/s), 1e-6 for either
    ic, gc, vc = ghosts_by_source(cpu)
    ig, gg, vg = ghosts_by_source(cuda)
    np.testing.assert_array_equal(ig, ic)
    np.testing.assert_allclose(gg, gc, rtol=0, atol=1e-6)
    np.testing.assert_allclose(vg, vc, rtol=0, atol=1e-6)
    # the die's reaction: a sum over the contacts, compared with the sum of its magnitudes' scale
    fscale = np.linalg.norm(sc["die_force"]) + 1e-3
    np.testing.assert_allclose(sg["die_force"], sc["die_force"], atol=1e-3 * fscale)
    # its torque about the die centre: the same contact forces times lever arms of at most the
    # die's half diagonal (0.055 m), so the same relative tolerance of its own scale
    tscale = np.linalg.norm(sc["die_torque"]) + 1e-3 * 0.055
    assert np.linalg.norm(sc["die_torque"]) > 1e-6  # a tilted, moving die: contacts off-centre
    np.testing.assert_allclose(sg["die_torque"], sc["die_torque"], atol=1e-3 * tscale)
    # a sound state on both: no instability flag
    assert (sg["bad"], sg["bad_step"]) == (sc["bad"], sc["bad_step"]) == (0, -1)


def die_state(sim):
    d = sim.state()["die"]
    return {k: np.asarray(v, dtype=np.float64) for k, v in d.items()}


@pytest.mark.gpu
@requires_cuda
def test_cuda_first_steps_match_cpu_pointwise():
    # the first 10 steps from the same state: float32 summation order perturbs each step by
    # ~1e-7 relative, and the flow amplifies it over 10 steps (~15 ms): positions by id within
    # 1e-5 m (a thousandth of the particle spacing; measured on an H200: 1.2e-6 m),
    # velocities within 1e-3 of the largest speed (measured 1.6e-5), the die within 1e-5 m
    cpu, cuda = same_state_pair()
    for k in range(10):
        cpu.step(1)
        cuda.step(1)
        assert cuda.dt == pytest.approx(cpu.dt, rel=1e-4), f"step {k}"
        np.testing.assert_allclose(by_id(cuda, "position"), by_id(cpu, "position"), rtol=0, atol=1e-5)
    vc, vg = by_id(cpu, "velocity"), by_id(cuda, "velocity")
    assert np.abs(vg - vc).max() < 1e-3 * np.abs(vc).max()
    assert cuda.time == pytest.approx(cpu.time, rel=1e-6)
    dc, dg = die_state(cpu), die_state(cuda)
    np.testing.assert_allclose(dg["position"], dc["position"], atol=1e-5)
    # the die's motion, with the fluid's tolerances: its velocity and angular velocity within
    # 1e-3 of their size (as the fluid velocities; plus 2e-5 m/s, 2e-5 m / 1 ms, the position
    # tolerance's worth), its orientation within 1e-4 (a 1e-3 relative error of an angular
    # velocity of ~1 rad/s over 15 ms turns it by 1.5e-5 rad; the position tolerance over the
    # die's half side, 1e-5 / 0.032, is 3e-4 rad)
    np.testing.assert_allclose(dg["velocity"], dc["velocity"], rtol=0,
                               atol=1e-3 * np.linalg.norm(dc["velocity"]) + 2e-5)
    np.testing.assert_allclose(dg["angular_velocity"], dc["angular_velocity"], rtol=0,
                               atol=1e-3 * np.linalg.norm(dc["angular_velocity"]) + 2e-5)
    qc, qg = dc["orientation"], dg["orientation"]
    assert np.linalg.norm(qg - qc) < 1e-4, (qg, qc)
    # the last step's die reaction: contact springs of the same particles within 1e-5 m, i.e.
    # m k 1e-5 ~ 1e-3 N per contact (m = 4e-3 kg, k = 2e4 /s^2) against ~N in total: 1e-2 of
    # the force (and of the torque) plus that per-contact amount
    sc, sg = cpu.state(), cuda.state()
    m, k = cpu.params["mass"], cpu.params["contact_stiffness"]
    per_contact = m * k * 1e-5
    assert abs(sg["die_contacts"] - sc["die_contacts"]) <= max(2, 0.02 * sc["die_contacts"])
    np.testing.assert_allclose(sg["die_force"], sc["die_force"], rtol=0,
                               atol=1e-2 * np.linalg.norm(sc["die_force"]) + per_contact)
    np.testing.assert_allclose(sg["die_torque"], sc["die_torque"], rtol=0,
                               atol=1e-2 * np.linalg.norm(sc["die_torque"]) + per_contact * 0.055)
    # densities and pressures by id: positions within 1e-5 m move a Poly6 sum by at most
    # ~|grad W| 1e-5 ~ 6 x 1e-5 / h = 1.2e-3 of it (h = 0.05 m); 2e-3, and the pressure by gamma
    # times that
    np.testing.assert_allclose(by_id(cuda, "density"), by_id(cpu, "density"), rtol=2e-3)
    assert_pressures_close(cpu, cuda, 2e-3)
    # ghosts: the mirrors of the same particles (those that cross the list-radius band within
    # rounding may differ), at the mirrored positions within the position tolerance
    ic, gc, _ = ghosts_by_source(cpu)
    ig, gg, _ = ghosts_by_source(cuda)
    common, jc, jg = np.intersect1d(ic, ig, return_indices=True)
    assert len(common) >= 0.95 * max(len(ic), len(ig))
    np.testing.assert_allclose(gg[jg], gc[jc], rtol=0, atol=2e-5)
    # and the shell (no control here: at rest on both), no instability flag on either
    assert sg["shell_angular_velocity"] == sc["shell_angular_velocity"] == [0.0, 0.0, 0.0]
    assert (sg["bad"], sg["bad_step"]) == (sc["bad"], sc["bad_step"]) == (0, -1)


@pytest.mark.gpu
@requires_cuda
def test_cuda_end_time_clipping_matches_cpu():
    # both backends shorten the step that reaches T to T - t_before and land on T exactly;
    # steps after it are no-ops on the device too (CUDA replays its step graph: the clock,
    # the particles and the die stay put)
    T = 0.0123456  # ~10 steps; no float32 sum of the steps
    cpu, cuda = same_state_pair()
    dts = {}
    for name, sim in (("cpu", cpu), ("cuda", cuda)):
        sim.set_end_time(T)
        seen = []
        while sim.time < T:
            t_before = sim.time
            sim.step(1)
            seen.append(sim.dt)
            assert len(seen) < 100
        assert sim.time == T
        assert sim.dt == np.float32(T - t_before) and sim.dt < seen[-2]
        dts[name] = seen
        x, d = by_id(sim, "position"), die_state(sim)
        n = sim.steps
        last_dt = sim.dt
        assert sim.step(7) == 0
        assert sim.time == T and sim.steps == n and sim.dt == last_dt and sim.state()["done"]
        # no step is taken: nothing moves
        np.testing.assert_array_equal(by_id(sim, "position"), x)
        np.testing.assert_array_equal(die_state(sim)["position"], d["position"])
    assert len(dts["cuda"]) == len(dts["cpu"])
    np.testing.assert_allclose(dts["cuda"][:-1], dts["cpu"][:-1], rtol=1e-4)
    # Simulation.run(until=) with its 100-step chunks: the same landing
    cuda.run(until=2 * T)
    cpu.run(until=2 * T)
    assert cuda.time == cpu.time == 2 * T


@pytest.mark.gpu
@requires_cuda
def test_cuda_flags_an_unstable_run_like_the_cpu():
    # a huge forced dt with a stiff fluid explodes within a few steps (test_cli_run_core.py):
    # both backends raise the instability flag, at the same step (the explosion is violent
    # enough that float32 summation order cannot move it by more than a step)
    ovr = {"timestep.dt_min": 0.05, "timestep.dt_max": 0.05, "fluid.stiffness": 1e8}
    runs = []
    for backend in ("cpu", "cuda"):
        sim = make(backend, 300, 1, **ovr)
        sim.step(20)
        runs.append(sim.state())
    sc, sg = runs
    assert sc["bad"] != 0 and sg["bad"] != 0
    assert sc["bad_step"] > 0 and abs(sg["bad_step"] - sc["bad_step"]) <= 1


@pytest.mark.gpu
@requires_cuda
def test_cuda_run_stays_close_to_cpu_statistically():
    # 300 steps of the scene under a shake (container acceleration and shell torque through
    # the API control) from the same start. Measured on an H200: the CUDA and CPU trajectories
    # separate exponentially (chaotic flow seeded by float32 summation order): the die's
    # distance grows ~10x per 50 steps, 2.5e-6 m at step 100, 5-14 mm at step 300 (seeds 4-6,
    # three controls). So pointwise: the die within 1e-4 m at step 100; statistically at step
    # 300: mean density within 0.5% (measured 0.04%; the fluid is weakly compressible:
    # density errors are a few %), kinetic energy within a factor 1.5 (measured 0.91-1.08;
    # it changes several-fold over the run), the fluid's centre of mass within 1 mm (0.14 mm;
    # the shake moves it by ~5 mm), the die within 2 cm (above the chaotic spread; a heavy
    # die's shake response is 2.5-5.6 cm, test_magic8ball.py), and the shell's spin, which
    # follows the control alone, to float32 rounding (rel 1e-5; measured 1e-7)
    cpu, cuda = make("cpu", 3500, 4), make("cuda", 3500, 4)
    for sim in (cpu, cuda):
        sim.set_control(acceleration=(3.0, 0.0, 0.0), torque=(0.0, 0.0, 0.01))
        sim.step(100)
    die = [np.asarray(s.state()["die"]["position"]) for s in (cpu, cuda)]
    assert np.linalg.norm(die[0] - die[1]) < 1e-4
    for sim in (cpu, cuda):
        sim.step(200)
    sc, sg = cpu.state(), cuda.state()
    assert not sg["bad"] and not sc["bad"]
    assert sg["time"] == pytest.approx(sc["time"], rel=1e-2)
    assert sg["mean_density"] == pytest.approx(sc["mean_density"], rel=5e-3)
    assert 1 / 1.5 < sg["kinetic_energy"] / sc["kinetic_energy"] < 1.5
    com = [s.field("position", copy=True).astype(np.float64).mean(axis=0) for s in (cpu, cuda)]
    assert np.linalg.norm(com[0] - com[1]) < 1e-3
    assert np.linalg.norm(np.subtract(sg["die"]["position"], sc["die"]["position"])) < 2e-2
    np.testing.assert_allclose(sg["shell_angular_velocity"], sc["shell_angular_velocity"], rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(sg["shell_orientation"], sc["shell_orientation"], rtol=1e-5, atol=1e-7)


# --------------------------------------------------------------------------------------
# DLPack: the zero-copy views
# --------------------------------------------------------------------------------------
class _DLDevice(ctypes.Structure):
    _fields_ = [("device_type", ctypes.c_int32), ("device_id", ctypes.c_int32)]


class _DLDataType(ctypes.Structure):
    _fields_ = [("code", ctypes.c_uint8), ("bits", ctypes.c_uint8), ("lanes", ctypes.c_uint16)]


class _DLTensor(ctypes.Structure):
    _fields_ = [("data", ctypes.c_void_p), ("device", _DLDevice), ("ndim", ctypes.c_int32), ("dtype", _DLDataType),
                ("shape", ctypes.POINTER(ctypes.c_int64)), ("strides", ctypes.POINTER(ctypes.c_int64)),
                ("byte_offset", ctypes.c_uint64)]


def read_dltensor(capsule):
    """The DLTensor (dlpack.h, unversioned) inside a "dltensor" capsule, without consuming it:
    (data address, (device type, id), shape, (code, bits, lanes), strides or None)."""
    api = ctypes.pythonapi
    api.PyCapsule_GetName.restype = ctypes.c_char_p
    api.PyCapsule_GetName.argtypes = [ctypes.py_object]
    api.PyCapsule_GetPointer.restype = ctypes.c_void_p
    api.PyCapsule_GetPointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
    assert api.PyCapsule_GetName(capsule) == b"dltensor"
    t = _DLTensor.from_address(api.PyCapsule_GetPointer(capsule, b"dltensor"))  # DLManagedTensor starts with it
    shape = tuple(t.shape[i] for i in range(t.ndim))
    strides = None if not t.strides else tuple(t.strides[i] for i in range(t.ndim))
    return ((t.data or 0) + t.byte_offset, (t.device.device_type, t.device.device_id), shape,
            (t.dtype.code, t.dtype.bits, t.dtype.lanes), strides)


def check_dltensor(capsule, expected, device):
    """The capsule describes an array like `expected` (a host copy) on `device`; returns its
    data address."""
    data, dev, shape, dtype, strides = read_dltensor(capsule)
    assert dev == device
    assert shape == expected.shape
    kind = {"f": 2, "i": 0, "u": 1}[expected.dtype.kind]  # kDLFloat, kDLInt, kDLUInt
    assert dtype == (kind, 8 * expected.dtype.itemsize, 1)
    if strides is not None:  # C-contiguous, in elements
        assert strides == tuple(s // expected.dtype.itemsize for s in expected.strides)
    return data


def _cuda_copy_to_host(address, nbytes, device_id):
    """Read device memory through the CUDA driver (libcuda), checking that it is device
    memory of `device_id`."""
    lib = ctypes.CDLL("libcuda.so.1")
    lib.cuPointerGetAttribute.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_uint64]
    lib.cuMemcpyDtoH_v2.argtypes = [ctypes.c_void_p, ctypes.c_uint64, ctypes.c_size_t]

    def ok(rc, what):
        assert rc == 0, f"{what}: CUresult {rc}"

    ok(lib.cuInit(0), "cuInit")
    ctx = ctypes.c_void_p()
    ok(lib.cuCtxGetCurrent(ctypes.byref(ctx)), "cuCtxGetCurrent")
    if not ctx.value:  # the core's runtime context lives on its thread; retain it here
        dev = ctypes.c_int()
        ok(lib.cuDeviceGet(ctypes.byref(dev), device_id), "cuDeviceGet")
        ok(lib.cuDevicePrimaryCtxRetain(ctypes.byref(ctx), dev), "cuDevicePrimaryCtxRetain")
        ok(lib.cuCtxSetCurrent(ctx), "cuCtxSetCurrent")
    mem_type, ordinal = ctypes.c_uint(), ctypes.c_int()
    ok(lib.cuPointerGetAttribute(ctypes.byref(mem_type), 2, address), "CU_POINTER_ATTRIBUTE_MEMORY_TYPE")
    assert mem_type.value == 2  # CU_MEMORYTYPE_DEVICE
    ok(lib.cuPointerGetAttribute(ctypes.byref(ordinal), 9, address), "CU_POINTER_ATTRIBUTE_DEVICE_ORDINAL")
    assert ordinal.value == device_id
    ok(lib.cuCtxSynchronize(), "cuCtxSynchronize")
    buf = ctypes.create_string_buffer(max(nbytes, 1))
    ok(lib.cuMemcpyDtoH_v2(buf, address, nbytes), "cuMemcpyDtoH")
    return buf.raw[:nbytes]


VIEW_FIELDS = ("position", "density", "id", "ghost_position")


@pytest.mark.parametrize("name", VIEW_FIELDS)
def test_cpu_view_dlpack_capsule_is_the_view(name):
    # the same reading of the capsule as the CUDA test below, on the CPU backend (kDLCPU):
    # it describes the view's own memory, so the DLTensor reader is checked where it can run
    sim = make("cpu", particles=300)
    sim.step(2)
    view = sim.field(name)
    expected = sim.field(name, copy=True)
    assert tuple(view.__dlpack_device__()) == (1, 0)
    data = check_dltensor(view.__dlpack__(), expected, (1, 0))
    assert data == view.__array_interface__["data"][0]
    assert ctypes.string_at(data, expected.nbytes) == expected.tobytes()


@pytest.mark.gpu
@requires_cuda
@pytest.mark.parametrize("name", VIEW_FIELDS)
def test_cuda_field_view_is_device_memory_through_dlpack(name):
    # field(name) on CUDA: a zero-copy view of device memory. Its DLPack device is
    # (kDLCUDA = 2, device 0: the core runs on device 0), __dlpack__() yields a "dltensor"
    # capsule whose tensor has the field's shape and dtype and points at device memory, and
    # that memory holds what download() (field(copy=True)) returns, bit for bit
    sim = make("cuda", particles=500)
    sim.step(2)
    expected = sim.field(name, copy=True)  # also synchronises the device
    view = sim.field(name)
    assert tuple(view.__dlpack_device__()) == (2, 0)
    capsule = view.__dlpack__()
    data = check_dltensor(capsule, expected, (2, 0))
    assert _cuda_copy_to_host(data, expected.nbytes, 0) == expected.tobytes()
    # and, where one is installed, a DLPack consumer reads the same values
    got = None
    try:
        import cupy
    except ImportError:
        try:
            import torch
        except ImportError:
            torch = None
        if torch is not None:
            got = torch.from_dlpack(sim.field(name)).cpu().numpy()
    else:
        got = cupy.asnumpy(cupy.from_dlpack(sim.field(name)))
    if got is not None:
        assert got.shape == expected.shape and got.dtype == expected.dtype
        np.testing.assert_array_equal(got, expected)


@pytest.mark.gpu
@requires_cuda
def test_cuda_field_view_round_trips_through_dlpack():
    # the zero-copy device view, imported by CuPy or PyTorch (either accepts an object with
    # __dlpack__ or a DLPack capsule), holds the same values as the host copy, bit for bit
    sim = make("cuda", particles=500)
    sim.step(2)
    expected = sim.field("position", copy=True)
    try:
        import torch

        got = torch.from_dlpack(sim.field("position")).cpu().numpy()
    except ImportError:
        cupy = pytest.importorskip("cupy")
        got = cupy.asnumpy(cupy.from_dlpack(sim.field("position")))
    assert got.shape == expected.shape and got.dtype == np.float32
    np.testing.assert_array_equal(got, expected)


def test_download_many_is_each_download(backend):
    # a frame's fields in one transfer (through pinned memory on CUDA): each array is what
    # download(name) returns, bit for bit, including the ghost fields whose count changes
    # from step to step, an empty list and a repeated name; an unknown name is an error
    sim = make(backend, particles=400)
    sim.step(3)
    names = ["position", "velocity", "density", "pressure", "id", "ghost_position", "position"]
    got = sim.core.download_many(names)
    assert set(got) == set(names)
    for name in names:
        want = sim.core.download(name)
        assert got[name].dtype == want.dtype and got[name].shape == want.shape
        assert got[name].tobytes() == want.tobytes()
    assert dict(sim.core.download_many([])) == {}
    with pytest.raises(KeyError, match="nope"):
        sim.core.download_many(["position", "nope"])
    # a frame is made from it: the same arrays as the per-field copies
    frame = sim.frame(velocity=True)
    assert frame["fields"]["position"].tobytes() == sim.core.download("position").tobytes()
