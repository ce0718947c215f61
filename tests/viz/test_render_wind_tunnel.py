"""How render and the live viewer colour a wind-tunnel run by default: the kind's header asks for
the number density on a fixed range from the free stream's (0 to 4 N / free area; the seed's
pressure is zero for nearly every particle of the stream, black on black), the renderer and
the viewer take it when the field was recorded and the user gave no other, and fall back to
their generic defaults otherwise."""

from __future__ import annotations

import types

import numpy as np
import pytest

from corpuscle import Simulation, _colors
from corpuscle.kinds import wind_tunnel as wt
from corpuscle.scene import load_scene

render = pytest.importorskip("corpuscle.render")


@pytest.fixture(scope="module")
def sim():
    return Simulation.from_scene(load_scene("wind-tunnel"), backend="serial", particles=3000)


def frame(sim, density=None, fields=("position", "pressure", "number_density")):
    n = sim.n_particles
    all_fields = {"position": np.ascontiguousarray(sim.positions, dtype=np.float32),
                  "pressure": np.zeros(n, np.float32),
                  "number_density": np.full(n, density if density is not None else 0.0, np.float32),
                  "velocity": np.ascontiguousarray(sim.velocities, dtype=np.float32)}
    return types.SimpleNamespace(fields={k: all_fields[k] for k in fields}, groups={}, rigid={}, time=0.0, step=0,
                                 index=0, diagnostics={})


def test_the_header_asks_for_number_density_over_the_free_streams(sim):
    h = sim.header()["render"]
    n0 = sim.n_particles / sim.info["free_area"]
    assert h["color"] == "number_density" and h["log"] is False and h["ramp"] == "heat"
    assert h["range"] == [0.0, pytest.approx(wt.RENDER_DENSITY_SPAN * n0, rel=1e-12)]
    assert h["free_stream_density"] == pytest.approx(n0, rel=1e-12)


def test_renderer_takes_the_kinds_colouring(sim):
    header = sim.header()
    n0 = header["render"]["free_stream_density"]
    r = render.FrameRenderer(header, size=(320, 180), overlay=False, colorbar=False)
    img = r.render(frame(sim, density=n0))
    assert r.field == "number_density" and r.log is False
    lo, hi = r.color_range
    assert lo == 0.0 and hi == pytest.approx(4 * n0, rel=1e-6)
    # a particle of the free stream's density is drawn a quarter up the heat ramp, not black
    want = _colors.map_values(np.array([n0]), _colors.make_lut("heat"), 0.0, 4 * n0, False)[0]
    assert want.max() > 100
    colours, counts = np.unique(img.reshape(-1, 3), axis=0, return_counts=True)
    top = [tuple(c) for c in colours[np.argsort(counts)[::-1][:3]]]
    assert tuple(want) in top


def test_the_range_is_fixed_not_the_frames_percentiles(sim):
    header = sim.header()
    n0 = header["render"]["free_stream_density"]
    r = render.FrameRenderer(header, size=(160, 90), overlay=False, colorbar=False)
    r.render(frame(sim, density=0.1 * n0))
    r.render(frame(sim, density=20 * n0))
    assert r.color_range[1] == pytest.approx(4 * n0, rel=1e-6)


def test_the_users_choice_wins(sim):
    header = sim.header()
    r = render.FrameRenderer(header, size=(160, 90), color="pressure", overlay=False, colorbar=False)
    r.render(frame(sim))
    assert r.field == "pressure" and r.log is True  # the generic 2-D pressure default
    r = render.FrameRenderer(header, size=(160, 90), value_range=(0, 10), log=True, ramp="gray", overlay=False,
                             colorbar=False)
    r.render(frame(sim))
    assert r.field == "number_density" and r.color_range == pytest.approx((0, 10)) and r.log is True


def test_without_the_field_or_the_hint_the_generic_defaults(sim):
    header = sim.header()
    r = render.FrameRenderer(header, size=(160, 90), overlay=False, colorbar=False)
    r.render(frame(sim, fields=("position", "pressure")))  # number density not recorded
    assert r.field == "pressure" and r.log is True
    old = {k: v for k, v in header.items() if k != "render"}  # a run recorded before the hint
    r = render.FrameRenderer(old, size=(160, 90), overlay=False, colorbar=False)
    r.render(frame(sim))
    assert r.field == "pressure"
    bad = dict(header, render={"color": "number_density", "range": [5, 1], "log": "yes"})
    r = render.FrameRenderer(bad, size=(160, 90), overlay=False, colorbar=False)
    r.render(frame(sim, density=3.0))
    assert r.field == "number_density" and r.log is False  # a malformed range or log is ignored


def test_live_viewer_colours_by_the_kinds_field_on_its_range(sim):
    server = pytest.importorskip("corpuscle.live.server")
    from corpuscle.live import protocol

    header = sim.header()
    assert server.default_color(header, ["pressure", "number_density"]) == "number_density"
    assert server.default_color({}, ["pressure", "density"]) == "density"
    assert server.default_color(header, ["pressure"]) == "pressure"
    n0 = header["render"]["free_stream_density"]
    f = frame(sim, density=n0)
    msg = server.encode({"positions": f.fields["position"], "fields": {"number_density": f.fields["number_density"]}},
                        header, "number_density")
    got = protocol.decode_frame(msg)
    assert got["meta"]["color"]["range"] == pytest.approx([0.0, 4 * n0])
    assert np.all(got["color"] == 63)  # a quarter of 255


def test_tick_labels_fit_the_colour_bar():
    from corpuscle._overlay import format_tick

    assert format_tick(73868.9) == "7.39e+04" and format_tick(36934.45) == "3.69e+04"
    assert format_tick(1234.5) == "1234" and format_tick(0.0) == "0" and format_tick(2.5e-5) == "2.50e-05"
    assert all(len(format_tick(v)) <= 8 for v in (9999.4, 1e4, 5.5e5, 0.00123, 1.0, 123.456))
