"""Inputs a new user reaches that used to end in a traceback, a misleading message, a silent
no-op or silently wrong state: each case fails before its fix.

The command-line cases go through the installed ``corpuscle`` console script (tests/cli_script.py)."""
import warnings

import numpy as np
import pytest

pytest.importorskip("corpuscle._core")

import corpuscle
from corpuscle.scene import SceneError
from cli_script import assert_one_line_error, corpuscle as run_cli


@pytest.fixture(scope="module")
def sim():
    return corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=300)


# --- the Python API ------------------------------------------------------------------------

def test_numpy_bool_is_a_bool_key_value():
    # NumPy 2 names np.bool_'s type "bool": it was rejected with "must be true or false, got false"
    s = corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=300,
                                        overrides={"sph.scale_h": np.bool_(False)})
    assert s.scene["sph.scale_h"] is False
    assert s.scene["sph.scale_h"] == corpuscle.Simulation.from_scene(
        "magic8ball", backend="serial", particles=300, overrides={"sph.scale_h": False}).scene["sph.scale_h"]


def test_numpy_bool_is_not_a_step_count(sim):
    with pytest.raises(TypeError, match="steps must be an integer"):
        sim.step(np.bool_(True))


@pytest.mark.parametrize("n", [2**63, 2**64 - 1, np.uint64(2**64 - 1)])
def test_step_count_beyond_int64_is_one_line(sim, n):
    # was nanobind's multi-line "incompatible function arguments" TypeError
    with pytest.raises(ValueError, match=r"^steps must be <= 9223372036854775807, got \d+$"):
        sim.step(n)


@pytest.mark.parametrize("name", [3, None, b"position"])
def test_field_name_must_be_a_string(sim, name):
    with pytest.raises(TypeError, match=r"^field name must be a string, got "):
        sim.field(name)


@pytest.mark.parametrize("until", ["1", b"1", True, [1.0]])
def test_run_until_must_be_a_number(until):
    # run(until="1") used to run to t = 1 s
    s = corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=300)
    with pytest.raises(TypeError, match="until must be a number of seconds"):
        s.run(until=until)
    assert s.steps == 0


@pytest.mark.parametrize("what", ["positions", "velocities"])
def test_set_particles_values_that_overflow_float32_are_refused(what):
    # 1e300 is finite as float64 but inf as the core's float32: it was accepted (with a
    # NumPy RuntimeWarning) and the next step started from an infinite state
    s = corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=300)
    pos = np.array(s.positions, dtype=np.float64)
    vel = np.zeros_like(pos)
    (pos if what == "positions" else vel)[7] = [1e300, 0.0, 0.0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow warning either
        with pytest.raises(ValueError, match=rf"^{what}\[7\] = \[1e\+300, 0.0, 0.0\] does not fit in float32"):
            s.set_particles(pos, vel)
    # the state is unchanged and finite
    assert np.isfinite(np.asarray(s.velocities)).all() and np.isfinite(np.asarray(s.positions)).all()


def test_checkpoint_values_that_overflow_float32_are_refused():
    s = corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=300)
    state = s.checkpoint()
    state["velocity"] = np.array(state["velocity"], dtype=np.float64)
    state["velocity"][0, 2] = -1e39
    with pytest.raises(ValueError, match=r"checkpoint velocity\[0\] = .* does not fit in float32"):
        s.restore(state)


@pytest.mark.parametrize("kw", [{"acceleration": (1e300, 0, 0)}, {"acceleration": (0, -1.5e4, 0)},
                                {"torque": (0, 0, 1e30)}])
def test_magic8ball_control_beyond_a_shake_bound_is_refused(kw):
    # 1e300 m/s² was taken (inf in float32) and the run went unstable at its first step
    s = corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=300)
    name = next(iter(kw))
    with pytest.raises(ValueError, match=rf"^{name} must be 3 numbers each in \["):
        s.set_control(**kw)
    assert s.control[name] == [0.0, 0.0, 0.0]
    # the bound itself is allowed (the same range as a [[shake]] window's key)
    s.set_control(acceleration=(1e4, 0, 0), torque=(0, 0, -1e6))
    assert s.control == {"acceleration": [1e4, 0.0, 0.0], "torque": [0.0, 0.0, -1e6]}


@pytest.mark.parametrize("n", [1, 2, 3])
def test_wind_tunnel_with_a_handful_of_particles_builds_without_warnings(n):
    # a lattice spacing wider than the channel gave no row: "divide by zero" RuntimeWarnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = corpuscle.Simulation.from_scene("wind-tunnel", backend="serial", particles=n)
    pos = np.asarray(s.positions)
    assert pos.shape == (n, 2) and np.isfinite(pos).all()
    L, H = s.scene["channel.length"], s.scene["channel.height"]
    assert (np.abs(pos[:, 0]) < L / 2).all() and (np.abs(pos[:, 1]) < H / 2).all()


@pytest.mark.parametrize("kind,extra", [("wind-tunnel", ()), ("wind-tunnel", ("--set", "contact.enabled=false")),
                                        ("wind-tunnel-3d", ())])
def test_wind_tunnel_with_too_many_cells_names_the_keys(kind, extra):
    # 2^31 - 1 particles: a contact grid of more than 2^31 cells; the error named no key
    proc = run_cli("run", kind, "--set", "gas.particles=2147483647", *extra, "--backend", "serial", "--steps", 1,
                   timeout=120)
    assert_one_line_error(proc, "gas.particles=2147483647")
    assert "grid.cell" in proc.stderr


# --- the command line ----------------------------------------------------------------------

@pytest.fixture(scope="module")
def checkpointed(tmp_path_factory):
    out = tmp_path_factory.mktemp("ck") / "c.cps"
    p = run_cli("run", "magic8ball", "--backend", "serial", "--particles", "300", "--steps", "20", "--every", "10",
                "--checkpoint-every", "10", "--out", out)
    assert p.returncode == 0, p.stderr
    return out


@pytest.mark.parametrize("t", ["0.0001", "0.03"])
def test_resume_to_a_time_already_passed_is_an_error(checkpointed, t):
    # it took no step and reported success (exit 0, "steps 0")
    before = checkpointed.read_bytes()
    p = run_cli("run", "--resume", checkpointed, "--backend", "serial", "--time", t)
    assert_one_line_error(p, f"--time {float(t):g} must be after the checkpoint's time 0.03 s (step 20")
    assert checkpointed.read_bytes() == before


def test_resume_to_a_later_time_still_runs(checkpointed, tmp_path):
    out = tmp_path / "more.cps"
    p = run_cli("run", "--resume", checkpointed, "--backend", "serial", "--time", "0.0375", "--out", out)
    assert p.returncode == 0, p.stderr
    with corpuscle.open(out) as r:
        assert r[-1].time == pytest.approx(0.0375, abs=1e-6)


@pytest.mark.parametrize("cmd", [["run", "--resume"], ["view"]])
def test_a_folder_is_named_a_folder_not_missing(tmp_path, cmd):
    d = tmp_path / "run.cps"
    d.mkdir()
    p = run_cli(*cmd, d)
    assert_one_line_error(p, f"{d}: is a folder")


@pytest.mark.parametrize("empty", ["", " "])
def test_empty_out_is_an_error_not_the_default_name(tmp_path, empty):
    # --out '' wrote magic8ball.cps in the current folder
    p = run_cli("run", "magic8ball", "--backend", "serial", "--particles", "300", "--steps", "1", "--out", empty,
                cwd=tmp_path)
    assert_one_line_error(p, f"--out must name a file, got {empty!r}")
    assert list(tmp_path.iterdir()) == []


def test_empty_out_on_resume_is_an_error(checkpointed):
    p = run_cli("run", "--resume", checkpointed, "--backend", "serial", "--steps", "1", "--out", "")
    assert_one_line_error(p, "--out must name a file, got ''")


@pytest.mark.parametrize("bad, words", [("", "--json must name a file, got ''"), (".", "--json .: is a folder")])
def test_bench_json_target_is_checked_before_the_benchmark(tmp_path, bad, words):
    # --json '' measured and wrote nothing; --json FOLDER measured, then failed to write
    p = run_cli("bench", "magic8ball", "--backend", "serial", "--particles", "300", "--steps", "1", "--repeats", "1",
                "--json", bad, cwd=tmp_path)
    assert_one_line_error(p, words)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("sets, words", [
    (["--set", "gas.radius=1"], "gas.radius = 1 m does not fit in the channel: channel.height = 2 m"),
    (["--particles", "1", "--set", "gas.solid_fraction=0.5"],
     "gas.radius = 1.06 m (from gas.solid_fraction = 0.5 and gas.particles = 1) does not fit in the channel"),
])
def test_wind_tunnel_particle_wider_than_the_channel_names_the_keys(tmp_path, sets, words):
    # was the core's "wind-tunnel: the channel must be wider than a particle", naming no key
    p = run_cli("run", "wind-tunnel", "--backend", "serial", "--steps", "1", *sets, "--out", tmp_path / "w.cps")
    assert_one_line_error(p, words)


def test_a_toml_date_is_shown_as_toml_writes_it(tmp_path):
    # the message showed Python's repr: "got datetime.date(1970, 1, 1)"
    f = tmp_path / "d.toml"
    f.write_text('[scene]\nkind = "magic8ball"\n[run]\nend_time = 1970-01-01\n', encoding="utf-8")
    p = run_cli("run", f, "--backend", "serial", "--out", tmp_path / "d.cps")
    assert_one_line_error(p, "run.end_time must be a number in (0, 1e6] s, got 1970-01-01")


def _interrupt_during_initialisation(argv):
    """Start ``corpuscle ARGV`` (a 2,000,000-particle initialisation: 3 s on 16 cores, a
    minute on 2), Ctrl-C it after a delay; returns (seconds it took to end, process, stdout,
    stderr). A signal that arrived while the command line was still importing (a loaded
    machine) is retried with a longer delay."""
    import signal
    import subprocess
    import time
    from cli_script import script
    for delay in (1.5, 3.0, 6.0, 12.0):
        proc = subprocess.Popen([script(), *map(str, argv)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        time.sleep(delay)
        t = time.monotonic()
        proc.send_signal(signal.SIGINT)
        try:
            stdout, stderr = proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            pytest.fail("Ctrl-C during initialisation was not taken within 20 s")
        if stderr != "corpuscle: interrupted\n":  # not still in the imports
            return time.monotonic() - t, proc, stdout, stderr
    pytest.skip("the command line never got past its imports before the signal")


def test_ctrl_c_during_a_long_initialisation_exits_at_once(tmp_path):
    # 2,000,000 particles are placed and built in one call into the core (a minute on 2
    # cores); Ctrl-C then waited for all of it
    out = tmp_path / "big.cps"
    waited, proc, stdout, stderr = _interrupt_during_initialisation(
        ["run", "magic8ball", "--backend", "serial", "--particles", "2000000", "--out", out])
    assert waited < 1.5
    assert proc.returncode == 130, stderr
    assert stderr == "corpuscle: interrupted while initialising (nothing written)\n"
    assert stdout == "" and not out.exists()


def test_a_binary_file_as_airfoil_is_named_binary(tmp_path):
    # random bytes were echoed back: a line of binary garbage (control characters included)
    f = tmp_path / "r.dat"
    f.write_bytes(bytes(range(256)) * 8)
    p = run_cli("run", "wind-tunnel", "--backend", "serial", "--particles", "300", "--steps", "1",
                "--set", f"airfoil.shape={f}", "--out", tmp_path / "w.cps")
    assert_one_line_error(p, f"airfoil.shape: {f}: not a text airfoil file (it holds binary data)")


def test_a_long_bad_airfoil_line_is_shortened(tmp_path):
    f = tmp_path / "long.dat"
    f.write_text("title\n" + "x" * 5000 + "\n", encoding="utf-8")
    with pytest.raises(SceneError, match=r"long.dat:2: expected two numbers 'x y', got 'x{57}\.\.\.'$"):
        corpuscle.Simulation.from_scene("wind-tunnel", backend="serial", particles=300,
                                        overrides={"airfoil.shape": str(f)})


@pytest.mark.parametrize("call, words", [
    (lambda: corpuscle.Simulation.from_scene(None), "scene must be a built-in scene name, a TOML file path or a Scene"),
    (lambda: corpuscle.Simulation.from_scene(3), "scene must be a built-in scene name, a TOML file path or a Scene"),
    (lambda: corpuscle.Simulation.from_scene("magic8ball", backend="serial", overrides=[("fluid.xsph", 0.2)]),
     "overrides must be a mapping of dotted keys to values"),
])
def test_from_scene_wrong_types_name_the_argument(call, words):
    # were "expected str, bytes or os.PathLike object, not NoneType" and "cannot convert
    # dictionary update sequence element #0 to a sequence"
    with pytest.raises(TypeError, match=words):
        call()


def test_restore_and_checkpoint_argument_must_be_a_checkpoint(sim):
    # were "argument of type 'NoneType' is not iterable"
    for bad in (None, 3, "state"):
        with pytest.raises(TypeError, match="checkpoint must be the dict Simulation.checkpoint"):
            sim.restore(bad)
        if bad is not None:  # None: no checkpoint, a fresh start
            with pytest.raises(TypeError, match="checkpoint must be the dict Simulation.checkpoint"):
                corpuscle.Simulation(sim.scene, backend="serial", checkpoint=bad)


def test_render_onto_the_frame_stream_is_refused(tmp_path, checkpointed):
    # --out same.gif --render same.gif wrote the run, then the GIF over it (exit 0: the run lost)
    same = tmp_path / "same.gif"
    p = run_cli("run", "magic8ball", "--backend", "serial", "--particles", "300", "--steps", "2",
                "--out", same, "--render", same)
    assert_one_line_error(p, f"--render {same}: is the --out file {same}")
    assert not same.exists()
    before = checkpointed.read_bytes()
    p = run_cli("run", "--resume", checkpointed, "--backend", "serial", "--steps", "1", "--render", checkpointed)
    assert_one_line_error(p, f"--render {checkpointed}: is the --out file")
    assert checkpointed.read_bytes() == before


def _write_section(path, thickness):
    # a symmetric section, Selig order (upper surface from the trailing edge, then the lower)
    x = np.linspace(1.0, 0.0, 21)
    y = thickness * np.sqrt(np.clip(x * (1 - x), 0, None))
    pts = [(a, b) for a, b in zip(x, y)] + [(a, -b) for a, b in zip(x[::-1][1:], y[::-1][1:])]
    path.write_text("section\n" + "".join(f"{a:.6f} {b:.6f}\n" for a, b in pts), encoding="utf-8")


def test_an_airfoil_file_beside_the_scene_file_is_found_from_any_folder(tmp_path, monkeypatch):
    # shape = "wing.dat" in scenes/wing.toml was looked up in the current folder: run from
    # the project folder it was an "unknown airfoil 'wing.dat'"
    folder = tmp_path / "scenes"
    folder.mkdir()
    _write_section(folder / "wing.dat", 0.2)
    (folder / "wing.toml").write_text('[scene]\nkind = "wind-tunnel"\n[airfoil]\nshape = "wing.dat"\n', encoding="utf-8")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    s = corpuscle.scene.load_scene(str(folder / "wing.toml"))
    assert s["airfoil.shape"] == str(folder / "wing.dat")
    # an override is taken from the current folder, before the scene's
    _write_section(elsewhere / "wing.dat", 0.1)
    assert s.with_overrides({"airfoil.shape": "wing.dat"})["airfoil.shape"] == str(elsewhere / "wing.dat")
    # names that are not files stay what they were
    assert s.with_overrides({"airfoil.shape": "naca2412"})["airfoil.shape"] == "naca2412"
    sim = corpuscle.Simulation.from_scene(s, backend="serial", particles=50)
    assert sim.n_particles == 50


def test_ctrl_c_during_bench_initialisation_exits_at_once():
    waited, proc, _, stderr = _interrupt_during_initialisation(
        ["bench", "magic8ball", "--backend", "serial", "--particles", "2000000", "--steps", "1", "--repeats", "1"])
    assert waited < 1.5
    assert proc.returncode == 130 and stderr == "corpuscle: interrupted while initialising serial\n", stderr


def test_out_dev_null_runs_and_exits_0():
    # the frames went to /dev/null, then fsync on the device failed: "cannot write /dev/null:
    # Invalid argument", exit 4, after a summary saying it succeeded
    p = run_cli("run", "magic8ball", "--backend", "serial", "--particles", "300", "--steps", "3", "--out", "/dev/null")
    assert p.returncode == 0, p.stderr
    assert p.stderr == "" and "/dev/null (2 frames)" in p.stdout


def test_wind_tunnel_speed_scale_within_the_inflow_speed_range():
    # speed_scale=1e30 was taken: the stream at 5e28 m/s, dt near zero, run(until=...) stood still
    s = corpuscle.Simulation.from_scene("wind-tunnel", backend="serial", particles=50)
    U = s.scene["inflow.speed"]
    with pytest.raises(ValueError, match=r"^speed_scale = 1e\+30 makes the stream .* above inflow.speed's bound 10000"):
        s.set_control(speed_scale=1e30)
    assert s.control["speed_scale"] == [0.0]
    top = 10000.0 / U - 1.0
    s.set_control(speed_scale=top * (1 - 1e-9))  # up to the bound is allowed
    with pytest.raises(ValueError, match="above inflow.speed's bound"):
        s.set_control(speed_scale=top * 1.001)


@pytest.mark.parametrize("argv, line", [
    (["--time", "1e7"], "corpuscle: error: --time 1e+07: run.end_time must be a number in (0, 1e6] s, got 10000000.0"),
    (["--seed", "-3"], "corpuscle: error: --seed -3: run.seed must be an integer in [0, "),
    (["--every", "10000000000"], "corpuscle: error: --every 10000000000: run.record_every must be an integer in "),
    (["--set", "run.end_time=-3"], "corpuscle: error: run.end_time must be a number in (0, 1e6] s, got -3"),
])
def test_an_out_of_range_option_is_named_as_typed(argv, line, tmp_path):
    # --time 1e7 said only "run.end_time must be ...", a key the user never typed
    p = run_cli("run", "magic8ball", "--backend", "serial", *argv, "--out", tmp_path / "m.cps")
    assert_one_line_error(p)
    assert p.stderr.startswith(line), p.stderr


def test_set_of_one_array_entry_says_how_arrays_are_set(tmp_path):
    # --set shake.0.start=1 was told it "expects a dotted key", and it is one
    p = run_cli("run", "magic8ball", "--set", "shake.0.start=1", "--out", tmp_path / "m.cps")
    assert_one_line_error(p, "--set shake.0.start: [[shake]] entries are set all at once, as --set 'shake=[{...}, ...]'")


def test_vtkhdf_export_on_a_full_disk_is_one_line_and_leaves_nothing(tmp_path):
    # HDF5's own writes failed inside h5py's close: a traceback per open object, then a
    # segmentation fault (exit 139) and the hidden partial file left in the folder
    pytest.importorskip("h5py")
    import resource
    import signal
    import subprocess
    from cli_script import script
    run = tmp_path / "r.cps"
    p = run_cli("run", "magic8ball", "--backend", "serial", "--particles", "300", "--steps", "60", "--every", "2",
                "--out", run)
    assert p.returncode == 0, p.stderr
    out = tmp_path / "ex"

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (60_000, 60_000))

    p = subprocess.run([script(), "export", str(run), "--format", "vtkhdf", str(out)], capture_output=True, text=True,
                       timeout=120, preexec_fn=limit)
    assert p.returncode == 4, p.stderr[-2000:]  # the disk, not the input: as run's full disk
    assert p.stderr == f"corpuscle: error: cannot write into {out}: File too large\n", p.stderr[-2000:]
    assert not out.exists()


def test_ctrl_c_while_the_command_line_starts_is_one_line(monkeypatch, capsys):
    # Ctrl-C during the imports (a second or more on a loaded machine) was a traceback out
    # of the generated console script, exit -2: the script now enters through
    # corpuscle._entry, which imports the command line where it can catch that
    import importlib.abc
    import importlib.metadata
    import sys
    from corpuscle import _entry

    scripts = [e for e in importlib.metadata.entry_points(group="console_scripts") if e.name == "corpuscle"]
    assert scripts and all(e.value == "corpuscle._entry:main" for e in scripts), scripts

    class Interrupted(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == "corpuscle.cli":
                raise KeyboardInterrupt  # as if Ctrl-C came in the middle of importing it
            return None

    monkeypatch.delitem(sys.modules, "corpuscle.cli", raising=False)
    monkeypatch.setattr(sys, "meta_path", [Interrupted(), *sys.meta_path])
    assert _entry.main() == 130
    assert capsys.readouterr().err == "corpuscle: interrupted\n"

def test_a_disk_full_before_the_first_frame_is_exit_4_and_leaves_no_empty_file(tmp_path):
    # the header did not fit: "cannot write ...", exit 2 as if the input were bad, and an
    # empty (unreadable) file left behind
    import resource
    import signal
    import subprocess
    from cli_script import script
    out = tmp_path / "r.cps"

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (1000, 1000))  # less than the header

    p = subprocess.run([script(), "run", "magic8ball", "--backend", "serial", "--particles", "300", "--steps", "2",
                        "--out", str(out)], capture_output=True, text=True, timeout=120, preexec_fn=limit)
    assert p.returncode == 4, p.stderr
    assert p.stderr == f"corpuscle: error: cannot write {out}: File too large\n"
    assert not out.exists()


@pytest.mark.parametrize("command", ["render", "plot"])
def test_render_and_plot_on_a_full_disk_exit_4_as_run_does(tmp_path, command):
    # a full disk (here a file size limit) was exit 2, as if the input were wrong
    pytest.importorskip("matplotlib")
    import resource
    import signal
    import subprocess
    from cli_script import script
    run = tmp_path / "r.cps"
    p = run_cli("run", "magic8ball", "--backend", "serial", "--particles", "300", "--steps", "4", "--every", "2",
                "--out", run)
    assert p.returncode == 0, p.stderr
    out = tmp_path / "picture.png"

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (2_000, 2_000))

    # matplotlib builds its font cache on first use (running fc-list, which warns on stderr when
    # it cannot write): on a fresh machine that first use is built here, without the limit, so
    # the stderr below is the command's alone
    import sys
    subprocess.run([sys.executable, "-c", "import matplotlib.font_manager"], capture_output=True, timeout=120)
    args = [str(run), "-o", str(out)] + (["--frame", "0"] if command == "render" else [])
    p = subprocess.run([script(), command, *args], capture_output=True, text=True, timeout=120, preexec_fn=limit)
    assert p.returncode == 4, p.stderr[-2000:]
    assert len(p.stderr.strip().splitlines()) == 1 and "File too large" in p.stderr, p.stderr[-2000:]
    assert not out.exists()


def test_a_negative_end_time_is_refused():
    # was taken: every later step a silent no-op
    sim = corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=300)
    with pytest.raises(ValueError, match="end time must not be negative.*-1"):
        sim.set_end_time(-1)
    sim.set_end_time(0.0)  # the start itself is an end: no step is taken
    assert sim.step(3) == 0
