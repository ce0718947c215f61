"""The live viewer's wire format and message checks (no server, no browser)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from corpuscle.live import protocol

CONTROLS = {"acceleration": 3, "torque": 3}


def test_quantisation_round_trips_within_one_quantum():
    rng = np.random.default_rng(1)
    lo, hi = [-0.2, -0.1, 0.0], [0.2, 0.3, 0.05]
    pos = rng.uniform(lo, hi, size=(5000, 3)).astype(np.float32)
    pos[0] = lo  # the box's corners are exact
    pos[1] = hi
    data = protocol.encode_frame(7, 1234, 0.5, pos, lo, hi, {"diagnostics": {"ke": 1.0}})
    f = protocol.decode_frame(data)
    assert (f["index"], f["step"], f["time"], f["count"], f["dim"]) == (7, 1234, 0.5, 5000, 3)
    quantum = (np.asarray(hi) - np.asarray(lo)) / protocol.QMAX
    err = np.abs(f["positions"] - pos)
    assert np.all(err <= quantum * 0.5 + 1e-7), (err / quantum).max()
    assert np.allclose(f["positions"][0], lo) and np.allclose(f["positions"][1], hi)
    assert f["meta"]["diagnostics"] == {"ke": 1.0} and f["color"] is None


def test_frame_with_colour_and_2d_and_outside_points():
    pos = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, -1.0]], dtype=np.float32)  # the last is outside: clipped
    col, vrange = protocol.color_bytes(np.array([0.0, 5.0, 10.0]), (0.0, 10.0))
    data = protocol.encode_frame(0, 0, 0.0, pos, [0.0, 0.0], [1.0, 1.0], {}, col)
    f = protocol.decode_frame(data)
    assert f["dim"] == 2 and np.allclose(f["positions"][2], [1.0, 0.0])
    assert f["color"].tolist() == [0, 127, 255] and vrange == [0.0, 10.0]


def test_domain_box_from_the_header():
    lo, hi = protocol.domain_box({"dim": 3, "container": {"type": "sphere", "center": [0, 0, 0], "radius": 0.15}})
    assert np.allclose(lo, [-0.153] * 3) and np.allclose(hi, [0.153] * 3)
    lo, hi = protocol.domain_box({"dim": 2, "container": {"type": "box", "min": [0, 0], "max": [2, 1]}})
    assert np.allclose(lo, [-0.04, -0.02]) and np.allclose(hi, [2.04, 1.02])
    lo, hi = protocol.domain_box({"dim": 3, "container": None}, np.array([[0, 0, 0], [1, 2, 3]], np.float32))
    assert np.all(np.asarray(lo) < 0) and np.all(np.asarray(hi) > [1, 2, 3])


def test_non_finite_overlay_values_are_null():
    data = protocol.encode_frame(0, 0, 0.0, np.zeros((1, 3), np.float32), [0] * 3, [1] * 3,
                                 {"d": {"x": float("nan"), "y": np.float32(2)}})
    assert protocol.decode_frame(data)["meta"]["d"] == {"x": None, "y": 2.0}


@pytest.mark.parametrize("msg", [
    {"type": "pause"}, {"type": "resume"},
    {"type": "control", "acceleration": [1, 2, 3.5]},
    {"type": "control", "acceleration": [0, 0, 0], "torque": [0.01, 0, 0]},
    {"type": "color", "field": "density"}, {"type": "color", "field": None},
])
def test_valid_messages(msg):
    out = protocol.parse_message(json.dumps(msg), CONTROLS, fields=["density"])
    assert out["type"] == msg["type"]
    if msg["type"] == "control":  # only the controls named (the server keeps the others)
        assert set(out) == set(msg) and out["acceleration"] == [float(x) for x in msg["acceleration"]]


@pytest.mark.parametrize("raw, reason", [
    ("not json", "not JSON"),
    ("[1, 2]", "not a JSON object"),
    ('{"type": "explode"}', "unknown message type"),
    ('{"kind": "control"}', "unknown message type"),
    ('{"type": "control", "acceleration": [NaN, 0, 0]}', "non-finite"),
    ('{"type": "control", "acceleration": [Infinity, 0, 0]}', "non-finite"),
    ('{"type": "control", "acceleration": [1e400, 0, 0]}', "non-finite"),
    ('{"type": "control", "acceleration": [1, 2]}', "list of 3 numbers"),
    ('{"type": "control", "acceleration": [1, 2, "3"]}', "list of 3 numbers"),
    ('{"type": "control", "acceleration": [true, 0, 0]}', "list of 3 numbers"),
    ('{"type": "control", "acceleration": [1000, 0, 0]}', "norm above"),
    ('{"type": "control", "torque": [0, 0, 50]}', "norm above"),
    ('{"type": "control", "gravity": [0, 0, 0]}', "unknown key"),
    ('{"type": "pause", "now": 1}', "unknown key"),
    ('{"type": "control"}', "names no control"),
    ('{"type": "control", "acceleration": {"x": 1}}', "list of 3 numbers"),
    ('{"type": "control", "acceleration": null}', "list of 3 numbers"),
    ('{"type": "color", "field": 3}', "unknown field"),
    ('{"type": "color"}', "without its field"),
    ('{"type": null}', "unknown message type"),
    ('{"type": ["control"]}', "unknown message type"),
    ('"control"', "not a JSON object"),
    ("", "not JSON"),
    ('{"type": "control", "acceleration": [1, 0, 0]} trailing', "not JSON"),
    ('{"type": "color", "field": "secret"}', "unknown field"),
    ('{"type": "seek", "frame": 3}', "unknown message type"),  # not in a live run
    (b'{"type": "pause"}', "binary"),
    ('{"type": "pause", "pad": "' + "x" * 5000 + '"}', "at most 4096"),
    ("[" * 3000 + "]" * 3000, "at most 4096"),
    ("[" * 2000 + "]" * 2000, "not JSON|not a JSON object"),  # deep nesting: refused, no crash
])
def test_rejected_messages(raw, reason):
    with pytest.raises(protocol.MessageError, match=reason):
        protocol.parse_message(raw, CONTROLS, fields=["density"])


def test_seek_is_checked_against_the_frame_count():
    assert protocol.parse_message('{"type": "seek", "frame": 4}', {}, frames=5) == {"type": "seek", "frame": 4}
    for bad in ('{"type": "seek", "frame": 5}', '{"type": "seek", "frame": -1}', '{"type": "seek", "frame": 1.5}'):
        with pytest.raises(protocol.MessageError, match="seek"):
            protocol.parse_message(bad, {}, frames=5)


SLIDERS = [{"control": "speed_scale", "min": 0.2, "max": 6.0, "scale": 0.5, "offset": -1.0},
           {"control": "pitch", "min": -30.0, "max": 40.0, "scale": 1.0, "offset": -10.0}]


def test_slider_ranges_bound_their_controls():
    ranges = protocol.slider_ranges(SLIDERS)
    assert ranges == {"speed_scale": [(-0.9, 2.0)], "pitch": [(-40.0, 30.0)]}
    controls = {"speed_scale": 1, "pitch": 1}
    ok = protocol.parse_message('{"type": "control", "pitch": [-40]}', controls, ranges=ranges)
    assert ok == {"type": "control", "pitch": [-40.0]}
    assert protocol.parse_message('{"type": "control", "speed_scale": [2.0], "pitch": [0]}', controls,
                                  ranges=ranges)["speed_scale"] == [2.0]
    for bad in ('{"type": "control", "pitch": [31]}', '{"type": "control", "speed_scale": [-0.95]}',
                '{"type": "control", "speed_scale": [0.5], "pitch": [-41]}'):
        with pytest.raises(protocol.MessageError, match="outside"):
            protocol.parse_message(bad, controls, ranges=ranges)
