"""render/plot/export read the run header's scene description (docs/frame_format.md, "Run
header") and guess nothing from the scene's parameters: containers, bodies and their faces,
obstacles (polygons and boxes), units and gravity."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from corpuscle import render
from corpuscle._viz_common import HeaderError, scene_info, units_of
from corpuscle.export import frame_parts, static_parts
from corpuscle.render import FrameRenderer

import viz_runs

IDENTITY = np.array([1.0, 0, 0, 0])


def frame_of(positions, rigid=None):
    return SimpleNamespace(fields={"position": np.asarray(positions, np.float32)}, groups={}, rigid=rigid or {},
                           time=0.0, step=0, index=0, diagnostics={}, dt=1e-3)


def test_a_header_with_only_parameters_describes_no_geometry():
    # the 8-ball's parameters hold a container radius and a die side: neither is turned
    # into geometry (every recorded run's header has its own container and bodies)
    hdr = {"scene": "old", "kind": "magic8ball",
           "parameters": {"scene": {"kind": "magic8ball"}, "container": {"radius": 0.15}, "die": {"side": 0.064},
                          "gravity": {"g": [0.0, 0.0, -9.81]}}}
    info = scene_info(hdr)
    assert info["container"] is None and info["bodies"] == [] and info["obstacles"] == []
    assert info["gravity"] == [0.0, 0.0, -9.81]  # gravity still read from the parameters of old runs
    # and the real header shape gives them
    info = scene_info(viz_runs.magic8ball_header())
    assert info["container"]["radius"] == 0.15 and info["bodies"][0]["faces"]["3"] == [0.0, 0.0, 1.0]


def test_pips_are_drawn_only_for_faces_the_header_gives():
    # a box body named "die" without faces is a plain box: nothing is guessed from its name
    with_faces = viz_runs.magic8ball_header()
    plain = dict(with_faces, bodies=[{k: v for k, v in with_faces["bodies"][0].items() if k != "faces"}])
    renamed = dict(plain, bodies=[dict(plain["bodies"][0], name="cube")])
    opts = dict(size=(240, 180), camera="0,8", overlay=False, colorbar=False, color="none", cutaway=False)
    pts = np.array([[0.0, 0.0, -0.12]])
    die = frame_of(pts, {"die": {"position": np.zeros(3), "orientation": IDENTITY}})
    cube = frame_of(pts, {"cube": {"position": np.zeros(3), "orientation": IDENTITY}})
    a = FrameRenderer(with_faces, **opts).render(die)
    b = FrameRenderer(plain, **opts).render(die)
    c = FrameRenderer(renamed, **opts).render(cube)
    assert np.array_equal(b, c)  # the name changes nothing
    r = FrameRenderer(with_faces, **opts)
    r.render(die)
    x, y = r.camera.project(np.array([[0.032, 0.0, 0.0]]))[0, :2]  # face 1's single pip, toward the camera
    assert a[int(y), int(x)].max() < 60 and b[int(y), int(x)].min() > 120


def test_units_come_from_the_header():
    hdr = {"units": {"pressure": "N/m", "lift": "N"}}
    assert units_of("pressure", hdr) == "N/m" and units_of("lift", hdr) == "N"
    assert units_of("density", hdr) == "kg/m³"  # not in the header: the readers' table
    assert units_of("pressure", {}) == "Pa" and units_of("pressure") == "Pa"
    # no guess from the kind's or the scene's name any more
    assert units_of("pressure", {"kind": "wind_tunnel", "scene": "dem_gas"}) == "Pa"
    assert units_of("nosuch", {"units": {"nosuch": 3}}) == ""


def test_header_gravity_sets_the_up_axis_before_the_parameters():
    hdr = viz_runs.magic8ball_header() | {"gravity": [0.0, -9.81, 0.0]}
    assert render.up_axis(scene_info(hdr)) == "+y"
    assert render.up_axis(scene_info(viz_runs.magic8ball_header())) == "+z"  # parameters' gravity.g


def test_2d_box_obstacle_is_a_filled_rectangle_and_an_exported_polygon():
    hdr = viz_runs.tunnel_header() | {"obstacles": [{"type": "box", "name": "step", "min": [0.5, 0.0],
                                                     "max": [0.9, 0.3]}]}
    ob = scene_info(hdr)["obstacles"][0]
    assert ob["points"] == [[0.5, 0.0], [0.9, 0.0], [0.9, 0.3], [0.5, 0.3]]
    r = FrameRenderer(hdr, size=(400, 200), overlay=False, colorbar=False, color="none")
    img = r.render(frame_of([[1.8, 0.9]]))
    x, y = r.camera.project(np.array([[0.7, 0.15]]))[0, :2]
    np.testing.assert_array_equal(img[int(y), int(x)], render.OBSTACLE_FILL)
    x, y = r.camera.project(np.array([[1.2, 0.15]]))[0, :2]
    assert not np.array_equal(img[int(y), int(x)], render.OBSTACLE_FILL)
    (part,) = static_parts(hdr)
    assert part.name == "obstacle_step" and len(part.points) == 4 and list(part.types) == [7]  # VTK_POLYGON


def test_3d_box_obstacle_is_drawn_and_exported_as_six_faces():
    hdr = {"scene": "box", "kind": "dam", "dim": 3, "container": {"type": "box", "min": [0, 0, 0], "max": [1, 1, 1]},
           "obstacles": [{"type": "box", "name": "block", "min": [0.4, 0.4, 0.0], "max": [0.6, 0.6, 0.3]}],
           "particle_radius": 0.01}
    opts = dict(size=(240, 180), camera="30,20", overlay=False, colorbar=False, color="none")
    r = FrameRenderer(hdr, **opts)
    img = r.render(frame_of([[0.1, 0.1, 0.1]]))
    bare = FrameRenderer(dict(hdr, obstacles=[]), **opts).render(frame_of([[0.1, 0.1, 0.1]]))
    x, y = r.camera.project(np.array([[0.5, 0.5, 0.3]]))[0, :2]  # the block's top
    assert not np.array_equal(img[int(y), int(x)], bare[int(y), int(x)])
    (part,) = static_parts(hdr)
    assert part.name == "obstacle_block" and len(part.types) == 6 and len(part.points) == 8
    np.testing.assert_allclose(part.points.min(axis=0), [0.4, 0.4, 0.0])
    np.testing.assert_allclose(part.points.max(axis=0), [0.6, 0.6, 0.3])
    # the particles' part is unaffected
    assert [p.name for p in frame_parts(frame_of([[0.1, 0.1, 0.1]]), hdr)] == ["particles"]


@pytest.mark.parametrize("ob, needle", [
    ({"type": "box", "min": [0, 0], "max": [1, 1, 1]}, "obstacles[0] min must not exceed max"),
    ({"type": "box", "min": [0, 0], "max": [1]}, "obstacles[0].max must be a list of 2..3 numbers, got [1]"),
    ({"type": "box", "min": [0, 2], "max": [1, 1]}, "obstacles[0] min must not exceed max"),
    ({"type": "box", "min": "low", "max": [1, 1]}, "obstacles[0].min must be a list of 2..3 numbers"),
])
def test_bad_box_obstacle_is_one_line(ob, needle):
    with pytest.raises(HeaderError) as e:
        scene_info({"obstacles": [ob]})
    assert needle in str(e.value) and "\n" not in str(e.value)
