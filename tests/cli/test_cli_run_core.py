"""The CLI on the real core: an unstable run stops and keeps its frames; --render renders as it records;
--time ends the run exactly at the time."""
import pytest

pytest.importorskip("corpuscle._core")

import corpuscle
from corpuscle.cli import main


def test_unstable_run_stops_names_the_step_and_keeps_frames(tmp_path, capsys):
    out = tmp_path / "bad.cps"
    # a huge forced dt with a stiff fluid explodes within a few steps
    rc = main(["run", "magic8ball", "--particles", "300", "--steps", "400", "--every", "5", "--no-progress",
               "--set", "timestep.dt_min=0.05", "--set", "timestep.dt_max=0.05", "--set", "fluid.stiffness=1e8",
               "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 3
    assert len(err) == 1 and "stopped at step" in err[0] and "unstable at step" in err[0]
    run = corpuscle.open(out)
    # the first frame and the frames up to the stop are all readable
    assert len(run) >= 2
    assert run[-1].step < 400
    run.verify()


def test_stable_run_reports_no_problem():
    sim = corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=300)
    sim.step(20)
    assert sim.check_health() is None


def test_run_render_writes_a_frame_per_recorded_frame(tmp_path):
    # `corpuscle run --render OUT` renders as it records: one picture per recorded frame
    Image = pytest.importorskip("PIL.Image")
    out = tmp_path / "run.cps"
    gif = tmp_path / "run.gif"
    rc = main(["run", "magic8ball", "--particles", "300", "--steps", "20", "--every", "10", "--no-progress",
               "--out", str(out), "--render", str(gif), "--render-size", "160x90"])
    assert rc == 0
    recorded = len(corpuscle.open(out))
    with Image.open(gif) as im:
        assert im.size == (160, 90)
        assert getattr(im, "n_frames", 1) == recorded == 3


def _corpuscle_command():
    """The installed `corpuscle` script next to this Python, else `python -m corpuscle`."""
    import os
    import sys

    exe = os.path.join(os.path.dirname(sys.executable), "corpuscle")
    return [exe] if os.path.exists(exe) else [sys.executable, "-m", "corpuscle"]


@pytest.mark.parametrize("every", [None, 1])
def test_run_time_ends_exactly_at_the_time(tmp_path, every):
    # `corpuscle run --time T` in a real process: the core shortens the last step to land on
    # T, so the last recorded frame is at T exactly (the frame stream stores float64 times;
    # 0.05 is no sum of float32 steps of 1.5 ms), the summary's simulated time is T, and no
    # frame lies beyond it. With a frame every step (--every 1), every recorded dt is the step
    # between consecutive frames, and the last one is the remainder T - t_before in float32,
    # shorter than the full step before it (a full step followed by a clamp of the clock
    # would record a full dt there).
    import json
    import subprocess

    import numpy as np

    out = tmp_path / "tmp.cps"
    cmd = _corpuscle_command() + ["run", "magic8ball", "--time", "0.05", "--particles", "300", "--backend", "cpu",
                                  "--out", str(out), "--json"]
    if every:
        cmd += ["--every", str(every)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["sim_time"] == 0.05 and summary["stopped"] is None
    run = corpuscle.open(out)
    run.verify()
    times = run.series("time")
    assert run[-1].time == 0.05
    assert times[0] == 0.0 and np.all(times[:-1] < 0.05)
    assert len(run) == summary["frames"]
    assert run[-1].step == summary["steps"]
    if every:
        dts = run.series("dt")
        assert len(run) == summary["steps"] + 1
        # each dt is the float32 step that took the clock from one frame to the next
        np.testing.assert_array_equal(dts[1:], np.float32(np.diff(times)).astype(np.float64))
        assert dts[-1] == np.float32(0.05 - times[-2])
        assert dts[-1] < dts[-2]
        assert times[-2] + dts[-2] > 0.05  # a full step from t_before would have passed T


@pytest.mark.parametrize("argv", [["run", "magic8ball", "--backend", "cpu", "--device", "1", "--steps", "2"],
                                  ["bench", "magic8ball", "--backend", "serial", "--device", "3", "--steps", "2"]])
def test_device_on_a_cpu_backend_is_a_one_line_error(argv, tmp_path, capsys, monkeypatch):
    # --device selects a CUDA device: on a CPU backend it would select nothing, silently
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--device" in err[0] and "CUDA" in err[0], err
    assert not list(tmp_path.glob("*.cps"))


def test_device_on_a_cpu_backend_is_refused_by_the_python_api():
    with pytest.raises(ValueError, match="device 2"):
        corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=500, device=2)
