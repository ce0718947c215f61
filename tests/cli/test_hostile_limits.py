"""Limits a hostile user reaches: nesting, file sizes, memory, counts, run times, Ctrl-C.

Each kind of limit is a table of cases (the command or call, its input, the one-line error
or the bound it must meet); the next feature adds its rows. Every case failed before its fix:
a traceback (RecursionError, MemoryError, IndexError, AttributeError), a hang, or minutes of
work before a limit that could be checked at once.

The command-line cases go through the installed ``corpuscle`` console script
(tests/cli_script.py): exit code 2, nothing on stdout, one line ``corpuscle: error: ...``."""
from __future__ import annotations

import pytest

from cli_script import assert_one_line_error, corpuscle as run_cli


def _nested(depth: int, leaf: str = "1", open_: str = "[", close: str = "]") -> str:
    return open_ * depth + leaf + close * depth


def _deep_list(depth: int):
    value: list = []
    for _ in range(depth):
        value = [value]
    return value


# --- nesting: one depth check for every scene file, --set value and override ---------------

DEEP = 3000  # past Python's recursion limit in tomllib, repr and deepcopy

NESTING_CLI = [  # (id, scene file text or None, extra args, words of the error)
    ("set-inline-table", None, ["--set", "x=" + _nested(DEEP, "1", "{a=", "}")], "--set x nests"),
    ("set-array", None, ["--set", "fluid.particles=" + _nested(DEEP)], "--set fluid.particles nests"),
    ("set-shake-array", None, ["--set", "shake=" + _nested(40)], "--set shake nests"),
    ("file-array", f'[scene]\nkind = "magic8ball"\n[fluid]\nx = {_nested(DEEP)}\n', [],
     "nests arrays or tables more than 32 levels deep"),
    ("file-shallow-enough-to-parse", f'[scene]\nkind = "magic8ball"\n[fluid]\nparticles = {_nested(100)}\n', [],
     "nests arrays or tables more than 32 levels deep"),
    ("file-inline-tables", f'[scene]\nkind = "magic8ball"\nfluid = {_nested(DEEP, "1", "{a=", "}")}\n', [],
     "nests arrays or tables more than 32 levels deep"),
]


@pytest.mark.parametrize("text, extra, words", [c[1:] for c in NESTING_CLI], ids=[c[0] for c in NESTING_CLI])
def test_deep_nesting_is_one_line(tmp_path, text, extra, words):
    scene = "magic8ball"
    if text is not None:
        scene = tmp_path / "deep.toml"
        scene.write_text(text, encoding="utf-8")
    proc = run_cli("run", scene, *extra, "--backend", "serial", "--steps", 1, "--out", tmp_path / "o.cps")
    assert_one_line_error(proc, words)
    assert not (tmp_path / "o.cps").exists()


@pytest.mark.parametrize("overrides, words", [
    ({"shake": _deep_list(DEEP)}, "shake nests"),
    ({"fluid.particles": _deep_list(DEEP)}, "fluid.particles nests"),
    ({"scene.name": {"a": _deep_list(40)}}, "scene.name nests"),
])
def test_deep_nesting_in_api_overrides_is_a_scene_error(overrides, words):
    from corpuscle.scene import SceneError, load_scene

    with pytest.raises(SceneError, match=words):
        load_scene("magic8ball", overrides)


def test_deep_nesting_in_a_scene_dict_is_a_scene_error():
    from corpuscle.scene import Scene, SceneError

    with pytest.raises(SceneError, match="the scene nests"):
        Scene.from_dict({"scene": {"kind": "magic8ball"}, "fluid": {"x": _deep_list(DEEP)}})
