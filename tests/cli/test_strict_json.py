"""Strict JSON out (issue 26): what the command line prints with --json parses with a reader that
rejects NaN and Infinity (jq, JavaScript's JSON.parse); a value that is not measured is null, and
the human-readable summary says why it is missing."""
import json
import math

import numpy as np
import pytest

from corpuscle import _json
from corpuscle.cli import main


def _no_constants(name):
    raise ValueError(f"non-standard JSON constant {name}")


def strict_loads(text):
    return json.loads(text, parse_constant=_no_constants)


def test_dumps_writes_null_for_every_non_finite_value():
    obj = {"a": math.nan, "b": [math.inf, -math.inf, 1.5], "c": np.float32("nan"), "d": np.array([1.0, np.nan]),
           "e": (np.int64(3), np.bool_(True)), "f": {"g": np.float64("inf")}, 7: "seven"}
    text = _json.dumps(obj)
    assert "NaN" not in text and "Infinity" not in text
    assert strict_loads(text) == {"a": None, "b": [None, None, 1.5], "c": None, "d": [1.0, None], "e": [3, True],
                                  "f": {"g": None}, "7": "seven"}
    # finite values are written as json.dumps writes them (the same digits)
    assert _json.dumps({"x": 0.1, "y": 1e300, "z": np.float64(2.5)}) == json.dumps({"x": 0.1, "y": 1e300, "z": 2.5})
    # json.dumps' own default would have written NaN, which a strict reader rejects
    with pytest.raises(ValueError, match="NaN"):
        strict_loads(json.dumps({"a": math.nan}))


def test_a_wind_tunnel_run_before_its_measurement_window_prints_null_and_says_why(tmp_path, capsys):
    pytest.importorskip("corpuscle._core")
    args = ["run", "wind-tunnel", "--backend", "serial", "--particles", "300", "--steps", "5", "--no-progress",
            "--out", str(tmp_path / "w.cps")]
    assert main([*args, "--json"]) == 0
    out = capsys.readouterr().out
    summary = strict_loads(out)  # raises on NaN / Infinity
    result = summary["result"]
    # the 5 steps end long before the measurement window: the coefficients are not measured
    assert result["blocks"] == 0 and result["measure_start"] > summary["sim_time"]
    for key in ("cl", "cd", "cm", "cl_se", "lift", "drag", "moment"):
        assert key in result and result[key] is None, key
    assert isinstance(summary["steps_per_second"], float)
    # the text summary says why C_L is missing (and prints no nan)
    assert main(args) == 0
    text = capsys.readouterr().out
    line = next(s for s in text.splitlines() if "C_L" in s)
    assert "not measured" in line and "before the measurement window at t = " in line
    assert f"{result['measure_start']:.4g} s" in line
    assert "nan" not in text.lower().replace("nanos", "")


def test_info_json_is_strict(capsys):
    pytest.importorskip("corpuscle._core")
    assert main(["info", "--json"]) == 0
    info = strict_loads(capsys.readouterr().out)
    assert "version" in info and isinstance(info["build_info"], dict)
