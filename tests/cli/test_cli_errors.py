"""Bad input to the command line: exit code 2, one line on stderr, no traceback.

Every case here must fail before the compiled core is needed, so the core and the
simulation module are blocked from importing for the whole file.
"""

import importlib.util
import os
import pathlib
import subprocess
import sys

import pytest

from corpuscle.cli import COMMANDS, main

REPO = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def no_core(monkeypatch):
    """Make `import corpuscle._core` and `import corpuscle.simulation` fail."""
    monkeypatch.setitem(sys.modules, "corpuscle._core", None)
    monkeypatch.setitem(sys.modules, "corpuscle.simulation", None)


def _bad_toml(tmp_path):
    p = tmp_path / "broken.toml"
    p.write_text('[scene]\nkind = "magic8ball"\n[fluid\n', encoding="utf-8")
    return str(p)


def _dt_file(tmp_path):
    p = tmp_path / "dt.toml"
    p.write_text('[scene]\nkind = "magic8ball"\n[timestep]\ndt_min = 0.01\ndt_max = 0.001\n', encoding="utf-8")
    return str(p)


# (argv, text that the one error line must contain)
CASES = [
    (["run", "nosuchscene"], "unknown scene 'nosuchscene' (built-in scenes: dam-break, dam-break-2d, dam-break-dsph, dam-break-dsph-building, dam-break-obstacle, floating-box, floating-box-2d, fluid-box, lid-driven-cavity, magic8ball, piston-wave-maker, poiseuille, taylor-green, wind-tunnel, wind-tunnel-3d, wind-tunnel-sphere, wind-tunnel-wing)"),
    (["run", "magic8ball", "--set", "fluid.stifness=2e4"], "unknown key 'fluid.stifness' (did you mean 'fluid.stiffness'?)"),
    (["run", "magic8ball", "--set", "fluid.particles=lots"], 'fluid.particles must be an integer in [200, 2000000], got "lots"'),
    (["run", "magic8ball", "--set", "sph.scale_h=1"], "sph.scale_h must be true or false, got 1"),
    (["run", "magic8ball", "--set", "gravity.g=[0,0]"], "gravity.g must be a list of 3 finite numbers"),
    (["run", "magic8ball", "--particles", "-5"], "fluid.particles must be an integer in [200, 2000000], got -5"),
    (["run", "magic8ball", "--particles", "many"], "--particles must be an integer, got 'many'"),
    (["run", "magic8ball", "--set", "sph.h=0"], "sph.h must be a number in (0, 10] m, got 0"),
    (["run", "magic8ball", "--set", "timestep.dt_min=0.01", "--set", "timestep.dt_max=0.001"],
     "timestep.dt_min must be <= timestep.dt_max"),
    (["run", "{dt}"], "timestep.dt_min must be <= timestep.dt_max"),
    (["run", "{bad}"], "cannot read scene file"),
    (["run", "{tmp}/missing.toml"], "No such file or directory"),
    (["run", "magic8ball", "--set", "fluid.particles"], "--set expects key=value"),
    (["run", "magic8ball", "--set", "gravity.g=[0,0"], "gravity.g"),
    (["run", "magic8ball", "--set", "scene.kind=other"], "scene.kind"),
    (["run", "magic8ball", "--set", "die.answers=[\"a\",\"b\"]"], "die.answers must be a list of exactly 6"),
    (["run", "magic8ball", "--set", "die.position=[0.1,0,0]"], "die.position"),
    (["run", "magic8ball", "--every", "0"], "--every must be a positive integer, got 0"),
    (["run", "magic8ball", "--steps", "-3"], "--steps must be a positive integer, got -3"),
    (["run", "magic8ball", "--steps", "ten"], "--steps must be an integer, got 'ten'"),
    (["run", "magic8ball", "--time", "-1"], "run.end_time must be a number in (0, 1e6] s, got -1.0"),
    (["run", "magic8ball", "--time", "soon"], "--time must be a number, got 'soon'"),
    (["run"], "run needs a SCENE or FILE.toml (or --resume RUN.cps)"),
    (["run", "magic8ball", "--checkpoint-every", "150", "--every", "100"],
     "--checkpoint-every 150 must be a multiple of the record interval (run.record_every = 100)"),
    (["run", "{scene}", "--out", "{scene}"], "is the scene file being run; choose another output"),
    (["run", "--resume", "{tmp}/nothing.cps"], "--resume {tmp}/nothing.cps: no such file"),
    (["run", "magic8ball", "--resume", "{tmp}/nothing.cps"], "--resume continues the recorded scene; SCENE cannot"),
    (["run", "magic8ball", "--seed", "-1"], "run.seed"),
    (["run", "magic8ball", "--out", "{tmp}/no/such/dir/x.cps"], "does not exist"),
    (["bench", "nosuchscene"], "unknown scene 'nosuchscene'"),
    (["bench", "magic8ball", "--steps", "-3"], "--steps must be a positive integer, got -3"),
    (["bench", "magic8ball", "--repeats", "0"], "--repeats must be a positive integer, got 0"),
    (["bench", "magic8ball", "--warmup", "-1"], "--warmup must be an integer >= 0, got -1"),
    (["bench", "magic8ball", "--particles", "100"], "fluid.particles must be an integer in [200, 2000000], got 100"),
    (["bench", "magic8ball", "--set", "fluid.viscosity=-1"], "fluid.viscosity"),
]


def _scene_file(tmp_path):
    p = tmp_path / "mine.toml"
    if not p.exists():
        p.write_text('[scene]\nkind = "magic8ball"\nname = "mine"\n', encoding="utf-8")
    return str(p)


def _expand(argv, tmp_path):
    """Fill in the placeholders: {bad}, {dt}, {scene} (files made here) and {tmp}."""
    files = {"{bad}": _bad_toml, "{dt}": _dt_file, "{scene}": _scene_file}
    return [files[a](tmp_path) if a in files else a.replace("{tmp}", str(tmp_path)) for a in argv]


@pytest.mark.parametrize("argv, needle", CASES, ids=[" ".join(c[0]) for c in CASES])
def test_bad_input_exits_2_with_one_line(argv, needle, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code = main(_expand(argv, tmp_path))
    out, err = capsys.readouterr()
    assert code == 2
    assert out == ""
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("corpuscle: error: ")
    assert needle.replace("{tmp}", str(tmp_path)) in lines[0], lines[0]
    assert "Traceback" not in err
    # nothing was written
    assert not list(tmp_path.glob("*.cps"))


def test_missing_core_is_one_line_after_validation(tmp_path, capsys, monkeypatch):
    # a valid scene gets as far as the core, whose absence is one line too
    monkeypatch.chdir(tmp_path)
    assert main(["run", "magic8ball", "--steps", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("corpuscle: error: the compiled core is not available")


def test_info_without_core(capsys):
    assert main(["info"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("corpuscle: error:") and "compiled core" in err


@pytest.mark.parametrize(
    "argv",
    [["run", "magic8ball", "--backend", "gpu"], ["bench", "magic8ball", "--backend", "auto"], ["nosuchcmd"],
     ["run", "magic8ball", "--bogus"], ["run", "magic8ball", "--steps"], ["render"]],
)
def test_argparse_usage_errors_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    out, err = capsys.readouterr()
    # one line: the message and where the usage is
    assert out == "" and err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("corpuscle") and "error:" in err and "--help`)" in err


def test_usage_error_through_the_console_script_is_one_line():
    p = subprocess.run(["corpuscle", "run", "magic8ball", "--backend", "foo"], capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 2 and p.stdout == ""
    assert p.stderr == ("corpuscle: error: argument --backend: invalid choice: 'foo' (choose from 'auto', "
                        "'serial', 'cpu', 'cuda') (see `corpuscle run --help`)\n")


@pytest.mark.parametrize("name", list(COMMANDS))
def test_help_on_every_subcommand(name, capsys):
    with pytest.raises(SystemExit) as e:
        main([name, "--help"])
    assert e.value.code == 0
    assert f"usage: corpuscle {name}" in capsys.readouterr().out


def test_scenes_lists_builtins(capsys):
    assert main(["scenes"]) == 0
    out = capsys.readouterr().out
    names = [line.split()[0] for line in out.splitlines() if line.strip()]
    assert "magic8ball" in names and names == sorted(names)
    assert main(["scenes", "--keys"]) == 0
    out = capsys.readouterr().out
    assert "fluid.stiffness" in out and "[[shake]]" in out
    if importlib.util.find_spec("corpuscle._core") is not None:
        assert "  --neighbors: lists, grid, allpairs (default lists)" in out.splitlines()


@pytest.mark.parametrize(
    "module", ["corpuscle.cli", "corpuscle"]
)
def test_subprocess_no_traceback(module, tmp_path):
    # a fresh interpreter, as the console script runs
    env = dict(os.environ, PYTHONPATH=str(REPO / "python"))
    proc = subprocess.run(
        [sys.executable, "-m", module, "run", "magic8ball", "--set", "fluid.stifness=1"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert proc.stderr == "corpuscle: error: unknown key 'fluid.stifness' (did you mean 'fluid.stiffness'?)\n"
