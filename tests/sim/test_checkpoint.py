"""Checkpoint and resume: a run killed at any moment and resumed from its last checkpoint
ends bit-identical to the run left alone (CPU backends; CUDA is deterministic too), and
Simulation.checkpoint()/restore() carry the same state from Python."""
import json
import os
import signal
import subprocess
import time

import numpy as np
import pytest

pytest.importorskip("corpuscle._core")

import corpuscle

RUN = ["run", "magic8ball", "--backend", "serial", "--particles", "300", "--steps", "120", "--every", "10",
       "--checkpoint-every", "30", "--velocity", "--no-progress"]


def cli(*argv, timeout=300):
    return subprocess.run(["corpuscle", *argv], capture_output=True, text=True, timeout=timeout)


def frames_of(path):
    with corpuscle.open(path) as run:
        return [(f.step, f.time, f.dt, f.kind, {k: np.array(v) for k, v in f.fields.items()},
                 {b: {k: np.array(v) for k, v in r.items()} for b, r in f.rigid.items()}) for f in run]


def assert_same_run(a, b):
    fa, fb = frames_of(a), frames_of(b)
    assert [f[:4] for f in fa] == [f[:4] for f in fb]
    for x, y in zip(fa, fb):
        assert x[4].keys() == y[4].keys()
        for name in x[4]:
            assert np.array_equal(x[4][name], y[4][name]), (x[0], name)
        for body in x[5]:
            for name in x[5][body]:
                assert np.array_equal(x[5][body][name], y[5][body][name]), (x[0], body, name)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "a.cps"
    p = cli(*RUN, "--out", str(out))
    assert p.returncode == 0, p.stderr
    return out


def test_checkpoint_frames_carry_the_state(reference):
    with corpuscle.open(reference) as run:
        kinds = run.kinds
        # frame 0, every third frame (steps 30, 60, 90) and the last one
        assert [i for i, k in enumerate(kinds) if k == "checkpoint"] == [0, 3, 6, 9, 12]
        f = run[6]
        assert f.step == 60
        for name in ("position", "velocity", "id", "state.time", "state.step", "state.die_position",
                     "state.die_angular_velocity_body", "state.shell_orientation", "state.control_acceleration"):
            assert name in f.fields, name
        assert int(f["state.step"][0]) == 60 and float(f["state.time"][0]) == f.time
        assert sorted(f["id"].tolist()) == list(range(300))


@pytest.mark.parametrize("kill_after_frames", [4, 7, 11])
def test_killed_run_resumes_bit_identical(reference, tmp_path, kill_after_frames):
    out = tmp_path / "b.cps"
    proc = subprocess.Popen(["corpuscle", *RUN, "--out", str(out)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    # wait for the frames, then kill at a moment between two of them
    deadline = time.monotonic() + 120
    frame_bytes = None
    while time.monotonic() < deadline and proc.poll() is None:
        if out.exists() and out.stat().st_size > 0:
            try:
                import warnings
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    with corpuscle.open(out) as run:
                        n = len(run)
            except corpuscle.io.FrameStreamError:
                n = 0
            if n >= kill_after_frames:
                time.sleep(0.013 * kill_after_frames)
                break
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    p = cli("run", "--resume", str(out), "--json")
    assert p.returncode == 0, p.stderr
    s = json.loads(p.stdout)
    assert s["resumed_at_step"] in (30, 60, 90, 120)
    assert_same_run(reference, out)


def test_resume_with_new_end_and_to_another_file(reference, tmp_path):
    more = tmp_path / "more.cps"
    p = cli("run", "--resume", str(reference), "--steps", "20", "--out", str(more), "--json")
    assert p.returncode == 0, p.stderr
    s = json.loads(p.stdout)
    assert s["resumed_at_step"] == 120 and s["steps"] == 20
    with corpuscle.open(more) as run:
        assert list(run.steps) == [130, 140]
        assert run.header["resumed_from"] == str(reference)
    # the reference is untouched
    assert len(corpuscle.open(reference)) == 13


def test_resume_without_a_checkpoint_is_one_line(tmp_path):
    out = tmp_path / "plain.cps"
    assert cli("run", "magic8ball", "--backend", "serial", "--particles", "300", "--steps", "5", "--out",
               str(out)).returncode == 0
    p = cli("run", "--resume", str(out))
    assert p.returncode == 2 and p.stderr.count("\n") == 1
    assert "has no checkpoint (record with --checkpoint-every K)" in p.stderr


@pytest.mark.parametrize("backend", ["serial", "cpu"])
def test_api_checkpoint_restore_is_bit_identical(backend):
    def make():
        return corpuscle.Simulation.from_scene("magic8ball", backend=backend, particles=400)

    a = make()
    a.set_control(acceleration=(2.0, 0.0, 0.0), torque=(0.0, 0.0, 0.01))
    a.step(25)
    state = a.checkpoint()
    a.step(30)
    b = corpuscle.Simulation(a.scene, backend=backend, checkpoint=state)
    assert b.steps == 25 and b.time == state["time"]
    b.step(30)
    for name in ("position", "velocity", "density", "pressure", "id"):
        assert np.array_equal(a.field(name, copy=True), b.field(name, copy=True)), name
    assert a.state()["die"] == b.state()["die"] and a.time == b.time
    # restore onto an existing simulation, too
    c = make()
    c.restore(state)
    c.step(30)
    assert np.array_equal(a.field("position", copy=True), c.field("position", copy=True))


def test_restore_rejects_a_foreign_state():
    sim = corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=300)
    state = sim.checkpoint()
    state["id"] = np.zeros(300, dtype=np.int32)
    with pytest.raises(ValueError, match="checkpoint id must be a permutation"):
        sim.restore(state)
    with pytest.raises(ValueError, match="checkpoint: missing velocity"):
        sim.restore({"position": state["position"], "id": np.arange(300)})


@pytest.mark.gpu
def test_cuda_checkpoint_restore_is_bit_identical():
    if not corpuscle.Simulation.cuda_available():
        pytest.skip("no usable CUDA device")
    a = corpuscle.Simulation.from_scene("magic8ball", backend="cuda", particles=3500)
    a.step(50)
    state = a.checkpoint()
    a.step(200)
    b = corpuscle.Simulation(a.scene, backend="cuda", checkpoint=state)
    b.step(200)
    # the CUDA backend has no float atomics and fixed reduction orders: deterministic
    for name in ("position", "velocity", "density"):
        assert np.array_equal(a.field(name, copy=True), b.field(name, copy=True)), name
    assert a.state()["die"] == b.state()["die"]
