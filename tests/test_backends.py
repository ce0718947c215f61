"""Backends against each other: serial and OpenMP give bit-identical runs (reductions have a
fixed order by design), runs are reproducible from their seed, and CUDA matches the CPU path
on the same input (``gpu`` mark: skipped where ``Simulation.cuda_available()`` is False).
"""

import hashlib
import os
import subprocess
import sys

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
    # field(name) without copy: a zero-copy NumPy view on the CPU (Simulation.field docstring)
    sim = make("cpu", particles=200)
    sim.step(1)
    view = sim.field("position")
    assert isinstance(view, np.ndarray)
    np.testing.assert_array_equal(view, sim.field("position", copy=True))


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


def test_gpu_tests_skip_cleanly_without_cuda():
    # the CUDA tests below are skipped, not errors, where no device is usable; where one is,
    # `cuda` must be a working backend
    if CUDA:
        assert make("cuda", particles=200).backend == "cuda"
    else:
        from corpuscle.simulation import BackendError

        with pytest.raises(BackendError):
            make("cuda", particles=200)


@pytest.mark.gpu
@requires_cuda
def test_cuda_evaluate_matches_cpu():
    cpu, cuda = same_state_pair()
    sc, sg = cpu.evaluate(), cuda.evaluate()
    assert sc["die_contacts"] > 0 and sc["n_ghost"] > 0
    # densities: the same float32 terms summed in another order (warp lanes): ~1e-6 relative
    # (measured on an H200: 6e-7); rel 1e-4 is the state tolerance
    np.testing.assert_allclose(by_id(cuda, "density"), by_id(cpu, "density"), rtol=1e-4)
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
    # the die's reaction: a sum over the contacts, compared with the sum of its magnitudes' scale
    fscale = np.linalg.norm(sc["die_force"]) + 1e-3
    np.testing.assert_allclose(sg["die_force"], sc["die_force"], atol=1e-3 * fscale)


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
    np.testing.assert_allclose(cuda.state()["die"]["position"], cpu.state()["die"]["position"], atol=1e-5)


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


@pytest.mark.gpu
@requires_cuda
def test_cuda_field_exposes_dlpack():
    sim = make("cuda", particles=500)
    sim.step(2)
    assert hasattr(sim.field("position"), "__dlpack__")


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
