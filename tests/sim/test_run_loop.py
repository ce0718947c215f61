"""The run loop on the real core: steps past the end time cost nothing and are not counted,
an unstable run stops at the step that went bad whatever the record interval, every
instability reason is found and named, and --steps means N steps."""
import json
import math
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("corpuscle._core")

import corpuscle
from corpuscle.simulation import UNSTABLE_REASONS, UnstableRunError


def small(backend="cpu", n=300, **kw):
    return corpuscle.Simulation.from_scene("magic8ball", backend=backend, particles=n, **kw)


def cli(*argv, timeout=300, **kw):
    return subprocess.run(["corpuscle", *argv], capture_output=True, text=True, timeout=timeout, **kw)


# ---- the end time -----------------------------------------------------------------------

def test_step_reports_the_steps_taken_and_stops_at_the_end_time():
    a = small()
    a.set_end_time(0.02)
    taken = a.step(100_000)
    assert a.time == 0.02 and a.state()["done"]
    assert taken == a.steps > 0
    # the same steps as when stepped one by one
    b = small()
    b.set_end_time(0.02)
    count = 0
    while b.step(1):
        count += 1
    assert count == taken
    assert np.array_equal(a.field("position", copy=True), b.field("position", copy=True))


def test_steps_after_the_end_cost_almost_nothing():
    sim = small()
    sim.set_end_time(0.01)
    t = time.perf_counter()
    real = sim.step(1000)
    per_step = (time.perf_counter() - t) / real
    t = time.perf_counter()
    assert sim.step(100_000) == 0
    surplus = time.perf_counter() - t
    # 100,000 no-op steps cost less than ten real ones
    assert surplus < 10 * per_step
    assert sim.steps == real


def test_extending_the_end_time_continues():
    sim = small()
    sim.set_end_time(0.01)
    sim.step(1000)
    n = sim.steps
    sim.set_end_time(0.02)
    assert sim.step(1000) > 0 and sim.time == 0.02 and sim.steps > n


def test_cli_summary_counts_real_steps_only(tmp_path):
    rows = []
    for every in ("100000", "10"):
        p = cli("run", "magic8ball", "--backend", "cpu", "--particles", "300", "--time", "0.03", "--every", every,
                "--out", str(tmp_path / f"e{every}.cps"), "--json")
        assert p.returncode == 0, p.stderr
        rows.append(json.loads(p.stdout))
    big, small_every = rows
    assert big["steps"] == small_every["steps"] > 0
    assert big["sim_time"] == small_every["sim_time"] == 0.03
    # steps/s is steps over the time they took, and initialisation is its own figure
    assert big["steps_per_second"] == pytest.approx(big["steps"] / big["wall_time"])
    assert big["init_time"] > 0
    # frame 0 and the last frame only
    assert big["frames"] == 2 and len(corpuscle.open(tmp_path / "e100000.cps")) == 2


def test_steps_n_runs_n_steps_past_the_scene_end_time(tmp_path):
    p = cli("run", "magic8ball", "--backend", "cpu", "--particles", "300", "--steps", "40",
            "--set", "run.end_time=0.005", "--out", str(tmp_path / "a.cps"), "--json")
    assert p.returncode == 0, p.stderr
    s = json.loads(p.stdout)
    assert s["steps"] == 40 and s["sim_time"] > 0.005
    # with --time too, whichever comes first
    p = cli("run", "magic8ball", "--backend", "cpu", "--particles", "300", "--steps", "4000", "--time", "0.005",
            "--out", str(tmp_path / "b.cps"), "--json")
    assert p.returncode == 0, p.stderr
    s = json.loads(p.stdout)
    assert s["steps"] < 4000 and s["sim_time"] == 0.005


def test_frame_zero_holds_the_evaluated_state(tmp_path):
    out = tmp_path / "r.cps"
    p = cli("run", "magic8ball", "--backend", "cpu", "--particles", "300", "--steps", "5", "--out", str(out))
    assert p.returncode == 0, p.stderr
    f0 = corpuscle.open(out)[0]
    # the densities and pressures of the initial state, as an evaluation of it gives them
    ref = small()
    assert np.array_equal(f0["position"], ref.field("position"))
    assert np.array_equal(f0["density"], ref.field("density"))
    assert np.array_equal(f0["pressure"], ref.field("pressure"))
    assert np.all(f0["density"] > 0) and np.any(f0["pressure"] > 0)


# ---- instability ----------------------------------------------------------------------

def _reason(sim):
    st = sim.state()
    return st["bad"], st["bad_step"], sim.check_health()


def test_a_list_overflow_grows_the_lists_and_repeats_the_step():
    sim = small(n=2000)
    caps = sim.params["max_neighbors"], sim.params["max_near"]
    assert caps[0] < 2000
    x = sim.field("position", copy=True)
    sim.set_particles(x * 0.05)  # everything within 7.5 mm: far more neighbours than a list holds
    # the overflowing step is not taken: the lists grow to hold every neighbour found and the
    # step is repeated, so the run goes on (here until the compressed blob flies apart)
    taken = sim.step(3)
    st = sim.core.scalars()
    assert taken >= 1 and sim.steps == taken
    assert st["max_neighbors"] > caps[0] and st["max_near"] > caps[1]
    assert st["bad"] != 4


def test_a_list_overflow_that_cannot_grow_stops_before_the_step_is_taken():
    # lists capped at 1 MB (sph.max_list_memory): the grown lists would not fit
    sim = small(n=2000, overrides={"sph.max_list_memory": 1.0})
    x = sim.field("position", copy=True)
    sim.set_particles(x * 0.05)
    assert sim.step(10) == 0
    bad, step, msg = _reason(sim)
    assert bad == 4 and step == 1 and sim.steps == 0
    assert msg == f"unstable at step 1: {UNSTABLE_REASONS[4]}"
    assert sim.core.scalars()["max_neighbors"] == sim.params["max_neighbors"]


def test_an_evaluation_that_overflows_grows_the_lists_and_lists_every_neighbour():
    x = small(n=2000).field("position", copy=True) * 0.05
    lists, ref = small(n=2000), small(n=2000, neighbors="allpairs")
    for sim in (lists, ref):
        sim.set_particles(x)
        sim.evaluate()
    assert lists.state()["bad"] == 0 and lists.core.scalars()["max_neighbors"] > lists.params["max_neighbors"]
    # every neighbour was listed: the densities are those of all pairs (to float rounding)
    ids_l, ids_r = lists.field("id", copy=True), ref.field("id", copy=True)
    rho_l, rho_r = np.empty(2000), np.empty(2000)
    rho_l[ids_l] = lists.field("density", copy=True)
    rho_r[ids_r] = ref.field("density", copy=True)
    np.testing.assert_allclose(rho_l, rho_r, rtol=1e-5)
    # and the run goes on from there
    assert lists.step(1) == 1


@pytest.mark.parametrize("speed, code, taken", [(1e20, 1, 0), (5e3, 3, 1)])
def test_non_finite_and_runaway_speeds_stop_at_the_first_step(speed, code, taken):
    sim = small()
    x = sim.field("position", copy=True)
    v = np.zeros_like(x)
    v[7] = (speed, 0.0, 0.0)  # its square overflows float32 (1e20), or 500 sound speeds
    sim.set_particles(x, v)
    # a non-finite state is not integrated; a runaway speed is, once, then the run stops
    assert sim.step(50) == taken
    bad, step, msg = _reason(sim)
    assert (bad, step) == (code, 1), msg
    assert msg == f"unstable at step 1: {UNSTABLE_REASONS[code]}"
    assert np.isfinite(sim.field("position", copy=True)).all()


def test_non_finite_die_is_found():
    sim = small()
    sim.step(3)
    sim.set_die(angular_velocity=(3e38, 3e38, 0.0))
    assert sim.step(20) == 0
    bad, step, msg = _reason(sim)
    assert (bad, step) == (2, 4), msg
    assert msg == f"unstable at step 4: {UNSTABLE_REASONS[2]}"
    assert sim.steps == 3


def test_run_raises_unstable_run_error_naming_the_step():
    sim = small()
    x = sim.field("position", copy=True)
    v = np.zeros_like(x)
    sim.step(2)
    v[0] = (5e3, 0, 0)
    sim.set_particles(sim.field("position", copy=True), v)
    with pytest.raises(UnstableRunError, match=r"unstable at step 3: a particle moved faster") as e:
        sim.run(until=1.0, chunk=1000)
    assert e.value.step == 3 and sim.steps == 3


UNSTABLE = ["--particles", "300", "--backend", "cpu", "--set", "timestep.dt_min=0.05", "--set",
            "timestep.dt_max=0.05", "--set", "fluid.stiffness=1e8"]


def test_cli_unstable_run_stops_at_the_same_step_whatever_every(tmp_path):
    seen = []
    for every in ("1000", "1"):
        out = tmp_path / f"u{every}.cps"
        p = cli("run", "magic8ball", *UNSTABLE, "--steps", "400", "--every", every, "--out", str(out), "--json")
        assert p.returncode == 3, p.stderr
        err = p.stderr.strip().splitlines()
        assert len(err) == 1 and "unstable at step" in err[0]
        s = json.loads(p.stdout)
        run = corpuscle.open(out)
        seen.append((s["stopped"], s["steps"], run[-1].step))
        run.verify()
        if every == "1":
            # a frame for every step taken
            assert list(run.steps) == list(range(s["steps"] + 1))
        else:
            assert list(run.steps) == [0, s["steps"]]
    assert seen[0] == seen[1]
    assert seen[0][1] < 20  # it went bad within a few steps and stopped there


# ---- API arguments --------------------------------------------------------------------

def test_api_rejects_bad_arguments():
    sim = small()
    x = sim.field("position", copy=True)
    bad = x.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"positions\[3\] = .* is not finite"):
        sim.set_particles(bad)
    bad = x.copy()
    bad[5] = (1e30, 0, 0)
    with pytest.raises(ValueError, match=r"positions\[5\] = .* outside the container"):
        sim.set_particles(bad)
    with pytest.raises(ValueError, match=r"velocities\[0\] = .* is not finite"):
        sim.set_particles(x, np.full_like(x, np.inf))
    with pytest.raises(ValueError, match=r"positions must be an \(300, 3\) array"):
        sim.set_particles(x[:10])
    with pytest.raises(ValueError, match=r"acceleration must be finite"):
        sim.set_control(acceleration=(0, math.nan, 0))
    with pytest.raises(ValueError, match=r"torque must be 3 numbers"):
        sim.set_control(torque=(1, 2))
    with pytest.raises(TypeError, match=r"steps must be an integer, got 1.5"):
        sim.step(1.5)
    with pytest.raises(ValueError, match=r"steps must be >= 0, got -1"):
        sim.step(-1)
    with pytest.raises(ValueError, match=r"until = -1.0 s is before the current time 0.0 s"):
        sim.run(until=-1)
    with pytest.raises(ValueError, match=r"orientation must be a non-zero quaternion"):
        sim.set_die(orientation=(0, 0, 0, 0))
    with pytest.raises(ValueError, match=r"angular_velocity must be finite"):
        sim.set_die(angular_velocity=(math.inf, 0, 0))
    # nothing was changed by the rejected calls
    assert np.array_equal(sim.field("position", copy=True), x) and sim.steps == 0


def test_numpy_integers_are_integers_and_floats_are_not():
    sim = corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=np.int64(300), seed=np.int32(4))
    assert sim.n_particles == 300
    assert sim.step(np.int64(2)) == 2
    with pytest.raises(corpuscle.scene.SceneError, match=r"fluid.particles must be an integer"):
        corpuscle.Simulation.from_scene("magic8ball", particles=np.float64(300))
    with pytest.raises(TypeError):
        sim.step(np.float64(2))


def test_memory_need_is_checked_before_allocating():
    with pytest.raises(corpuscle.simulation.MemoryNeedError) as e:
        corpuscle.Simulation.from_scene("magic8ball", backend="cpu", particles=2_000_000,
                                        overrides={"sph.h": 1.0, "sph.scale_h": False})
    msg = str(e.value)
    assert "\n" not in msg
    for needle in ("fluid.particles=2000000", "sph.h=1.0", "sph.scale_h=false", "need", "host memory available"):
        assert needle in msg


def test_cli_memory_need_is_one_line(tmp_path):
    p = cli("run", "magic8ball", "--backend", "cpu", "--particles", "2000000", "--set", "sph.h=1",
            "--set", "sph.scale_h=false", "--out", str(tmp_path / "m.cps"), timeout=120)
    assert p.returncode == 2
    assert p.stderr.count("\n") == 1 and p.stderr.startswith("corpuscle: error: fluid.particles=2000000")
    assert "Traceback" not in p.stderr and not (tmp_path / "m.cps").exists()


def test_a_large_h_that_fits_runs():
    # every particle neighbours every other one: the lists hold them all instead of failing
    sim = corpuscle.Simulation.from_scene("magic8ball", backend="cpu", particles=300,
                                          overrides={"sph.h": 0.4, "sph.scale_h": False, "die.contact_margin": 0.02})
    assert sim.params["max_neighbors"] >= 600
    assert sim.step(2) == 2 and sim.check_health() is None


def test_no_room_for_the_fluid_is_one_clear_error():
    with pytest.raises(ValueError, match=r"die.contact_margin=0.16 h with sph.h=1 m .* leaves 0.0% of the container"):
        corpuscle.Simulation.from_scene("magic8ball", backend="cpu", particles=300,
                                        overrides={"sph.h": 1.0, "sph.scale_h": False})


def test_a_shake_window_acts_from_the_step_that_starts_at_its_start_time():
    # windows are compared with the double clock: one starting at 0.1 s (not a binary
    # fraction) acts on the step that starts at exactly 0.1 s
    window = [{"start": 0.1, "end": 0.2, "acceleration": [50.0, 0.0, 0.0], "torque": [0.0, 0.0, 0.0]}]
    a = small(n=300, overrides={"shake": window})
    b = small(n=300, overrides={"shake": []})
    a.run(until=0.1)
    b.run(until=0.1)
    assert a.time == b.time == 0.1
    assert np.array_equal(a.field("position", copy=True), b.field("position", copy=True))
    b.set_control(acceleration=(50.0, 0.0, 0.0))
    a.evaluate()
    b.evaluate()
    assert np.array_equal(a.field("acceleration", copy=True), b.field("acceleration", copy=True))
