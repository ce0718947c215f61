"""Scene loading and validation (corpuscle.scene); needs no compiled core."""

import json
import math
import pathlib
import tomllib

import pytest

from corpuscle import scene as sc
from corpuscle.scene import SCHEMAS, SceneError, builtin_scenes, load_scene, parse_set

M8 = SCHEMAS["magic8ball"]


def _one_line_error(excinfo, *needles):
    """The message is one line and names each needle."""
    msg = str(excinfo.value)
    assert "\n" not in msg
    for n in needles:
        assert n in msg, f"{n!r} not in {msg!r}"
    return msg


def _write(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


# ---------------------------------------------------------------------------
# built-ins and defaults
# ---------------------------------------------------------------------------


def test_builtin_list_has_magic8ball():
    names = dict(builtin_scenes())
    assert "magic8ball" in names
    assert names["magic8ball"]


def test_builtin_loads_with_schema_defaults():
    s = load_scene("magic8ball")
    assert s.kind == "magic8ball" and s.name == "magic8ball" and s.builtin
    assert s.path is not None and pathlib.Path(s.path).name == "magic8ball.toml"
    # the built-in sets every key to its schema default
    for key, spec in M8.items():
        assert s[key] == spec.default, key
    assert s["fluid.particles"] == 3500 and isinstance(s["fluid.particles"], int)
    assert s["gravity.g"] == [0.0, 0.0, -9.81]
    assert s["die.answers"][3] == "Don't count on it"


def test_builtin_shakes():
    s = load_scene("magic8ball")
    assert s.shakes == [
        {"start": 0.5, "end": 1.0, "acceleration": [3.0, 0.0, 0.0], "torque": [0.0, 0.0, 0.02]},
        {"start": 1.2, "end": 1.6, "acceleration": [-2.0, 1.5, 0.0], "torque": [0.01, 0.0, 0.0]},
    ]


def test_builtin_toml_keys_match_schema_exactly():
    text = load_scene("magic8ball").path.read_text(encoding="utf-8")
    doc = tomllib.loads(text)
    flat = {f"{t}.{k}" for t, table in doc.items() if t not in ("scene", "shake") for k in table}
    assert flat == set(M8)
    # every key line after the [scene] table carries a unit comment
    body = text.split("[run]", 1)[1]
    for line in body.splitlines():
        if "=" in line and not line.lstrip().startswith(("#", '"', "[")):
            assert "#" in line, line


def test_minimal_file_takes_defaults(tmp_path):
    p = _write(tmp_path, '[scene]\nkind = "magic8ball"\n', "tiny.toml")
    s = load_scene(p)
    assert s.name == "tiny" and not s.builtin and s.path == p
    assert s.values == {k: spec.default for k, spec in M8.items()}
    assert s.shakes == []


def test_int_accepted_for_float_and_normalised(tmp_path):
    p = _write(tmp_path, '[scene]\nkind = "magic8ball"\n[fluid]\nstiffness = 20000\n[gravity]\ng = [0, 0, -1]\n')
    s = load_scene(str(p))
    assert s["fluid.stiffness"] == 20000.0 and isinstance(s["fluid.stiffness"], float)
    assert s["gravity.g"] == [0.0, 0.0, -1.0]


def test_to_dict_is_json_and_round_trips():
    s = load_scene("magic8ball", {"fluid.particles": 5000})
    d = json.loads(json.dumps(s.to_dict()))
    assert d["scene"]["kind"] == "magic8ball"
    assert d["fluid"]["particles"] == 5000
    assert len(d["shake"]) == 2
    back = sc.Scene.from_dict(d)
    assert back == s and back.values == s.values and back.shakes == s.shakes


# ---------------------------------------------------------------------------
# bad values: type, range, unknown keys and tables
# ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "key, value, needles",
    [
        ("fluid.particles", -5, ["fluid.particles must be an integer in [200, 2000000], got -5"]),
        ("fluid.particles", 3500.5, ["fluid.particles", "3500.5"]),
        ("fluid.particles", 1e4, ["fluid.particles", "10000.0"]),
        ("fluid.particles", True, ["fluid.particles", "got true"]),
        ("fluid.particles", "many", ["fluid.particles", '"many"']),
        ("fluid.stiffness", "stiff", ["fluid.stiffness", "(0, 1e10] Pa", '"stiff"']),
        ("fluid.stiffness", 0, ["fluid.stiffness", "got 0"]),
        ("fluid.stiffness", math.nan, ["fluid.stiffness", "nan"]),
        ("fluid.stiffness", math.inf, ["fluid.stiffness", "inf"]),
        ("fluid.gamma", True, ["fluid.gamma", "got true"]),
        ("sph.h", 0, ["sph.h must be a number in (0, 10] m, got 0"]),
        ("sph.h", -0.1, ["sph.h", "-0.1"]),
        ("sph.scale_h", 1, ["sph.scale_h must be true or false, got 1"]),
        ("sph.scale_h", "yes", ["sph.scale_h", '"yes"']),
        ("container.restitution", 1.5, ["container.restitution", "[0, 1]", "1.5"]),
        ("run.end_time", 0.0, ["run.end_time", "(0, 1e6] s", "0.0"]),
        ("run.seed", -1, ["run.seed", "-1"]),
        ("run.record_every", 0, ["run.record_every", "got 0"]),
        ("timestep.dt_min", 2.0, ["timestep.dt_min", "got 2.0"]),
    ],
)
def test_bad_value_names_key_and_value(key, value, needles):
    with pytest.raises(SceneError) as e:
        load_scene("magic8ball", {key: value})
    _one_line_error(e, key, *needles)


@pytest.mark.parametrize(
    "value, shown",
    [
        ([0, 0], "[0, 0]"),
        ([0, 0, 0, 1], "[0, 0, 0, 1]"),
        ([0, "x", 0], '[0, "x", 0]'),
        ([0, math.inf, 0], "[0, inf, 0]"),
        ([0, True, 0], "[0, true, 0]"),
        ([0, 0, -2e4], "[0, 0, -20000.0]"),
        (9.81, "9.81"),
    ],
)
def test_bad_vec3(value, shown):
    with pytest.raises(SceneError) as e:
        load_scene("magic8ball", {"gravity.g": value})
    _one_line_error(e, "gravity.g must be a list of 3 finite numbers", shown)


def test_unknown_key_did_you_mean(tmp_path):
    p = _write(tmp_path, '[scene]\nkind = "magic8ball"\n[fluid]\nstifness = 1.0\n')
    with pytest.raises(SceneError) as e:
        load_scene(p)
    msg = _one_line_error(e)
    assert msg == "unknown key 'fluid.stifness' (did you mean 'fluid.stiffness'?)"


def test_unknown_key_without_close_match_lists_table_keys():
    with pytest.raises(SceneError) as e:
        load_scene("magic8ball", {"fluid.zzzzzz": 1})
    _one_line_error(e, "unknown key 'fluid.zzzzzz'", "particles", "stiffness")


def test_unknown_key_suggests_by_leaf():
    with pytest.raises(SceneError) as e:
        load_scene("magic8ball", {"particles": 5000})
    _one_line_error(e, "unknown key 'particles'", "fluid.particles")


def test_unknown_table_did_you_mean(tmp_path):
    p = _write(tmp_path, '[scene]\nkind = "magic8ball"\n[fluidd]\nparticles = 400\n')
    with pytest.raises(SceneError) as e:
        load_scene(p)
    assert str(e.value) == "unknown table 'fluidd' (did you mean 'fluid'?)"


def test_unknown_table_without_match(tmp_path):
    p = _write(tmp_path, '[scene]\nkind = "magic8ball"\n[zzqq]\nx = 1\n')
    with pytest.raises(SceneError) as e:
        load_scene(p)
    _one_line_error(e, "unknown table 'zzqq'", "valid tables:", "fluid")


def test_table_given_a_scalar(tmp_path):
    p = _write(tmp_path, 'fluid = 3\n[scene]\nkind = "magic8ball"\n')
    with pytest.raises(SceneError) as e:
        load_scene(p)
    _one_line_error(e, "fluid must be a table, got 3")


def test_scalar_given_a_table(tmp_path):
    p = _write(tmp_path, '[scene]\nkind = "magic8ball"\n[fluid.particles]\nn = 3\n')
    with pytest.raises(SceneError) as e:
        load_scene(p)
    _one_line_error(e, "fluid.particles must be an integer", "{n = 3}")


# ---------------------------------------------------------------------------
# cross-key checks
# ---------------------------------------------------------------------------


def test_dt_min_above_dt_max():
    with pytest.raises(SceneError) as e:
        load_scene("magic8ball", {"timestep.dt_min": 0.01, "timestep.dt_max": 0.001})
    _one_line_error(e, "timestep.dt_min must be <= timestep.dt_max", "0.01", "0.001")


def test_dt_min_equal_dt_max_is_fine():
    s = load_scene("magic8ball", {"timestep.dt_min": 0.001, "timestep.dt_max": 0.001})
    assert s["timestep.dt_min"] == s["timestep.dt_max"]


def test_die_outside_container():
    with pytest.raises(SceneError) as e:
        load_scene("magic8ball", {"die.position": [0.1, 0.0, 0.0]})
    _one_line_error(e, "die.position", "[0.1, 0.0, 0.0]", "container.radius")


def test_die_too_big_for_container():
    with pytest.raises(SceneError) as e:
        load_scene("magic8ball", {"die.side": 0.2})
    _one_line_error(e, "die.position", "die.side = 0.2")


def test_die_off_centre_but_inside():
    s = load_scene("magic8ball", {"die.position": [0.05, 0.0, -0.02]})
    assert s["die.position"] == [0.05, 0.0, -0.02]


@pytest.mark.parametrize(
    "answers", [["a", "b", "c", "d", "e"], ["a", "b", "c", "d", "e", "f", "g"], ["a", "b", "c", "d", "e", ""], "abcdef",
                ["a", "b", "c", "d", "e", 6]]
)
def test_answers_must_be_six_non_empty_strings(answers):
    with pytest.raises(SceneError) as e:
        load_scene("magic8ball", {"die.answers": answers})
    _one_line_error(e, "die.answers must be a list of exactly 6 non-empty strings, got")


def test_answers_can_be_replaced():
    new = ["yes", "no", "maybe", "later", "never", "ask Bob"]
    assert load_scene("magic8ball", {"die.answers": new})["die.answers"] == new


# ---------------------------------------------------------------------------
# shakes
# ---------------------------------------------------------------------------


def _shake_file(tmp_path, body):
    return _write(tmp_path, '[scene]\nkind = "magic8ball"\n' + body)


def test_shake_end_before_start(tmp_path):
    p = _shake_file(tmp_path, "[[shake]]\nstart = 0.1\nend = 0.2\n[[shake]]\nstart = 1.0\nend = 0.5\n")
    with pytest.raises(SceneError) as e:
        load_scene(p)
    _one_line_error(e, "shake[2]", "start = 1.0", "end = 0.5")


def test_shake_equal_start_end(tmp_path):
    p = _shake_file(tmp_path, "[[shake]]\nstart = 1.0\nend = 1.0\n")
    with pytest.raises(SceneError) as e:
        load_scene(p)
    _one_line_error(e, "shake[1]", "start < end")


def test_shake_negative_start(tmp_path):
    p = _shake_file(tmp_path, "[[shake]]\nstart = -1.0\nend = 1.0\n")
    with pytest.raises(SceneError) as e:
        load_scene(p)
    _one_line_error(e, "shake[1].start", "-1.0")


def test_shake_missing_end(tmp_path):
    p = _shake_file(tmp_path, "[[shake]]\nstart = 0.5\n")
    with pytest.raises(SceneError) as e:
        load_scene(p)
    _one_line_error(e, "shake[1].end is missing")


def test_shake_bad_vec3(tmp_path):
    p = _shake_file(tmp_path, "[[shake]]\nstart = 0\nend = 1\ntorque = [1, 2]\n")
    with pytest.raises(SceneError) as e:
        load_scene(p)
    _one_line_error(e, "shake[1].torque", "[1, 2]")


def test_shake_unknown_key(tmp_path):
    p = _shake_file(tmp_path, "[[shake]]\nstart = 0\nend = 1\naccel = [1, 0, 0]\n")
    with pytest.raises(SceneError) as e:
        load_scene(p)
    _one_line_error(e, "unknown key 'shake[1].accel'", "shake[1].acceleration")


def test_shake_not_an_array(tmp_path):
    p = _write(tmp_path, 'shake = 3\n[scene]\nkind = "magic8ball"\n')
    with pytest.raises(SceneError) as e:
        load_scene(p)
    _one_line_error(e, "shake must be an array of tables", "got 3")


def test_shake_defaults_filled(tmp_path):
    p = _shake_file(tmp_path, "[[shake]]\nstart = 0\nend = 1\n")
    assert load_scene(p).shakes == [
        {"start": 0.0, "end": 1.0, "acceleration": [0.0, 0.0, 0.0], "torque": [0.0, 0.0, 0.0]}
    ]


def test_shakes_replaced_by_override():
    s = load_scene("magic8ball", {"shake": [{"start": 0, "end": 2, "acceleration": [1, 0, 0]}]})
    assert s.shakes == [{"start": 0.0, "end": 2.0, "acceleration": [1.0, 0.0, 0.0], "torque": [0.0, 0.0, 0.0]}]
    assert load_scene("magic8ball", {"shake": []}).shakes == []


# ---------------------------------------------------------------------------
# the [scene] table and files
# ---------------------------------------------------------------------------


def test_missing_scene_table(tmp_path):
    p = _write(tmp_path, "[fluid]\nparticles = 400\n")
    with pytest.raises(SceneError) as e:
        load_scene(p)
    _one_line_error(e, "scene.kind is missing", "magic8ball")


def test_unknown_kind(tmp_path):
    p = _write(tmp_path, '[scene]\nkind = "magic8bal"\n')
    with pytest.raises(SceneError) as e:
        load_scene(p)
    _one_line_error(e, "scene.kind must be one of", "magic8ball", '"magic8bal"', "did you mean")


def test_unknown_scene_table_key(tmp_path):
    p = _write(tmp_path, '[scene]\nkind = "magic8ball"\nnmae = "x"\n')
    with pytest.raises(SceneError) as e:
        load_scene(p)
    _one_line_error(e, "unknown key 'scene.nmae'", "scene.name")


def test_unreadable_toml(tmp_path):
    p = _write(tmp_path, '[scene]\nkind = "magic8ball"\n[fluid\nparticles = 400\n', "broken.toml")
    with pytest.raises(SceneError) as e:
        load_scene(p)
    _one_line_error(e, f"cannot read scene file {p}:", "line 3")


def test_non_utf8_file(tmp_path):
    p = tmp_path / "bin.toml"
    p.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(SceneError) as e:
        load_scene(p)
    _one_line_error(e, f"cannot read scene file {p}:", "UTF-8")


def test_missing_file(tmp_path):
    p = tmp_path / "nope.toml"
    with pytest.raises(SceneError) as e:
        load_scene(str(p))
    assert str(e.value) == f"cannot read scene file {p}: No such file or directory"


def test_directory_given(tmp_path):
    d = tmp_path / "dir.toml"
    d.mkdir()
    with pytest.raises(SceneError) as e:
        load_scene(d)
    _one_line_error(e, f"cannot read scene file {d}:")


def test_unknown_scene():
    with pytest.raises(SceneError) as e:
        load_scene("foo")
    assert str(e.value) == ("unknown scene 'foo' (built-in scenes: dam-break, dam-break-2d, dam-break-dsph, dam-break-dsph-building, "
                            "dam-break-obstacle, floating-box, floating-box-2d, fluid-box, lid-driven-cavity, magic8ball, "
                            "piston-wave-maker, poiseuille, "
                            "taylor-green, wind-tunnel, wind-tunnel-3d, wind-tunnel-sphere, wind-tunnel-wing)")


def test_unknown_scene_did_you_mean():
    with pytest.raises(SceneError) as e:
        load_scene("magic8")
    _one_line_error(e, "unknown scene 'magic8'", "did you mean 'magic8ball'")


# ---------------------------------------------------------------------------
# overrides
# ---------------------------------------------------------------------------


def test_overrides_apply_and_keep_the_rest():
    base = load_scene("magic8ball")
    s = base.with_overrides({"fluid.particles": 20000, "gravity.g": (0, 0, -1), "sph.scale_h": False})
    assert s["fluid.particles"] == 20000 and s["gravity.g"] == [0.0, 0.0, -1.0] and s["sph.scale_h"] is False
    assert s["fluid.stiffness"] == base["fluid.stiffness"]
    assert base["fluid.particles"] == 3500  # the original is untouched
    assert s.shakes == base.shakes


def test_override_scene_name_but_not_kind():
    s = load_scene("magic8ball", {"scene.name": "mine"})
    assert s.name == "mine"
    with pytest.raises(SceneError) as e:
        load_scene("magic8ball", {"scene.kind": "other"})
    _one_line_error(e, "scene.kind", '"other"')


def test_override_unknown_key_did_you_mean():
    with pytest.raises(SceneError) as e:
        load_scene("magic8ball", {"fluid.stifness": 2e4})
    assert str(e.value) == "unknown key 'fluid.stifness' (did you mean 'fluid.stiffness'?)"


def test_override_unknown_table_is_an_unknown_key():
    with pytest.raises(SceneError) as e:
        load_scene("magic8ball", {"fluidd.particles": 400})
    _one_line_error(e, "unknown key 'fluidd.particles'", "fluid.particles")


def test_overrides_cross_checked_with_file_values():
    # dt_min alone is in range but exceeds the file's dt_max
    with pytest.raises(SceneError) as e:
        load_scene("magic8ball", {"timestep.dt_min": 0.01})
    _one_line_error(e, "timestep.dt_min", "timestep.dt_max")


def test_getitem_unknown_key():
    with pytest.raises(KeyError, match="fluid.stiffness"):
        load_scene("magic8ball")["fluid.stifness"]


# ---------------------------------------------------------------------------
# parse_set
# ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "expr, expected",
    [
        ("fluid.stiffness=2e4", ("fluid.stiffness", 20000.0)),
        ("fluid.particles=3", ("fluid.particles", 3)),
        ("fluid.particles = 1_000", ("fluid.particles", 1000)),
        ("gravity.g=[0,0,-1]", ("gravity.g", [0, 0, -1])),
        ("sph.scale_h=true", ("sph.scale_h", True)),
        ('scene.name="a b"', ("scene.name", "a b")),
        ("scene.name=bare", ("scene.name", "bare")),
        ("scene.name=my run", ("scene.name", "my run")),
        ("scene.description=x=y", ("scene.description", "x=y")),
        ("shake=[{start=0, end=1}]", ("shake", [{"start": 0, "end": 1}])),
    ],
)
def test_parse_set(expr, expected):
    key, value = parse_set(expr)
    assert (key, value) == expected
    assert type(value) is type(expected[1])


@pytest.mark.parametrize(
    "expr, needle",
    [
        ("fluid.particles", "key=value"),
        ("=3", "dotted key"),
        ("a..b=3", "dotted key"),
        ("fluid.particles=", "no value"),
        ("gravity.g=[0,0", "cannot parse"),
    ],
)
def test_parse_set_errors(expr, needle):
    with pytest.raises(SceneError) as e:
        parse_set(expr)
    _one_line_error(e, needle)


def test_parse_set_then_validate_wrong_type():
    key, value = parse_set("fluid.particles=lots")
    with pytest.raises(SceneError) as e:
        load_scene("magic8ball", {key: value})
    _one_line_error(e, "fluid.particles", '"lots"')


# ---------------------------------------------------------------------------
# schema machinery
# ---------------------------------------------------------------------------


def test_every_spec_default_is_valid():
    for kind in sc.KINDS.values():
        for key, spec in kind.keys.items():
            assert sc.check_value(key, spec, spec.default) == spec.default, key
            assert spec.doc, key


def test_interval_text():
    assert M8["run.end_time"].interval() == "(0, 1e6]"
    assert M8["fluid.particles"].interval() == "[200, 2000000]"
    assert M8["die.position"].interval() == ""


def test_new_kind_can_be_registered(monkeypatch):
    from corpuscle import schema

    for name in ("KINDS", "SCHEMAS"):  # the tables live in corpuscle.schema; scene reads the same objects
        table = dict(getattr(schema, name))
        monkeypatch.setattr(schema, name, table)
        monkeypatch.setattr(sc, name, table)
    sc.register_kind(
        sc.SceneKind(
            name="toy",
            description="a toy",
            keys={"box.size": sc.KeySpec("float", 1.0, "m", 0.0, 2.0, "box edge", lo_open=True),
                  "box.deep.level": sc.KeySpec("int", 1, "", 0, 3, "nested key")},
        )
    )
    s = sc.Scene({"scene": {"kind": "toy"}, "box": {"deep": {"level": 2}}})
    assert s.values == {"box.size": 1.0, "box.deep.level": 2}
    assert s.to_dict()["box"] == {"size": 1.0, "deep": {"level": 2}}
    with pytest.raises(SceneError, match=r"box.deep.level must be an integer in \[0, 3\], got 7"):
        s.with_overrides({"box.deep.level": 7})
    assert s.shakes == []
