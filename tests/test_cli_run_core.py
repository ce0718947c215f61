"""The CLI on the real core: an unstable run stops and keeps its frames; --render renders as it records."""
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
