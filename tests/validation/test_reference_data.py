"""The reference data the validations read (python/corpuscle/data/): each file as shipped, by
its SHA-256, its number of points, a few of its values and the source its header names. A
file edited, truncated, shifted or swapped for another fails here, whatever a validation then
makes of it."""

from __future__ import annotations

import hashlib
import pathlib

import numpy as np
import pytest

DATA = pathlib.Path(__file__).resolve().parents[2] / "python" / "corpuscle" / "data"

# file: (sha256, data rows, column names, {row: values}, words the header names)
FILES = {
    "dam_break_martin_moyce.csv": ("90be5c0c156b722137865043034b14d150f3391b3b9c7c3b63436650e40bfd64", 15,
                                   ["T", "Z"], {0: (0.41, 1.13), 10: (2.63, 3.22), -1: (3.33, 4.13)},
                                   ["Martin & Moyce 1952", "Koshizuka & Oka 1996"]),
    "martin_moyce1952_a1125.csv": ("93f31eddd06f5fc2035b582117177d995c41d37859a0f65bc997a020a0430b39", 10,
                                   ["T", "Z"], {0: (0.849, 1.245), 3: (2.283, 2.689), -1: (5.316, 6.717)},
                                   ["Martin & Moyce 1952", "a = 1.125 in"]),
    "martin_moyce1952_a225.csv": ("168dde9f9744aa8d2ce0a167630a63527976f600585fd487b19281e8859e02b3", 15,
                                  ["T", "Z"], {0: (0.832, 1.217), 2: (1.997, 2.292), -1: (9.237, 13.970)},
                                  ["Martin & Moyce 1952", "a = 2.25 in"]),
    "lobovsky2014_sensor1.csv": ("bfa608525074cdf33d2c379b76cef50a5cd0b7ddc40d00229c723c0d9e6ce881", 61,
                                 ["T", "P"], {0: (0.081, 0.023), -1: (6.982, 0.618)},
                                 ["Lobovsky", "J. Fluids Struct. 48 (2014)", "height 3 mm"]),
    "lobovsky2014_sensor3.csv": ("2621623fc7ff92e081166d86a2a89813beec4be22bc3990a1968bd51225aa517", 119,
                                 ["T", "P"], {0: (0.098, 0.006), -1: (6.966, 0.649)},
                                 ["Lobovsky", "J. Fluids Struct. 48 (2014)", "height 30 mm"]),
    "lobovsky2014_sensor4.csv": ("b6a0d2e381e8ecdaa68bb8e88b0ebcca35a4d1a196d5e0546cfd3011d18e8790", 58,
                                 ["T", "P"], {0: (0.086, 0.003), -1: (6.941, 0.475)},
                                 ["Lobovsky", "J. Fluids Struct. 48 (2014)", "height 80 mm"]),
    "buchner2002_pressure.csv": ("a04e1858141bacf57d3f1583fa8f41e27b005781a72717f8b3f75cea0612653f", 86,
                                 ["T", "P"], {0: (0.055, 0.0), 1: (0.394, 0.028), -1: (7.36, 0.449)},
                                 ["Buchner 2002", "(5.366 H, 0.2 H)"]),
    "ghia1982_u_vertical_centerline.csv": ("899bc5f67244ed218be121272e9462993f383b39b03937bc780dbd583bd8950b", 17,
                                           ["y", "Re100", "Re400", "Re1000"],
                                           {0: (1.0, 1.0, 1.0, 1.0), 8: (0.5, -0.20581, -0.11477, -0.0608),
                                            -1: (0.0, 0.0, 0.0, 0.0)},
                                           ["Ghia, Ghia & Shin 1982", "Table I"]),
    "ghia1982_v_horizontal_centerline.csv": ("7c4b5dcabec3d1d014e93dcbd50df15d1a42ca34df86e06b320f79f4e2d2c068", 17,
                                             ["x", "Re100", "Re400", "Re1000"],
                                             {0: (1.0, 0.0, 0.0, 0.0), 8: (0.5, 0.05454, 0.05188, 0.02526),
                                              -1: (0.0, 0.0, 0.0, 0.0)},
                                             ["Ghia, Ghia & Shin 1982", "Table II"]),
}


def read(path: pathlib.Path):
    lines = path.read_text().splitlines()
    header = [line for line in lines if line.startswith("#")]
    body = [line for line in lines if line and not line.startswith("#")]
    names = body[0].split(",")
    rows = np.array([[float(x) for x in line.split(",")] for line in body[1:]])
    return header, names, rows


@pytest.mark.parametrize("name", sorted(FILES))
def test_reference_file_content(name):
    sha, npts, names, values, source = FILES[name]
    path = DATA / name
    assert hashlib.sha256(path.read_bytes()).hexdigest() == sha, f"{name} changed"
    header, cols, rows = read(path)
    assert cols == names
    assert rows.shape == (npts, len(names))
    assert np.all(np.isfinite(rows))
    for i, v in values.items():
        assert rows[i] == pytest.approx(v, abs=1e-9), (name, i)
    text = " ".join(header)
    for word in source:
        assert word in text, (name, word)


def test_time_series_are_ordered():
    for name in ("martin_moyce1952_a1125.csv", "martin_moyce1952_a225.csv", "dam_break_martin_moyce.csv"):
        _, _, rows = read(DATA / name)
        assert np.all(np.diff(rows[:, 0]) > 0) and np.all(np.diff(rows[:, 1]) > 0), name  # the front only advances
    for name in ("lobovsky2014_sensor1.csv", "lobovsky2014_sensor3.csv", "lobovsky2014_sensor4.csv"):
        _, _, rows = read(DATA / name)
        assert np.all(np.diff(rows[:, 0]) >= 0), name  # (the impact digitised as vertical runs at one T)
    _, _, rows = read(DATA / "lobovsky2014_sensor1.csv")
    assert rows[:, 1].max() == pytest.approx(2.843) and rows[np.argmax(rows[:, 1]), 0] == pytest.approx(2.45)
    for name in ("ghia1982_u_vertical_centerline.csv", "ghia1982_v_horizontal_centerline.csv"):
        _, _, rows = read(DATA / name)
        assert np.all(np.diff(rows[:, 0]) < 0), name  # wall to wall, 1 down to 0
