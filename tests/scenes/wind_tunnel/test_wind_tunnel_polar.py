"""corpuscle polar: the sweep's CSV (one row per angle, the run's C_L, C_D beside the
free-molecular theory) and PNG, the angle parser, bad input."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from corpuscle import free_molecular as fm
from corpuscle.polar import parse_aoa

from cli_script import assert_one_line_error, corpuscle


def test_parse_aoa():
    assert parse_aoa("-10:20:2") == [float(a) for a in range(-10, 21, 2)]
    assert parse_aoa("0:1:0.25") == [0.0, 0.25, 0.5, 0.75, 1.0]
    assert parse_aoa("5") == [5.0] and parse_aoa("0, 3,7") == [0.0, 3.0, 7.0]
    for bad in ("", "1:2", "0:10:0", "10:0:1", "a,b", "0:100:10", "nan"):
        with pytest.raises(ValueError, match="--aoa"):
            parse_aoa(bad)


def test_polar_writes_csv_and_png(tmp_path):
    out = tmp_path / "p"
    r = corpuscle("polar", "wind-tunnel", "--aoa", "0:10:10", "--backend", "serial", "--particles", "1500",
                  "--set", "inflow.speed=1.0", "--set", "wing.restitution=0.5", "--end-time", "0.1",
                  "--out", out, "--no-progress")
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader(open(f"{out}.csv")))
    assert [float(row["angle_of_attack"]) for row in rows] == [0.0, 10.0]
    th = fm.thin_plate(np.array([0.0, 10.0]), math.inf, 0.5)
    for row, cl, cd in zip(rows, th["cl"], th["cd"]):
        assert float(row["theory_cl"]) == pytest.approx(cl) and float(row["theory_cd"]) == pytest.approx(cd)
        assert math.isfinite(float(row["cl"])) and int(row["blocks"]) > 0 and int(row["particles"]) == 1500
    png = (tmp_path / "p.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


@pytest.mark.parametrize("args,words", [
    (["wind-tunnel", "--aoa", "1:x"], "--aoa"),
    (["magic8ball", "--aoa", "0"], "wind-tunnel"),
    (["wind-tunnel", "--aoa", "0", "--end-time", "-1"], "--end-time"),
    (["wind-tunnel", "--aoa", "0", "--out", "/nonexistent/dir/p"], "--out"),
    (["wind-tunnel", "--aoa", "0", "--set", "airfoil.chord=-1"], "airfoil.chord"),
])
def test_polar_bad_input(args, words):
    assert_one_line_error(corpuscle("polar", *args), words)
