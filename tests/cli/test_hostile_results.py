"""Wrong results presented as results: inputs that used to give a number nobody measured, a
state nobody could have reached or a run that went on with what it should have refused.
Each row of a table is one hostile case; each fails before its fix.

The command-line cases go through the installed ``corpuscle`` console script (tests/cli_script.py)."""
import json
import math

import numpy as np
import pytest

pytest.importorskip("corpuscle._core")

import corpuscle
from corpuscle.scene import SceneError, load_scene
from cli_script import assert_one_line_error, corpuscle as run_cli


# --- the wind tunnel's airfoil is checked as placed -----------------------------------------

# (scene, overrides, refused): the angle of attack turns the chord about the leading edge
PLACED_AIRFOILS = [
    # nose down 90 degrees: the trailing edge reaches past the top wall (was accepted)
    ("wind-tunnel", {"airfoil.leading_edge": [-1.2, 0.6], "airfoil.angle_of_attack": -90.0}, True),
    ("wind-tunnel-3d", {"airfoil.leading_edge": [-1.2, 0.6], "airfoil.angle_of_attack": -90.0}, True),
    # nose up 60 degrees near the floor: the trailing edge goes through it (was accepted)
    ("wind-tunnel", {"airfoil.leading_edge": [0.0, -0.7], "airfoil.angle_of_attack": 60.0}, True),
    # a long chord at 80 degrees from the middle: through the floor (was accepted)
    ("wind-tunnel", {"airfoil.chord": 1.5, "airfoil.angle_of_attack": 80.0, "airfoil.leading_edge": [0.0, 0.0]},
     True),
    # upright near the outlet: fits (leading edge + chord > length / 2 was refused)
    ("wind-tunnel", {"airfoil.leading_edge": [1.6, 0.0], "airfoil.angle_of_attack": 90.0}, False),
    ("wind-tunnel-3d", {"airfoil.leading_edge": [1.6, 0.0], "airfoil.angle_of_attack": 90.0}, False),
    # the leading edge itself outside
    ("wind-tunnel", {"airfoil.leading_edge": [-1.9, 0.0]}, True),
]


@pytest.mark.parametrize("scene, overrides, refused", PLACED_AIRFOILS)
def test_wind_tunnel_checks_the_placed_airfoil(scene, overrides, refused):
    base = load_scene(scene)
    if refused:
        with pytest.raises(SceneError, match=r"airfoil\.angle_of_attack = .*not inside the channel") as e:
            base.with_overrides(overrides)
        assert "\n" not in str(e.value)
    else:
        assert base.with_overrides(overrides)["airfoil.angle_of_attack"] == overrides["airfoil.angle_of_attack"]


def test_wind_tunnel_airfoil_past_the_wall_is_one_line_on_the_cli():
    proc = run_cli("run", "wind-tunnel", "--set", "airfoil.leading_edge=[-1.2, 0.6]",
                   "--set", "airfoil.angle_of_attack=-90", "--steps", "1", "--no-progress")
    assert_one_line_error(proc, "not inside the channel")


# --- what cannot be measured is refused or reported missing, never a made-up 0 ---------------

# (scene, probe position): outside the tank, where a probe has no fluid to sample
PROBES_OUTSIDE = [
    ("dam-break-2d", [5.0, 0.1]),     # past the far wall (the tank is 5 a = 0.73 m long)
    ("dam-break-2d", [-0.01, 0.1]),   # behind the back wall
    ("dam-break-2d", [0.1, 9.0]),     # above the lid
    ("dam-break", [0.7, 0.5, 0.02]),  # beyond the depth (0.5 a = 0.073 m)
    ("fluid-box", [0.5, 0.5, 1.5]),   # above the 1 m box
    ("fluid-box", [0.5, -1e-3, 0.1]),
]


@pytest.mark.parametrize("scene, position", PROBES_OUTSIDE)
def test_probe_outside_the_tank_is_refused_at_load(scene, position):
    with pytest.raises(SceneError, match=r"^probes\[0\]\.position = .* \('p'\) is outside the tank"):
        load_scene(scene).with_overrides({"probes": [{"name": "p", "position": position}]})


def test_probe_inside_the_tank_is_accepted():
    s = load_scene("dam-break-2d").with_overrides({"probes": [{"name": "p", "position": [0.7, 0.36]}]})
    assert s.arrays["probes"][0]["position"] == [0.7, 0.36]


def test_probe_outside_the_tank_is_one_line_on_the_cli():
    proc = run_cli("run", "dam-break-2d", "--set", 'probes=[{name="far", position=[5.0, 0.1]}]', "--steps", "1")
    assert_one_line_error(proc, "probes[0].position = [5.0, 0.1] ('far') is outside the tank")


def test_probe_without_fluid_near_reports_missing_not_zero():
    # in the tank's empty top corner no particle is within the kernel's support: the pressure
    # was reported as 0.0 Pa, a number nobody measured
    sim = corpuscle.Simulation.from_scene(
        "dam-break-2d", backend="serial", particles=200,
        overrides={"probes": [{"name": "air", "position": [0.7, 0.36]}, {"name": "low", "position": [0.05, 0.02]}]})
    sim.step(5)
    probes = sim.state()["probes"]
    assert math.isnan(probes["air"]["pressure"]) and all(math.isnan(v) for v in probes["air"]["velocity"])
    assert math.isfinite(probes["low"]["pressure"]) and probes["low"]["pressure"] > 0
    result = sim.result()
    assert math.isnan(result["probe_air_p"])
    lines, rest = sim.kind.summary(result)
    assert any("probe_air_p" in line and "not measured" in line for line in lines)
    assert "probe_air_p" not in rest and "probe_low_p" in rest


def test_wind_tunnel_coefficients_nobody_measured_are_missing():
    # one particle never reaches the airfoil: C_L = 0 +- 0 was printed as a measurement
    sim = corpuscle.Simulation.from_scene("wind-tunnel", backend="serial", particles=1,
                                          overrides={"run.end_time": 0.2})
    sim.run(until=0.2)
    r = sim.result()
    assert r["blocks"] > 1
    assert all(math.isnan(r[k]) for k in ("cl", "cd", "cm", "cl_se", "lift", "drag", "moment"))
    assert "no particle touched the airfoil" in r["not_measured"]
    lines, rest = sim.kind.summary(r)
    assert lines[0].startswith("C_L, C_D, C_M: not measured (no particle touched the airfoil")
    assert "cl" not in rest and "lift" not in rest


def test_polar_with_one_particle_prints_no_coefficient(tmp_path):
    proc = run_cli("polar", "wind-tunnel", "--aoa", "5", "--particles", "1", "--end-time", "0.2", "--no-plot",
                   "--out", tmp_path / "p")
    assert proc.returncode == 0, proc.stderr
    assert "C_L 0 ± 0" not in proc.stderr and "not measured (no particle touched the airfoil" in proc.stderr
    row = (tmp_path / "p.csv").read_text().splitlines()[1].split(",")
    assert row[1] == "nan"  # cl: no number


def test_run_json_has_null_for_what_was_not_measured(tmp_path):
    proc = run_cli("run", "wind-tunnel", "--particles", "1", "--time", "0.2", "--json", "--out", tmp_path / "w.cps")
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)["result"]
    assert result["cl"] is None and result["lift"] is None and "touched" in result["not_measured"]


# --- a restored state's scalars are checked as the API's arguments are -----------------------

NAN, INF = float("nan"), float("inf")

# (scene, key, value): a crafted checkpoint (valid arrays) with one scalar nobody could reach;
# a NaN time made every step a no-op that exited 0
BAD_SCALARS = [
    ("magic8ball", "time", NAN),
    ("magic8ball", "time", INF),
    ("magic8ball", "time", -1.0),
    ("magic8ball", "step", -1),
    ("magic8ball", "step", 2**64),
    ("magic8ball", "step", 1e30),
    ("magic8ball", "step", 2.5),
    ("magic8ball", "dt", NAN),
    ("magic8ball", "dt", -1e-3),
    ("magic8ball", "sums_ke", INF),
    ("magic8ball", "sums_ke", 1e300),          # finite in float64, inf in the core's float32
    ("magic8ball", "rebuilds", -5),
    ("magic8ball", "die_position", [0.0, NAN, 0.0]),
    ("magic8ball", "die_orientation", [1.0, 0.0]),
    ("magic8ball", "control_acceleration", [1e30, 0.0, 0.0]),
    ("magic8ball", "control_torque", [0.0, 0.0, NAN]),
    ("magic8ball", "spacing", NAN),
    ("wind-tunnel", "time", NAN),
    ("wind-tunnel", "nblocks", -1),
    ("wind-tunnel", "block_len", INF),
    ("wind-tunnel", "control_pitch", 1e9),
    ("dam-break-2d", "time", -0.5),
    ("dam-break-2d", "sums_nbrs", 2**70),
    ("dam-break-2d", "control_acceleration", [0.0, INF, 0.0]),
]

_CHECKPOINTS = {}


def _checkpoint(scene):
    if scene not in _CHECKPOINTS:
        sim = corpuscle.Simulation.from_scene(scene, backend="serial", particles=300 if scene != "dam-break-2d" else 200)
        sim.step(3)
        _CHECKPOINTS[scene] = (sim, sim.checkpoint())
    return _CHECKPOINTS[scene]


@pytest.mark.parametrize("scene, key, value", BAD_SCALARS)
def test_restore_checks_every_scalar(scene, key, value):
    sim, good = _checkpoint(scene)
    before = sim.checkpoint()
    state = dict(good, **{key: value})
    with pytest.raises(ValueError, match=rf"^checkpoint {'control' if key.startswith('control_') else key}\b") as e:
        sim.restore(state)
    assert "\n" not in str(e.value)
    # nothing was restored: the state is the one before
    after = sim.checkpoint()
    assert after["time"] == before["time"] and after["step"] == before["step"] and sim.control == {
        k[len("control_"):]: list(np.atleast_1d(v)) for k, v in before.items() if k.startswith("control_")}


def test_restore_takes_a_good_checkpoint():
    sim, good = _checkpoint("magic8ball")
    sim.restore(dict(good))
    assert sim.steps == good["step"] and sim.time == good["time"]


def _crafted_run(tmp_path, key, value):
    """A recorded magic8ball run whose last checkpoint's state.<key> is `value` (valid checksums)."""
    from corpuscle import io

    src, out = tmp_path / "a.cps", tmp_path / "crafted.cps"
    proc = run_cli("run", "magic8ball", "--particles", "300", "--backend", "serial", "--steps", "20", "--every", "10",
                   "--checkpoint-every", "10", "--out", src, "--no-progress")
    assert proc.returncode == 0, proc.stderr
    with io.open(src) as run, io.FrameWriter(out, dict(run.header)) as w:
        for i in range(len(run)):
            f = run[i]
            fields = {k: np.array(v) for k, v in f.fields.items()}
            if f.kind == "checkpoint" and i == len(run) - 1:
                fields[f"state.{key}"] = np.array([value], dtype=fields[f"state.{key}"].dtype)
            w.write_frame(f.step, f.time, f.dt, fields, groups=dict(f.groups), rigid=f.rigid,
                          diagnostics=f.diagnostics, kind=f.kind)
    return out


@pytest.mark.parametrize("key, value", [("time", NAN), ("time", -1.0), ("step", -3)])
def test_resume_of_a_crafted_checkpoint_is_one_line(tmp_path, key, value):
    crafted = _crafted_run(tmp_path, key, value)
    proc = run_cli("run", "--resume", crafted, "--steps", "10", "--out", tmp_path / "b.cps", "--no-progress")
    assert_one_line_error(proc, f"checkpoint {key} = ")
    assert not (tmp_path / "b.cps").exists()


# --- one control bound for every entry point -------------------------------------------------

# (entry point, the call): 1e30 m/s² was taken by Batch and the env, refused by Simulation only
BEYOND_THE_CONTROL_BOUND = [
    ("Batch acceleration", lambda b: b.set_control(np.array([[1e30, 0, 0, 0, 0, 0], [0] * 6]))),
    ("Batch acceleration at 1.5e4", lambda b: b.set_control(np.array([[0] * 6, [0, -1.5e4, 0, 0, 0, 0]]))),
    ("Batch torque", lambda b: b.set_control(np.array([[0] * 6, [0, 0, 0, 0, 0, 2e6]]))),
]


@pytest.fixture(scope="module")
def batch():
    return corpuscle.Batch.from_scene("magic8ball", n=2, backend="serial", particles=200, settle=0.0)


@pytest.mark.parametrize("what, call", BEYOND_THE_CONTROL_BOUND, ids=[w for w, _ in BEYOND_THE_CONTROL_BOUND])
def test_batch_control_beyond_the_bound_is_refused(batch, what, call):
    with pytest.raises(ValueError, match=r"^actions\[\d, \d\] \((acceleration|torque)_[xyz]\) must be in "
                                         r"\[-(10000|1e\+06), (10000|1e\+06)\] (m/s²|N·m), got "):
        call(batch)
    # the bound itself is taken, as Simulation.set_control takes it
    batch.set_control(np.array([[1e4, 0, 0, 0, 0, -1e6]] * 2))


@pytest.mark.parametrize("kw", [{"max_acceleration": 1e30}, {"max_acceleration": 2e4}, {"max_torque": 1e7}])
def test_env_scale_beyond_the_control_bound_is_refused(kw):
    pytest.importorskip("gymnasium")
    from corpuscle.envs import Magic8BallVectorEnv

    name = next(iter(kw))
    with pytest.raises(ValueError, match=rf"^{name} must be in \(0, (10000|1e\+06)\] (m/s²|N·m), got "):
        Magic8BallVectorEnv(num_envs=1, particles=200, backend="serial", settle=0.0, **kw)


@pytest.mark.parametrize("scene, kw", [
    ("dam-break-2d", {"acceleration": (1e30, 0.0)}),      # the SPH kinds took any finite acceleration
    ("dam-break-2d", {"acceleration": (0.0, -2e4)}),
    ("fluid-box", {"acceleration": (0.0, 0.0, 1e5)}),
    ("magic8ball", {"acceleration": (0.0, 0.0, 1.5e4)}),
])
def test_simulation_control_beyond_the_bound_is_refused(scene, kw):
    sim = corpuscle.Simulation.from_scene(scene, backend="serial", particles=200 if scene != "magic8ball" else 300)
    with pytest.raises(ValueError, match=r"^acceleration must be 3 numbers each in \[-10000, 10000\] m/s², got "):
        sim.set_control(**kw)
    assert sim.control["acceleration"] == [0.0, 0.0, 0.0]


def test_the_bound_is_the_shake_windows_bound():
    from corpuscle.kinds import CONTROL_BOUNDS
    from corpuscle.kinds.magic8ball import SHAKE_KEYS

    for name, (bound, unit) in CONTROL_BOUNDS.items():
        assert (SHAKE_KEYS[name].lo, SHAKE_KEYS[name].hi, SHAKE_KEYS[name].unit) == (-bound, bound, unit)


# --- a value that begins as a negative number is a value, for every option ------------------

# argparse took anything after '-' but -12 and -1.5 for an option name: "expected one argument"
NEGATIVE_VALUES = [
    ["polar", "wind-tunnel", "--aoa", "-10:20:2"],
    ["polar", "wind-tunnel", "--aoa", "-5,0,5"],
    ["render", "r.cps", "-o", "a.png", "--camera", "-30,20"],
    ["render", "r.cps", "-o", "a.png", "--camera", "-30,-20,2"],
    ["render", "r.cps", "-o", "a.mp4", "--frames", "-3:"],
    ["render", "r.cps", "-o", "a.png", "--range", "-1e3:1e3"],
    ["export", "r.cps", "--format", "vtk", "out", "--frames", "-3:"],
    ["validate", "dam-break", "--particles", "-3e3"],
    ["run", "magic8ball", "--time", "-1e3"],
    ["run", "magic8ball", "--steps", "-.5e1"],
]


@pytest.mark.parametrize("argv", NEGATIVE_VALUES, ids=" ".join)
def test_negative_looking_values_reach_the_option(argv, capsys):
    from corpuscle.cli import build_parser
    from corpuscle.cli.validate import options_parser

    try:
        args = build_parser().parse_args(argv)
        if args.command == "validate":
            assert args.options == argv[2:]
            options_parser(args.name)[1].parse_known_args(args.options)
    except SystemExit:
        pytest.fail(f"corpuscle {' '.join(argv)}: {capsys.readouterr().err.strip()}")
    option = argv[-2].lstrip("-").replace("-", "_")
    if args.command != "validate":
        assert getattr(args, option) == argv[-1]


@pytest.mark.parametrize("argv, words", [
    (["run", "magic8ball", "--time", "-1e3"], "--time -1000: run.end_time must be"),
    (["polar", "wind-tunnel", "--aoa", "-100:20:2"], "--aoa '-100:20:2'"),
    (["validate", "wind-tunnel", "--alpha", "-10,10"], "--alpha angles must lie in [0, 60] degrees, got '-10,10'"),
    (["validate", "dam-break", "--particles", "-3e3"], "--particles must be a positive integer, got '-3e3'"),
])
def test_a_negative_value_out_of_range_is_named(argv, words):
    # the option's own check names it (not argparse's "expected one argument")
    assert_one_line_error(run_cli(*argv), words)
