"""Scene kinds (corpuscle.kinds): the registry, the contract a kind keeps, the scene value
types the next kinds need (vec2, points, path, enum), and the CLI reading everything
kind-specific from the kind. Nothing here needs the compiled core."""

from __future__ import annotations

import json
import os
import pathlib

import numpy as np
import pytest

import corpuscle.scene as sc
import corpuscle.schema as schema
from corpuscle import kinds
from corpuscle.cli import main
from corpuscle.kinds import magic8ball
from corpuscle.scene import KeySpec, SceneError, check_value, load_scene


def one_line(exc_info, *needles):
    msg = str(exc_info.value)
    assert "\n" not in msg, msg
    for n in needles:
        assert n in msg, f"{n!r} not in {msg!r}"
    return msg


# ---------------------------------------------------------------------------
# the registry
# ---------------------------------------------------------------------------


def test_every_kind_module_is_registered_with_its_schema():
    folder = pathlib.Path(kinds.__file__).parent
    modules = sorted(p.stem for p in folder.glob("*.py") if not p.stem.startswith("_"))
    # a module is named after its kind, '-' written '_' (wind-tunnel lives in wind_tunnel.py)
    assert sorted(n.replace("-", "_") for n in kinds.registry()) == modules and "magic8ball" in modules
    for name, kind in kinds.registry().items():
        assert kind.name == name and kind.schema.name == name
        # the loader's tables are the registry's
        assert sc.KINDS[name] is kind.schema and sc.SCHEMAS[name] is kind.schema.keys
        assert {"run.end_time", "run.record_every"} <= set(kind.schema.keys)
        assert kind.particle_key is None or kind.particle_key in kind.schema.keys


def test_the_8ball_schema_lives_in_its_kind_not_in_the_loader():
    assert not hasattr(sc, "MAGIC8BALL_KEYS") and not hasattr(sc, "SHAKE_KEYS")
    assert kinds.get("magic8ball") is magic8ball.KIND
    assert magic8ball.KIND.particle_key == "fluid.particles"
    assert sc.KINDS["magic8ball"].arrays == {"shake": magic8ball.SHAKE_KEYS}
    with pytest.raises(KeyError, match="unknown scene kind 'nosuch' \\(kinds: [a-z0-9, -]*magic8ball"):
        kinds.get("nosuch")
    assert kinds.find("nosuch") is None


class ToyKind(kinds.Kind):
    """A test-only kind: a 2-D box of particles with an airfoil polygon from a file."""

    name = "toy"
    dim = 2
    schema = sc.SceneKind(
        name="toy",
        description="a test-only kind",
        keys={
            "run.end_time": KeySpec("float", 1.0, "s", 0.0, 1e3, "end", lo_open=True),
            "run.record_every": KeySpec("int", 10, "steps", 1, 10**6, "record interval"),
            "box.size": KeySpec("vec2", [2.0, 1.0], "m", 0.0, 100.0, "channel size", lo_open=True),
            "box.mode": KeySpec("enum", "open", doc="ends", choices=("open", "closed", "periodic")),
            "wing.outline": KeySpec("points", [[0.0, 0.0], [1.0, 0.0], [0.5, 0.1]], "m", -10.0, 10.0,
                                    "polygon", min_length=3, max_length=50),
            "wing.file": KeySpec("path", "foil.dat", doc="airfoil coordinates"),
        },
    )

    def summary(self, result):
        return [f"toy says: {result.get('word')}"], {k: v for k, v in result.items() if k != "word"}


@pytest.fixture
def toy(monkeypatch):
    """Register ToyKind for one test (registry and loader tables restored after)."""
    monkeypatch.setattr(kinds, "_REGISTRY", dict(kinds._REGISTRY))
    # the tables live in corpuscle.schema; corpuscle.scene reads the same objects
    for name in ("KINDS", "SCHEMAS"):
        table = dict(getattr(schema, name))
        monkeypatch.setattr(schema, name, table)
        monkeypatch.setattr(sc, name, table)
    return kinds.register(ToyKind())


def test_register_rejects_an_incomplete_kind(toy):
    class NoEnd(ToyKind):
        schema = sc.SceneKind("noend", "x", {"run.record_every": KeySpec("int", 1, "", 1, 9, "r")})
        name = "noend"

    with pytest.raises(TypeError, match="'noend': its schema lacks run.end_time"):
        kinds.register(NoEnd())

    class BadKey(ToyKind):
        particle_key = "fluid.particles"

    with pytest.raises(TypeError, match="particle_key 'fluid.particles' is not one of its keys"):
        kinds.register(BadKey())

    class NoMethod(ToyKind):
        methods = ("set_wing",)

    with pytest.raises(TypeError, match="methods set_wing are not defined"):
        kinds.register(NoMethod())

    class WrongName(ToyKind):
        name = "other"

    with pytest.raises(TypeError, match="schema must be a SceneKind named 'other'"):
        kinds.register(WrongName())


def test_a_registered_kind_loads_from_a_file_with_every_new_type(toy, tmp_path):
    (tmp_path / "data").mkdir()
    foil = tmp_path / "data" / "naca.dat"
    foil.write_text("0 0\n1 0\n", encoding="utf-8")
    (tmp_path / "foil.dat").write_text("x", encoding="utf-8")
    f = tmp_path / "t.toml"
    f.write_text('[scene]\nkind = "toy"\n[box]\nsize = [4, 2]\nmode = "periodic"\n'
                 '[wing]\noutline = [[0, 0], [1, 0.5], [1, -0.5], [0.2, 0]]\nfile = "data/naca.dat"\n',
                 encoding="utf-8")
    s = load_scene(f)
    assert s["box.size"] == [4.0, 2.0] and s["box.mode"] == "periodic"
    assert s["wing.outline"] == [[0.0, 0.0], [1.0, 0.5], [1.0, -0.5], [0.2, 0.0]]
    # relative to the scene file's folder, stored absolute, so the scene's dict reloads anywhere
    assert s["wing.file"] == str(foil) and os.path.isabs(s["wing.file"])
    again = sc.Scene.from_dict(s.to_dict())
    assert again == s
    # the default path ("foil.dat") is relative to the file's folder too
    assert load_scene(f, {"wing.file": str(foil)})["wing.file"] == str(foil)


def test_scenes_keys_lists_every_registered_kind(toy, capsys):
    assert main(["scenes", "--keys"]) == 0
    out = capsys.readouterr().out
    assert "kind magic8ball:" in out and "kind toy: a test-only kind" in out
    line = next(ln for ln in out.splitlines() if "wing.outline" in ln)
    assert "points" in line and "[-10, 10]" in line and "polygon" in line
    assert any("box.mode" in ln and "enum" in ln for ln in out.splitlines())


def test_particles_option_needs_a_kind_with_a_particle_key(toy, tmp_path, capsys):
    (tmp_path / "foil.dat").write_text("x", encoding="utf-8")
    f = tmp_path / "t.toml"
    f.write_text('[scene]\nkind = "toy"\n', encoding="utf-8")
    for cmd in ("run", "bench"):
        assert main([cmd, str(f), "--particles", "500"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1
        assert "--particles: scene kind 'toy' has no particle count (use --set)" in err


def test_particles_option_sets_the_kinds_particle_key(tmp_path, monkeypatch):
    # parse the run's plan only (no core): --particles lands on fluid.particles for the 8-ball
    import argparse

    from corpuscle import cli
    from corpuscle.cli import _run_plan

    monkeypatch.chdir(tmp_path)
    parser = cli.build_parser()
    args = parser.parse_args(["run", "magic8ball", "--particles", "777", "--set", "fluid.particles=500"])
    plan = _run_plan.prepare(args)
    assert plan.scene["fluid.particles"] == 777
    assert isinstance(args, argparse.Namespace)


def test_the_kind_writes_the_run_summary_lines(toy, capsys):
    from types import SimpleNamespace

    from corpuscle.cli import run

    summary = {"scene": "t", "backend": "cpu", "particles": 10, "ghosts": None, "steps": 1, "sim_time": 0.1,
               "init_time": 0.0, "wall_time": 1.0, "steps_per_second": 1.0, "particle_steps_per_second": 10.0,
               "frames": 1, "out": "t.cps", "result": {"word": "yes", "lift": 2.5}}
    run.print_summary(summary, SimpleNamespace(kind="toy", path=None, builtin=True))
    out = capsys.readouterr().out.splitlines()
    assert "toy says: yes" in out and out[-1].split() == ["lift", "2.5"] and "8-ball says" not in "".join(out)
    # the 8-ball's: the answer line, then the rest as rows
    lines, rest = magic8ball.KIND.summary({"answer_face": 3, "answer": "Outlook good", "die_position": [0, 0, 0]})
    assert lines == ["8-ball says: Outlook good (face 3)"] and rest == {"die_position": [0, 0, 0]}
    assert magic8ball.KIND.summary({}) == ([], {})


# ---------------------------------------------------------------------------
# value types: vec2, points, path, enum
# ---------------------------------------------------------------------------

VEC2 = KeySpec("vec2", [0.0, 0.0], "m/s", -100.0, 100.0, "inflow velocity")


@pytest.mark.parametrize("value, expect", [([1, 2], [1.0, 2.0]), ((0.5, -3), [0.5, -3.0]),
                                           (np.array([1.0, 2.0]), [1.0, 2.0]), ([-100, 100], [-100.0, 100.0])])
def test_vec2_good(value, expect):
    assert check_value("inflow.velocity", VEC2, value) == expect


@pytest.mark.parametrize("value, shown", [([1, 2, 3], "[1, 2, 3]"), ([1], "[1]"), ([1, float("nan")], "[1, nan]"),
                                          ([True, 1], "[true, 1]"), ("12", '"12"'), ([1, 101], "[1, 101]"),
                                          (3.0, "3.0")])
def test_vec2_bad(value, shown):
    with pytest.raises(SceneError) as e:
        check_value("inflow.velocity", VEC2, value)
    one_line(e, "inflow.velocity must be a list of 2 finite numbers each in [-100, 100] m/s", f"got {shown}")


POINTS = KeySpec("points", [], "m", -5.0, 5.0, "outline", min_length=3, max_length=5)


def test_points_good_2d_3d_and_numpy():
    tri = [[0, 0], [1, 0], [0.5, 1]]
    assert check_value("wing.outline", POINTS, tri) == [[0.0, 0.0], [1.0, 0.0], [0.5, 1.0]]
    assert check_value("wing.outline", POINTS, [(0, 0, 0), (1, 0, 0), (0, 1, 0)])[2] == [0.0, 1.0, 0.0]
    arr = np.array(tri, dtype=np.float32)
    assert check_value("wing.outline", POINTS, arr) == [[0.0, 0.0], [1.0, 0.0], [0.5, 1.0]]
    fixed = KeySpec("points", [], "m", dim=3, doc="probes")
    assert check_value("probes.at", fixed, []) == []
    assert POINTS.describe() == "a list of 3 to 5 points, each 2 or 3 finite numbers in [-5, 5] m (all the same)"
    assert fixed.describe() == "a list of points, each 3 finite numbers m"


@pytest.mark.parametrize("value, needles", [
    ([[0, 0], [1, 0]], ["wing.outline must be a list of 3 to 5 points", "got 2 points"]),
    ([[0, 0]] * 6, ["wing.outline must be a list of 3 to 5 points", "got 6 points"]),
    ("square", ["wing.outline must be a list of 3 to 5 points", 'got "square"']),
    ([[0, 0], [1, 0], [1, 0, 0]], ["wing.outline[2] must be 2 finite numbers each in [-5, 5] (as the first point)",
                                   "got [1, 0, 0]"]),
    ([[0, 0], [1, float("inf")], [0, 1]], ["wing.outline[1] must be 2 finite numbers", "got [1, inf]"]),
    ([[0, 0], [1, 9], [0, 1]], ["wing.outline[1]", "each in [-5, 5]", "got [1, 9]"]),
    ([[0, 0], 3, [0, 1]], ["wing.outline[1] must be 2 finite numbers", "got 3"]),
    ([[0], [1], [2]], ["wing.outline[0] must be 2 or 3 finite numbers", "got [0]"]),
    ([["a", "b"], [1, 0], [0, 1]], ["wing.outline[0]", 'got ["a", "b"]']),
])
def test_points_bad(value, needles):
    with pytest.raises(SceneError) as e:
        check_value("wing.outline", POINTS, value)
    one_line(e, *needles)


def test_points_of_fixed_dimension():
    spec = KeySpec("points", [], "m", dim=3, doc="probes", max_length=2)
    with pytest.raises(SceneError) as e:
        check_value("probes.at", spec, [[0, 0]])
    one_line(e, "probes.at[0] must be 3 finite numbers, got [0, 0]")
    with pytest.raises(SceneError) as e:
        check_value("probes.at", spec, [[0, 0, 0]] * 3)
    one_line(e, "probes.at must be a list of at most 2 points, each 3 finite numbers m, got 3 points")


PATH = KeySpec("path", None, doc="airfoil file")


def test_path_relative_to_the_base_folder_and_absolute(tmp_path):
    (tmp_path / "a").mkdir()
    f = tmp_path / "a" / "foil.dat"
    f.write_text("0 0\n", encoding="utf-8")
    assert check_value("wing.file", PATH, "foil.dat", base=tmp_path / "a") == str(f)
    assert check_value("wing.file", PATH, "a/foil.dat", base=tmp_path) == str(f)
    assert check_value("wing.file", PATH, str(f), base="/nonexistent") == str(f)
    assert check_value("wing.file", PATH, f) == str(f)  # a path object
    assert check_value("wing.file", PATH, "a/../a/foil.dat", base=tmp_path) == str(f)


def test_path_bad(tmp_path):
    (tmp_path / "dir").mkdir()
    with pytest.raises(SceneError) as e:
        check_value("wing.file", PATH, "nosuch.dat", base=tmp_path)
    one_line(e, 'wing.file must be the path of an existing file, got "nosuch.dat"',
             f"({tmp_path / 'nosuch.dat'} does not exist)")
    with pytest.raises(SceneError) as e:
        check_value("wing.file", PATH, "dir", base=tmp_path)
    one_line(e, 'wing.file must be the path of an existing file, got "dir"', "is a folder")
    for bad, shown in ((3, "3"), ("", '""'), (["a.dat"], '["a.dat"]'), (None, "None")):
        with pytest.raises(SceneError) as e:
            check_value("wing.file", PATH, bad, base=tmp_path)
        one_line(e, f"wing.file must be the path of an existing file, got {shown}")


def test_path_in_a_scene_file_is_relative_to_the_file_and_an_override_to_the_current_folder(toy, tmp_path,
                                                                                            monkeypatch):
    scenes, work = tmp_path / "scenes", tmp_path / "work"
    scenes.mkdir(), work.mkdir()
    (scenes / "foil.dat").write_text("scene's", encoding="utf-8")
    (work / "foil.dat").write_text("mine", encoding="utf-8")
    (work / "other.dat").write_text("mine too", encoding="utf-8")
    f = scenes / "t.toml"
    f.write_text('[scene]\nkind = "toy"\n[wing]\nfile = "foil.dat"\n', encoding="utf-8")
    monkeypatch.chdir(work)
    assert load_scene(f)["wing.file"] == str(scenes / "foil.dat")
    assert load_scene(f, {"wing.file": "other.dat"})["wing.file"] == str(work / "other.dat")


def test_path_error_from_the_command_line_is_one_line(toy, tmp_path, monkeypatch, capsys):
    (tmp_path / "foil.dat").write_text("x", encoding="utf-8")
    f = tmp_path / "t.toml"
    f.write_text('[scene]\nkind = "toy"\n', encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(f), "--set", "wing.file=missing.dat"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert 'wing.file must be the path of an existing file, got' in err and "missing.dat" in err


ENUM = KeySpec("enum", "open", doc="inlet", choices=("open", "closed", "periodic"))


def test_enum_good_and_bad():
    assert check_value("box.mode", ENUM, "closed") == "closed"
    with pytest.raises(SceneError) as e:
        check_value("box.mode", ENUM, "perodic")
    one_line(e, 'box.mode must be one of "open", "closed", "periodic", got "perodic" (did you mean "periodic"?)')
    for bad, shown in (("Open", '"Open"'), (1, "1"), (True, "true"), (["open"], '["open"]')):
        with pytest.raises(SceneError) as e:
            check_value("box.mode", ENUM, bad)
        one_line(e, 'box.mode must be one of "open", "closed", "periodic", got ' + shown)


def test_enum_in_a_scene_via_set(toy, tmp_path, capsys):
    (tmp_path / "foil.dat").write_text("x", encoding="utf-8")
    f = tmp_path / "t.toml"
    f.write_text('[scene]\nkind = "toy"\n', encoding="utf-8")
    assert load_scene(f, {"box.mode": "closed"})["box.mode"] == "closed"
    assert main(["run", str(f), "--set", "box.mode=shut"]) == 2
    assert 'box.mode must be one of "open", "closed", "periodic", got "shut"' in capsys.readouterr().err


def test_schema_typos_fail_at_declaration():
    with pytest.raises(TypeError, match="needs choices"):
        KeySpec("enum", "a")
    with pytest.raises(TypeError, match="type must be one of"):
        KeySpec("vec4", [0, 0, 0, 0])
    with pytest.raises(TypeError, match="dim must be 2 or 3"):
        KeySpec("points", [], dim=4)
    with pytest.raises(TypeError, match="min_length/max_length"):
        KeySpec("points", [], min_length=5, max_length=2)
    with pytest.raises(TypeError, match="choices must be a tuple of strings"):
        KeySpec("enum", "a", choices="abc")


def test_json_of_new_types_is_plain(toy, tmp_path):
    (tmp_path / "foil.dat").write_text("x", encoding="utf-8")
    f = tmp_path / "t.toml"
    f.write_text('[scene]\nkind = "toy"\n', encoding="utf-8")
    d = load_scene(f).to_dict()
    assert json.loads(json.dumps(d)) == d
    assert d["wing"]["outline"] == [[0.0, 0.0], [1.0, 0.0], [0.5, 0.1]] and d["box"]["size"] == [2.0, 1.0]
