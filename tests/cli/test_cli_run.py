"""The run, bench and info commands against stand-ins for the core, the simulation
module and the frame stream: the loop, the summary, the exit codes, the JSON."""

import json
import sys
import types

import pytest

from corpuscle.cli import main


class BackendError(ValueError):
    pass


class FrameStreamError(Exception):
    pass


class FakeWriter:
    """Records what the CLI writes; ``instances`` keeps every writer opened."""

    instances: list = []
    fail_open = None

    def __init__(self, path, header):
        if FakeWriter.fail_open:
            raise FakeWriter.fail_open
        self.path, self.header, self.frames, self.closed = path, header, [], False
        FakeWriter.instances.append(self)

    def write_frame(self, step, time, dt, fields=None, groups=None, rigid=None, diagnostics=None, kind="frame"):
        assert not self.closed
        self.frames.append({"step": step, "time": time, "dt": dt, "fields": fields, "rigid": rigid})

    def close(self):
        self.closed = True
        self.path.write_bytes(b"\x89CPS\r\n\x1a\nfake")  # a frame stream's magic: a rerun may replace it

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


class FakeSim:
    """A simulation with a fixed dt that tells the CLI what it was asked."""

    made: list = []
    cuda = False
    unhealthy_at = None  # step from which check_health reports

    def __init__(self, scene, backend):
        self.scene = scene
        self.backend = "serial" if backend == "auto" else backend
        self.steps, self.time, self.dt = 0, 0.0, 1e-3
        self.end_time = scene["run.end_time"]
        self.n_particles = scene["fluid.particles"]
        self.n_ghosts = 42
        self.calls = []
        FakeSim.made.append(self)

    @classmethod
    def from_scene(cls, scene, backend="auto", neighbors=None, device=0):
        if backend == "cuda" and not cls.cuda:
            raise BackendError("--backend cuda: no usable GPU (no driver)")
        return cls(scene, backend)

    @classmethod
    def cuda_available(cls):
        return cls.cuda

    def set_end_time(self, t):
        self.end_time = t

    def step(self, k):
        # the core's contract: up to k steps, none past the end time or once unsound;
        # returns the steps taken
        self.calls.append(("step", k))
        taken = 0
        while taken < k and self.time < self.end_time - 1e-12:
            if self.unhealthy_at is not None and self.steps >= self.unhealthy_at:
                break
            self.steps += 1
            self.time = min(self.end_time, self.time + self.dt)
            taken += 1
        return taken

    def frame(self, ghosts=False, velocity=False):
        fields = {"position": "pos"}
        if velocity:
            fields["velocity"] = "vel"
        if ghosts:
            fields["ghost_position"] = "g"
        return {"fields": fields, "groups": None, "rigid": {"die": (0, 0, 0)}, "diagnostics": {}}

    def check_health(self):
        if self.unhealthy_at is not None and self.steps >= self.unhealthy_at:
            return "density went\nnon-finite"
        return None

    def result(self):
        return {"answer_face": 3, "answer": "Outlook good"}

    def bench_steps(self, n):
        self.calls.append(("bench", n))
        return {"serial": 1.0, "cpu": 0.1, "cuda": 0.01}[self.backend] * n / 100

    def stage_times(self, n):
        return {"neighbours": 0.1, "density": 0.05, "forces": 0.15}


@pytest.fixture
def fakes(monkeypatch, tmp_path):
    """Install the stand-ins and run in an empty folder."""
    sim_mod = types.ModuleType("corpuscle.simulation")
    sim_mod.Simulation, sim_mod.BackendError = FakeSim, BackendError
    io_mod = types.ModuleType("corpuscle.io")
    io_mod.FrameWriter, io_mod.FrameStreamError = FakeWriter, FrameStreamError
    core = types.ModuleType("corpuscle._core")
    core.build_info = lambda: {
        "version": "0.1.0", "cuda_compiled": True, "cuda_architectures": "90", "openmp": True, "omp_threads": 16,
        "gpus": [{"name": "NVIDIA H100", "compute_capability": "9.0", "memory_gib": 79.2}], "gpu_error": None,
    }
    monkeypatch.setitem(sys.modules, "corpuscle.simulation", sim_mod)
    monkeypatch.setitem(sys.modules, "corpuscle.io", io_mod)
    monkeypatch.setitem(sys.modules, "corpuscle._core", core)
    monkeypatch.setattr(FakeWriter, "instances", [])
    monkeypatch.setattr(FakeWriter, "fail_open", None)
    monkeypatch.setattr(FakeSim, "made", [])
    monkeypatch.setattr(FakeSim, "cuda", False)
    monkeypatch.setattr(FakeSim, "unhealthy_at", None)
    monkeypatch.chdir(tmp_path)
    return tmp_path


# ---------------------------------------------------------------------------
# run
# ---------------------------------------------------------------------------


def test_run_step_budget_chunks_and_frames(fakes, capsys):
    assert main(["run", "magic8ball", "--steps", "250", "--every", "100", "--json"]) == 0
    out, err = capsys.readouterr()
    summary = json.loads(out)
    assert out.count("\n") == 1 and err == ""
    sim, writer = FakeSim.made[0], FakeWriter.instances[0]
    assert sim.calls == [("step", 100), ("step", 100), ("step", 50)]
    assert [f["step"] for f in writer.frames] == [0, 100, 200, 250]
    assert writer.closed and str(writer.path) == "magic8ball.cps"
    for key in ("scene", "backend", "particles", "steps", "sim_time", "wall_time", "steps_per_second",
                "particle_steps_per_second", "frames", "out", "result"):
        assert key in summary
    assert summary["steps"] == 250 and summary["frames"] == 4 and summary["backend"] == "serial"
    assert summary["particles"] == 3500 and summary["out"] == "magic8ball.cps"
    assert summary["result"] == {"answer_face": 3, "answer": "Outlook good"}
    assert summary["particle_steps_per_second"] == pytest.approx(summary["steps_per_second"] * 3500)


def test_run_until_end_time(fakes, capsys):
    assert main(["run", "magic8ball", "--time", "0.5", "--every", "100", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["steps"] == 500 and summary["frames"] == 6
    assert summary["sim_time"] == pytest.approx(0.5)


def test_run_options_reach_the_scene(fakes, capsys):
    argv = ["run", "magic8ball", "--steps", "10", "--particles", "5000", "--seed", "7", "--set", "fluid.stiffness=2e4",
            "--set", "gravity.g=[0, 0, -1]", "--set", "fluid.particles=999", "--out", "x.cps", "--backend", "cpu",
            "--ghosts", "--velocity", "--no-progress"]
    assert main(argv) == 0
    scene = FakeSim.made[0].scene
    # the dedicated option wins over --set
    assert scene["fluid.particles"] == 5000 and scene["run.seed"] == 7
    assert scene["fluid.stiffness"] == 20000.0 and scene["gravity.g"] == [0.0, 0.0, -1.0]
    writer = FakeWriter.instances[0]
    assert str(writer.path) == "x.cps"
    assert set(writer.frames[0]["fields"]) == {"position", "velocity", "ghost_position"}
    assert writer.header["parameters"]["fluid"]["particles"] == 5000
    assert writer.header["backend"] == "cpu"


def test_run_text_summary(fakes, capsys):
    assert main(["run", "magic8ball", "--steps", "200"]) == 0
    out = capsys.readouterr().out
    assert "8-ball says: Outlook good (face 3)" in out
    for word in ("scene", "backend", "particles", "ghosts", "steps/s", "particle-steps/s", "magic8ball.cps (3 frames)"):
        assert word in out


def test_run_health_stop_keeps_file_and_exits_3(fakes, capsys):
    FakeSim.unhealthy_at = 200
    code = main(["run", "magic8ball", "--steps", "1000", "--every", "100", "--json"])
    out, err = capsys.readouterr()
    assert code == 3
    assert err == "corpuscle: run stopped at step 200: density went non-finite\n"
    writer = FakeWriter.instances[0]
    assert writer.closed and [f["step"] for f in writer.frames] == [0, 100, 200]
    summary = json.loads(out)
    assert summary["steps"] == 200 and summary["stopped"] == "density went non-finite"


def test_run_backend_error_is_one_line(fakes, capsys):
    assert main(["run", "magic8ball", "--backend", "cuda"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err == "corpuscle: error: --backend cuda: no usable GPU (no driver)\n"
    assert not FakeWriter.instances


def test_run_frame_stream_error_is_one_line(fakes, capsys):
    FakeWriter.fail_open = FrameStreamError("cannot create x.cps: bad\nheader")
    assert main(["run", "magic8ball", "--steps", "10"]) == 2
    assert capsys.readouterr().err == "corpuscle: error: cannot create x.cps: bad header\n"


def test_run_unwritable_output_is_one_line(fakes, capsys):
    FakeWriter.fail_open = PermissionError(13, "Permission denied")
    assert main(["run", "magic8ball", "--steps", "10", "--out", "y.cps"]) == 2
    assert capsys.readouterr().err == "corpuscle: error: cannot write y.cps: Permission denied\n"


def test_run_file_scene_default_out_name(fakes, capsys):
    (fakes / "my scene.toml").write_text('[scene]\nkind = "magic8ball"\nname = "my ball/1"\n', encoding="utf-8")
    assert main(["run", "./my scene.toml", "--steps", "5", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["out"] == "my_ball_1.cps"


@pytest.mark.parametrize("stop, shown", [(["--steps", "300"], "/300"), (["--time", "0.3"], "/0.300 s simulated")])
def test_run_progress_bar_on_a_terminal(fakes, capsys, monkeypatch, stop, shown):
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    assert main(["run", "magic8ball", "--every", "100", *stop]) == 0
    assert shown in capsys.readouterr().err
    # --json and --no-progress keep stderr quiet
    assert main(["run", "magic8ball", "--every", "100", "--no-progress", *stop]) == 0
    assert main(["run", "magic8ball", "--every", "100", "--json", *stop]) == 0
    assert capsys.readouterr().err == ""


# ---------------------------------------------------------------------------
# bench
# ---------------------------------------------------------------------------


def test_bench_default_backends_without_gpu(fakes, capsys):
    assert main(["bench", "magic8ball", "--steps", "100", "--repeats", "3", "--warmup", "5", "--json", "b.json"]) == 0
    out = capsys.readouterr().out
    assert [s.backend for s in FakeSim.made] == ["serial", "cpu"]
    assert FakeSim.made[0].calls == [("step", 5)] + [("bench", 100)] * 3
    rows = json.loads((fakes / "b.json").read_text())
    assert [r["backend"] for r in rows] == ["serial", "cpu"]
    for r in rows:
        for key in ("scene", "backend", "particles", "steps", "repeats", "steps_per_second",
                    "particle_steps_per_second", "device", "date"):
            assert key in r
        assert "stages" not in r
    assert rows[0]["steps_per_second"] == pytest.approx(100.0)
    assert rows[1]["steps_per_second"] == pytest.approx(1000.0)
    assert "10.0x" in out


def test_bench_cuda_stages(fakes, capsys):
    FakeSim.cuda = True
    assert main(["bench", "magic8ball", "--particles", "5000", "--json", "b.json"]) == 0
    out = capsys.readouterr().out
    rows = json.loads((fakes / "b.json").read_text())
    assert [r["backend"] for r in rows] == ["serial", "cpu", "cuda"]
    assert rows[2]["stages"] == {"neighbours": 0.1, "density": 0.05, "forces": 0.15}
    assert rows[2]["particles"] == 5000 and "H100" in rows[2]["device"]
    assert "neighbours" in out and "100.0x" in out


def test_bench_chosen_backend_only(fakes, capsys):
    assert main(["bench", "magic8ball", "--backend", "cpu", "--warmup", "0"]) == 0
    out = capsys.readouterr().out
    assert [s.backend for s in FakeSim.made] == ["cpu"]
    assert FakeSim.made[0].calls[0] == ("bench", 100)
    assert "speedup" not in out


def test_bench_cuda_unavailable(fakes, capsys):
    assert main(["bench", "magic8ball", "--backend", "cuda"]) == 2
    assert capsys.readouterr().err == "corpuscle: error: --backend cuda: no usable GPU (no driver)\n"


# ---------------------------------------------------------------------------
# info
# ---------------------------------------------------------------------------


def test_info(fakes, capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("corpuscle 0.1.0")
    assert "NVIDIA H100" in out and "90" in out and "16 threads" in out
    assert main(["info", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["build_info"]["omp_threads"] == 16
