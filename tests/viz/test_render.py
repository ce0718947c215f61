"""corpuscle render: rasterizer pixels and colours, scenes, outputs and bad input."""

from __future__ import annotations

import argparse
import math
from types import SimpleNamespace

import numpy as np
import pytest

from corpuscle import _colors, _render, render
from corpuscle.render import FrameRenderer, LiveRender, RenderError, render_run

import viz_runs

BLACK, WHITE = (0, 0, 0), (255, 255, 255)
HEAT_STOPS = [(0, 0, 0), (0, 0, 255), (0, 255, 255), (0, 255, 0), (255, 255, 0), (255, 0, 0), (255, 255, 255)]


def frame_of(positions, dim=None, t=0.0, step=0, rigid=None, **fields):
    """A frame-like object (the attributes FrameRenderer reads)."""
    f = {"position": np.asarray(positions, np.float32)}
    f.update({k: np.asarray(v, np.float32) for k, v in fields.items()})
    return SimpleNamespace(fields=f, groups={}, rigid=rigid or {}, time=t, step=step, index=0, diagnostics={})


def shade_reference(base, nx, ny, nz):
    """NumPy float64 reference of raster.h ``shade`` (Lambert + Blinn-Phong^16 key light)."""
    light = np.array([-0.42, 0.56, 0.71])
    half = np.array([-0.22, 0.29, 0.93])
    n = np.array([nx, ny, nz])
    d = max(n @ light, 0.0)
    s = max(n @ half, 0.0) ** 16
    v = np.asarray(base, float) * (0.32 + 0.68 * d) + 255 * 0.28 * s
    return np.floor(np.minimum(v, 255) + 0.5).astype(np.uint8)


def tunnel_renderer(**kw):
    """A 400x200 2-D renderer of the test channel, no overlay or colour bar."""
    kw.setdefault("overlay", False)
    kw.setdefault("colorbar", False)
    return FrameRenderer(viz_runs.tunnel_header() | {"particle_radius": 0.02}, size=(400, 200), **kw)


# ---- colour ramps ---------------------------------------------------------------------------


def test_heat_ramp_has_the_seven_seed_stops_in_order():
    lut = _colors.make_lut("heat", 6 * 64 + 1)
    for k, stop in enumerate(HEAT_STOPS):
        np.testing.assert_allclose(lut[min(k * 64, len(lut) - 1)], stop, atol=4)


def test_colour_mapping_is_log_of_p_plus_one_for_pressure():
    lut = _colors.make_lut("heat")
    p = np.array([0.0, math.e - 1, math.e ** 2 - 1])
    # log(p+1) = 0, 1, 2 over the range 0..2: the bottom, middle and top of the ramp
    cols = _colors.map_values(p, lut, 0.0, 2.0, log=True)
    assert tuple(cols[0]) == BLACK and tuple(cols[2]) == WHITE
    np.testing.assert_array_equal(cols[1], lut[128])


# ---- the compiled rasterizer ------------------------------------------------------------------


def test_flat_disc_covers_exactly_the_pixel_centres_inside_its_radius():
    img = np.zeros((20, 30, 3), np.uint8)
    cam = np.array([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 1, 0, 20], np.float32)  # ortho, 1 px per unit, y up
    pos = np.array([[10.0, 10.0]], np.float32)  # screen (10, 10)
    red = np.array([255, 0, 0], np.uint8)
    n = _render.splat(img, None, pos, None, cam, True, 3.0, 0.75, None, 0, 1, 0, red, red, False, False)
    assert n == 1
    ys, xs = np.nonzero(img[..., 0])
    d2 = (xs + 0.5 - 10) ** 2 + (ys + 0.5 - 10) ** 2
    assert d2.max() <= 9.0
    # every pixel centre within the radius is covered
    yy, xx = np.mgrid[0:20, 0:30]
    inside = (xx + 0.5 - 10) ** 2 + (yy + 0.5 - 10) ** 2 <= 9.0
    np.testing.assert_array_equal(img[..., 0] == 255, inside)


def test_tiny_particles_still_light_a_pixel():
    cam = np.array([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 1, 0, 10], np.float32)
    white = np.array([255, 255, 255], np.uint8)
    for p in ([2.3, 7.9], [6.51, 3.49], [5.0, 5.0], [0.02, 9.97]):
        img = np.zeros((10, 10, 3), np.uint8)
        _render.splat(img, None, np.array([p], np.float32), None, cam, True, 1e-4, 0.75, None, 0, 1, 0, white, white,
                      False, False)
        ys, xs = np.nonzero(img[..., 0])
        assert 1 <= len(xs) <= 4
        assert np.all(np.hypot(xs + 0.5 - p[0], ys + 0.5 - (10 - p[1])) <= 0.75)


def test_sphere_shading_matches_the_reference_and_the_nearer_particle_wins():
    h = w = 64
    lut = _colors.make_lut("heat")
    # orthographic camera looking down -z at the origin (forward = -z), 100 px per unit
    cam = np.array([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, -1, 5, 100, 32, 32], np.float32)
    for order in ((0, 1), (1, 0)):
        img = np.zeros((h, w, 3), np.uint8)
        depth = np.full((h, w), np.inf, np.float32)
        pos = np.array([[0, 0, 1.0], [0, 0, 0.0]], np.float32)[list(order)]  # z=1 is nearer
        val = np.array([[1.0], [0.0]], np.float32)[list(order)]
        _render.splat(img, depth, pos, val, cam, True, 0.1, 0.75, lut, 0.0, 1.0, 0,
                      np.zeros(3, np.uint8), np.zeros(3, np.uint8), True, True)
        # pixel (32, 32) has its centre 0.5 px off the sphere's axis
        nx, ny = 0.5 / 10, -0.5 / 10
        expect = shade_reference(lut[-1], nx, ny, math.sqrt(1 - nx * nx - ny * ny))
        np.testing.assert_allclose(img[32, 32], expect, atol=1)
        assert depth[32, 32] == pytest.approx(4.0 - 0.1 * math.sqrt(1 - nx * nx - ny * ny), abs=1e-5)


def test_projection_in_python_matches_the_rasterizer():
    r = FrameRenderer(viz_runs.magic8ball_header(), size=(320, 240), overlay=False, colorbar=False, color="none")
    pts = np.array([[0.05, -0.03, 0.02], [-0.1, 0.04, -0.06], [0.0, 0.0, 0.0]])
    empty = r.render(frame_of(np.zeros((0, 3))))
    for p in pts:
        img = r.render(frame_of(p[None]))
        diff = np.any(img != empty, axis=2)
        ys, xs = np.nonzero(diff)
        x, y = r.camera.project(p[None])[0, :2]
        assert abs(xs.mean() + 0.5 - x) < 0.6 and abs(ys.mean() + 0.5 - y) < 0.6


# ---- 2-D scenes ------------------------------------------------------------------------------


def test_2d_particles_land_on_the_expected_pixels_with_the_ramp_colour():
    r = tunnel_renderer(value_range="0:10", log=False)
    pos = np.array([[1.0, 0.5 + 0.3], [0.2, 0.2], [1.8, 0.9]])
    p = np.array([2.5, 0.0, 10.0])
    img = r.render(frame_of(pos, pressure=p))
    # channel [0,2]x[0,1] fitted into 400x200 with a 4 % margin: 184 px per metre, centred
    assert r.camera.focal == pytest.approx(184.0)
    px = 200 + 184 * (pos[:, 0] - 1.0)
    py = 100 - 184 * (pos[:, 1] - 0.5)
    expect = _colors.map_values(p, _colors.make_lut("heat"), 0.0, 10.0, log=False)
    for k in range(3):
        np.testing.assert_array_equal(img[int(py[k]), int(px[k])], expect[k])


def test_2d_default_is_log_pressure_on_the_heat_ramp_with_airfoil_and_walls():
    r = tunnel_renderer(value_range=f"0:{math.e ** 2 - 1}")
    img = r.render(frame_of([[1.6, 0.2]], pressure=[math.e - 1]))
    assert r.field == "pressure" and r.log
    x, y = r.camera.project(np.array([[1.6, 0.2]]))[0, :2]
    np.testing.assert_array_equal(img[int(y), int(x)], _colors.make_lut("heat")[128])
    # the airfoil is filled: its centre has the obstacle colour
    x, y = r.camera.project(np.array([[0.8, 0.5]]))[0, :2]
    np.testing.assert_array_equal(img[int(y), int(x)], render.OBSTACLE_FILL)
    # the bottom wall is drawn: the wall row is brighter than the background
    x, y = r.camera.project(np.array([[1.0, 0.0]]))[0, :2]
    assert img[int(y), int(x)].mean() > 150 > r._background[int(y), int(x)].mean()


def test_default_colour_range_is_robust_percentiles():
    rng = np.random.default_rng(3)
    pos = rng.random((20000, 2)) * [2, 1]
    vals = rng.random(20000) * 100
    vals[:10] = 1e6  # a few extreme particles do not stretch the range
    r = tunnel_renderer(log=False)
    r.render(frame_of(pos, pressure=vals))
    lo, hi = r.color_range
    assert lo == pytest.approx(1.0, abs=0.5) and hi == pytest.approx(99.0, abs=0.5)


# ---- 3-D scenes ------------------------------------------------------------------------------


def die_frame(orientation=(1, 0, 0, 0)):
    return frame_of(np.array([[0.0, 0.0, -0.12]]), rigid={"die": {"position": np.zeros(3), "orientation": np.array(orientation, float)}})


def test_die_is_a_lit_cube_with_pips_on_the_face_toward_the_camera():
    hdr = viz_runs.magic8ball_header()
    half = hdr["bodies"][0]["half_extents"][0]
    six = [(a, b) for a in (-1, 1) for b in (-1, 0, 1)]
    # (camera azimuth, face normal, pips in face units, a bare spot): face 1 from +x, face 6 from -x
    for az, normal, pips, bare in ((0.0, [1.0, 0, 0], [(0, 0)], (1.0, 1.0)), (180.0, [-1.0, 0, 0], six, (0.0, 0.5))):
        r = FrameRenderer(hdr, size=(320, 240), camera=f"{az},8", overlay=False, colorbar=False, color="none")
        img = r.render(die_frame())
        normal = np.array(normal)
        u = np.array([0, 1.0, 0])
        v = np.cross(normal, u)
        on_face = lambda a, b: normal * half + 0.5 * half * (a * u + b * v)  # noqa: E731
        for a, b in pips:
            x, y = r.camera.project(on_face(a, b)[None])[0, :2]
            assert img[int(y), int(x)].max() < 60, f"pip ({a}, {b}) should be dark"
        # away from the pips the face is bright and neutral (ivory)
        x, y = r.camera.project(on_face(*bare)[None])[0, :2]
        c = img[int(y), int(x)].astype(int)
        assert c.min() > 120 and c.max() - c.min() < 40


def camera_light(r):
    """The key light in world space, from the camera's eye and target alone (docs/rendering.md):
    (-0.42, 0.56, 0.71) in a frame of screen right, screen up and toward the viewer."""
    toward = r.camera.eye - r.target
    toward /= np.linalg.norm(toward)
    right = np.cross(-toward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, -toward)
    # that frame is the screen's: right moves right on screen, up moves up (smaller row)
    c, x, y = r.camera.project(np.array([r.target, r.target + 0.01 * right, r.target + 0.01 * up]))[:, :2]
    assert x[0] > c[0] + 1 and abs(x[1] - c[1]) < 0.5 and y[1] < c[1] - 1 and abs(y[0] - c[0]) < 0.5
    return -0.42 * right + 0.56 * up + 0.71 * toward


def test_die_faces_are_shaded_by_their_angle_to_the_light():
    # from azimuth 45, elevation 30 the camera sees faces +x (1), +y (2) and +z (3); the light
    # from the upper left of the screen falls steeply on the top, obliquely on +x, not on +y
    r = FrameRenderer(viz_runs.magic8ball_header(), size=(640, 480), camera="45,30", overlay=False, colorbar=False,
                      color="none")
    img = r.render(die_frame())
    half = 0.032
    light = camera_light(r)
    seen = {}
    for axis in range(3):
        normal = np.eye(3)[axis]
        # a spot on the face clear of every pip layout: 0.75 half-sides out along its second axis
        spot = normal * half + 0.75 * half * np.eye(3)[max(a for a in range(3) if a != axis)]
        x, y = r.camera.project(spot[None])[0, :2]
        seen[axis] = img[int(y), int(x)].astype(int)
        # Lambert factor 0.38 + 0.62 max(0, n.L) on the ivory die colour
        expect = np.floor(np.array(render.DIE_RGB) * (0.38 + 0.62 * max(0.0, float(normal @ light))))
        np.testing.assert_allclose(seen[axis], expect, atol=1.5, err_msg=f"face normal {normal}")
    # the top is brightest, the +y face (facing away from the light) darkest
    assert seen[2].sum() > seen[0].sum() + 60 > seen[1].sum() + 120


def test_sphere_impostor_is_lit_from_the_upper_left_pixel_for_pixel():
    # one big grey sphere seen down -z (orthographic, 100 px per unit, radius 20 px)
    cam = np.array([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, -1, 5, 100, 32, 32], np.float32)
    img = np.zeros((64, 64, 3), np.uint8)
    depth = np.full((64, 64), np.inf, np.float32)
    grey = np.array([128, 128, 128], np.uint8)
    _render.splat(img, depth, np.zeros((1, 3), np.float32), None, cam, True, 0.2, 0.75, None, 0.0, 1.0, 0,
                  grey, grey, True, True)
    # every pixel well inside the disc matches the shading model for its surface normal
    yy, xx = np.mgrid[0:64, 0:64]
    nx, ny = (xx + 0.5 - 32) / 20, -(yy + 0.5 - 32) / 20
    inside = nx ** 2 + ny ** 2 < 0.9 ** 2
    expect = np.array([shade_reference(grey, a, b, math.sqrt(1 - a * a - b * b)) for a, b in zip(nx[inside], ny[inside])])
    np.testing.assert_allclose(img[inside].astype(int), expect.astype(int), atol=1)
    # so the upper-left half (toward the light) is brighter than the lower-right half
    lum = img.astype(int).sum(axis=2)
    upper_left = inside & (nx - ny < 0)
    assert lum[upper_left].mean() > lum[inside & (nx - ny > 0)].mean() + 100
    # and the highlight sits where the normal is the half vector (-0.22, 0.29, 0.93)
    peak = np.unravel_index(np.argmax(np.where(inside, lum, -1)), lum.shape)
    assert abs(peak[1] + 0.5 - (32 - 0.22 * 20)) <= 1.5 and abs(peak[0] + 0.5 - (32 - 0.29 * 20)) <= 1.5


def test_3d_container_outline_and_particles_are_drawn(tmp_path):
    viz_runs.write_magic8ball(tmp_path / "m8.cps", frames=2)
    out = tmp_path / "m8.png"
    res = render_run(tmp_path / "m8.cps", out, size=(320, 240), progress=False)
    assert res.frames == 1 and out.exists()
    from PIL import Image

    img = np.asarray(Image.open(out))
    # the sphere's outline: a ring of container-coloured pixels
    ring_pixels = np.all(np.abs(img.astype(int) - render.CONTAINER_RGB) < 60, axis=2)
    assert ring_pixels.sum() > 200


def test_ghosts_are_drawn_only_when_asked_as_small_grey_spheres():
    hdr = viz_runs.magic8ball_header()
    ghost = np.array([[0.09, -0.02, 0.06]])
    f = frame_of([[-0.05, 0.0, -0.05], [0.0, 0.05, -0.08]], ghost_position=ghost)
    f.groups = {"ghost_position": "ghost"}
    opts = dict(size=(200, 150), overlay=False, colorbar=False, color="none", cutaway=False)
    a = FrameRenderer(hdr, **opts).render(f)
    r = FrameRenderer(hdr, ghosts=True, **opts)
    b = r.render(f)
    # the only change is a disc around the ghost's projection, at most its radius (0.6 of a
    # particle's) plus a pixel of antialiasing away
    x, y = r.camera.project(ghost)[0, :2]
    radius_px = 0.6 * hdr["particle_radius"] * r.camera.focal / r.camera.view(ghost)[0, 2]
    ys, xs = np.nonzero(np.any(a != b, axis=2))
    assert len(xs) >= 0.5 * math.pi * radius_px ** 2
    assert np.hypot(xs + 0.5 - x, ys + 0.5 - y).max() <= radius_px + 1.5
    # its centre is the ghost grey (150, 150, 160) lit as a sphere: red = green, a little more
    # blue, between the darkest and the brightest shade of that grey; before, the background
    centre = b[int(y), int(x)].astype(int)
    lo, hi = shade_reference(render.GHOST_RGB, 0.0, -1.0, 0.0), shade_reference(render.GHOST_RGB, -0.22, 0.29, 0.93)
    assert abs(centre[0] - centre[1]) <= 2 and 0 <= centre[2] - centre[0] <= 14
    assert np.all(lo <= centre) and np.all(centre <= hi)
    np.testing.assert_array_equal(a[int(y), int(x)], r._background[int(y), int(x)])


def test_no_blank_frames(tmp_path):
    viz_runs.write_magic8ball(tmp_path / "m8.cps", frames=3)
    viz_runs.write_tunnel(tmp_path / "wt.cps", frames=3)
    import corpuscle

    for name in ("m8.cps", "wt.cps"):
        run = corpuscle.open(tmp_path / name)
        r = FrameRenderer(run.header, size=(200, 120), overlay=False, colorbar=False)
        for frame in run:
            img = r.render(frame)
            drawn = np.any(img != r._background, axis=2).mean()
            assert drawn > 0.05, f"{name} frame {frame.index}: only {drawn:.1%} of pixels drawn"


def test_overlay_text_changes_with_the_time_and_step_and_nothing_else():
    from corpuscle import _overlay

    hdr = viz_runs.magic8ball_header()
    pts = np.array([[0.0, 0.0, -0.05], [0.05, 0.02, -0.08]])
    early, late = frame_of(pts, t=0.125, step=10), frame_of(pts, t=0.5, step=40)
    r = FrameRenderer(hdr, size=(320, 240), colorbar=False, color="none")
    a, b = r.render(early), r.render(late)
    # the text reads differently, so its pixels differ ...
    changed = np.any(a != b, axis=2)
    assert changed.sum() > 30
    # ... only inside the text's box: the text at (10, 8), whose size the overlay font gives,
    # on a darkened backing 4 px wider and 3 px taller on each side
    h, w = _overlay.text_mask("magic8ball   t = 0.5000 s   step 40", max(11, round(240 / 40))).shape
    box = np.zeros_like(changed)
    box[8 - 3:8 + h + 3, 10 - 4:10 + w + 4] = True
    assert not np.any(changed & ~box)
    # outside the box the picture is the one without text; the same frame draws the same text
    plain = FrameRenderer(hdr, size=(320, 240), colorbar=False, overlay=False, color="none").render(early)
    np.testing.assert_array_equal(a[~box], plain[~box])
    assert np.any(a[box] != plain[box])
    np.testing.assert_array_equal(r.render(early), a)


# ---- outputs ---------------------------------------------------------------------------------


def test_mp4_decodes_to_the_expected_frames_and_size(tmp_path):
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
    viz_runs.write_magic8ball(tmp_path / "m8.cps", frames=6)
    out = tmp_path / "m8.mp4"
    res = render_run(tmp_path / "m8.cps", out, size=(160, 120), fps=10, frames="1:6", progress=False)
    assert res.frames == 5
    gen = imageio_ffmpeg.read_frames(str(out))
    meta = next(gen)
    frames = [np.frombuffer(b, np.uint8).reshape(120, 160, 3) for b in gen]
    assert meta["size"] == (160, 120) and len(frames) == 5
    assert meta["fps"] == pytest.approx(10)
    # the first decoded frame looks like frame 1 rendered directly (H.264 is lossy)
    import corpuscle

    run = corpuscle.open(tmp_path / "m8.cps")
    r = FrameRenderer(run.header, size=(160, 120), sample_frames=[run[i] for i in range(1, 6)])
    direct = r.render(run[1])
    assert np.abs(frames[0].astype(int) - direct.astype(int)).mean() < 6


def test_gif_png_and_png_directory(tmp_path):
    from PIL import Image

    viz_runs.write_tunnel(tmp_path / "wt.cps", frames=4)
    render_run(tmp_path / "wt.cps", tmp_path / "wt.gif", size=(120, 80), frames="::2", progress=False)
    with Image.open(tmp_path / "wt.gif") as g:
        assert g.n_frames == 2 and g.size == (120, 80)
    render_run(tmp_path / "wt.cps", tmp_path / "frames", size=(120, 80), progress=False)
    pngs = sorted((tmp_path / "frames").glob("frame_*.png"))
    assert [p.name for p in pngs] == [f"frame_{k:05d}.png" for k in range(4)]
    # a single .png is the last frame by default, pixel for pixel (with the same colour range)
    render_run(tmp_path / "wt.cps", tmp_path / "frames", size=(120, 80), value_range="0:20", progress=False)
    render_run(tmp_path / "wt.cps", tmp_path / "last.png", size=(120, 80), value_range="0:20", progress=False)
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "last.png")), np.asarray(Image.open(pngs[-1])))
    render_run(tmp_path / "wt.cps", tmp_path / "first.png", size=(120, 80), frame=0, value_range="0:20", progress=False)
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "first.png")), np.asarray(Image.open(pngs[0])))
    # frames 0 and 3 hold different particles, so their pictures differ in many pixels
    assert np.any(np.asarray(Image.open(pngs[0])) != np.asarray(Image.open(pngs[-1])), axis=2).sum() > 500
    # the GIF's frames are frames 0 and 2 (quantised to 255 colours: close, not equal)
    with Image.open(tmp_path / "wt.gif") as g:
        for k, want in ((0, 0), (1, 2)):
            g.seek(k)
            got = np.asarray(g.convert("RGB")).astype(int)
            ref = np.asarray(Image.open(pngs[want])).astype(int)
            assert np.abs(got - ref).mean() < 8


def test_live_render_hook_matches_offline_rendering(tmp_path):
    from PIL import Image

    import corpuscle

    viz_runs.write_magic8ball(tmp_path / "m8.cps", frames=3)
    run = corpuscle.open(tmp_path / "m8.cps")
    parser = argparse.ArgumentParser()
    render.add_live_render_arguments(parser)
    args = parser.parse_args(["--render", str(tmp_path / "live"), "--render-size", "160x120",
                              "--render-range", "0:0.3", "--render-color", "speed"])
    assert render.LiveRender.from_args(parser.parse_args([]), run.header) is None
    with LiveRender.from_args(args, run.header) as live:
        for frame in run:
            live.add_frame(frame)
    render_run(run, tmp_path / "offline", size=(160, 120), color="speed", value_range="0:0.3", progress=False)
    for k in range(3):
        a = np.asarray(Image.open(tmp_path / "live" / f"frame_{k:05d}.png"))
        b = np.asarray(Image.open(tmp_path / "offline" / f"frame_{k:05d}.png"))
        np.testing.assert_array_equal(a, b)


# ---- bad input -------------------------------------------------------------------------------


# the command line's bad input is tested through the console script: test_viz_console.py


def test_errors_are_value_errors_for_the_cli_table():
    assert issubclass(RenderError, ValueError)
    with pytest.raises(RenderError, match="lo < hi"):
        render.parse_range("3:3")


def test_cutaway_shows_a_die_buried_in_fluid():
    hdr = viz_runs.magic8ball_header()
    # a dense ball of particles all around the die
    g = np.linspace(-0.13, 0.13, 27)
    pts = np.stack(np.meshgrid(g, g, g), -1).reshape(-1, 3)
    pts = pts[np.linalg.norm(pts, axis=1) < 0.14]
    f = frame_of(pts, rigid={"die": {"position": np.zeros(3), "orientation": np.array([1.0, 0, 0, 0])}})
    opts = dict(size=(240, 180), camera="0,8", overlay=False, colorbar=False, color="none")
    cut = FrameRenderer(hdr, **opts).render(f)
    full = FrameRenderer(hdr, cutaway=False, **opts).render(f)
    r = FrameRenderer(hdr, **opts)
    r.render(f)
    x, y = r.camera.project(np.array([[0.032, 0.016, 0.016]]))[0, :2]  # on face 1, off its pip
    ivory = lambda c: c.min() > 120 and int(c.max()) - int(c.min()) < 40  # noqa: E731
    assert ivory(cut[int(y), int(x)]) and not ivory(full[int(y), int(x)])


def test_live_render_takes_a_simulation_style_frame_dict(tmp_path):
    from PIL import Image

    hdr = viz_runs.magic8ball_header()
    rec = {"fields": {"position": np.zeros((5, 3), np.float32), "density": np.full(5, 1000.0, np.float32)},
           "groups": {"position": "fluid", "density": "fluid"},
           "rigid": {"die": {"position": np.zeros(3), "orientation": np.array([1.0, 0, 0, 0])}},
           "diagnostics": {"kinetic_energy": 0.0}}
    with LiveRender(tmp_path / "live.png", hdr, size=(64, 48)) as live:
        live.add_frame(SimpleNamespace(**rec, time=0.25, step=7))
    assert Image.open(tmp_path / "live.png").size == (64, 48)


def test_2d_rigid_body_with_an_angle_is_drawn_rotated():
    hdr = viz_runs.tunnel_header() | {"bodies": [{"name": "plate", "shape": "box", "half_extents": [0.2, 0.02]}]}
    r = FrameRenderer(hdr, size=(400, 200), overlay=False, colorbar=False, color="none")
    plate = {"position": np.array([1.5, 0.5]), "orientation": np.array([math.pi / 2])}
    img = r.render(frame_of(np.array([[0.1, 0.1]]), rigid={"plate": plate}))
    # turned a quarter: it now reaches 0.15 m up and only 0.02 m sideways
    up = r.camera.project(np.array([[1.5, 0.65]]))[0, :2]
    side = r.camera.project(np.array([[1.65, 0.5]]))[0, :2]
    np.testing.assert_array_equal(img[int(up[1]), int(up[0])], render.DIE_RGB)
    assert not np.array_equal(img[int(side[1]), int(side[0])], render.DIE_RGB)


# ---- rendering while recording equals rendering afterwards ---------------------------------------


def test_live_render_of_corpuscle_run_equals_offline_render_pixel_for_pixel(tmp_path):
    # `corpuscle run --render` draws each frame from the record it writes, with the same
    # renderer as `corpuscle render` reading the file back; the float32 fields are stored
    # bit for bit, so with a fixed colour range (without one, the live range widens as
    # frames come while the offline one samples the whole run) the pictures are identical
    pytest.importorskip("corpuscle._core")
    from PIL import Image

    from cli_script import corpuscle

    run = tmp_path / "run.cps"
    proc = corpuscle("run", "magic8ball", "--particles", "300", "--steps", "20", "--every", "10", "--velocity",
                     "--no-progress", "--out", run, "--render", tmp_path / "live", "--render-size", "160x120",
                     "--render-range", "0:0.5", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = corpuscle("render", run, "-o", tmp_path / "offline", "--size", "160x120", "--range", "0:0.5", "-q")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    names = sorted(p.name for p in (tmp_path / "live").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "offline").iterdir()) == [f"frame_{k:05d}.png" for k in range(3)]
    for name in names:
        live = np.asarray(Image.open(tmp_path / "live" / name))
        offline = np.asarray(Image.open(tmp_path / "offline" / name))
        np.testing.assert_array_equal(live, offline)
        assert np.any(live != live[0, 0], axis=2).mean() > 0.05  # and they are not blank


# ---- failed renders leave no partial output ------------------------------------------------------


@pytest.fixture
def damaged(tmp_path):
    """A 20-frame run whose frame 8 fails its checksum, and an empty output folder. (Frame 8 is
    not among the 12 frames render_run samples for its colour range, so a render without a
    range still gets through frames 0-7 before it meets it.)"""
    from cli_script import corrupt_frame

    run = tmp_path / "runs" / "m8.cps"
    run.parent.mkdir()
    viz_runs.write_magic8ball(run, frames=20, n=200)
    corrupt_frame(run, 8)
    (tmp_path / "work").mkdir()
    return run, tmp_path / "work"


@pytest.mark.parametrize("out", ["m8.mp4", "m8.gif", "frames", "new/frames"])
def test_render_failing_part_way_leaves_no_partial_output(damaged, out):
    from cli_script import listing
    from corpuscle.io import FrameStreamError

    run, work = damaged
    if out == "m8.mp4":
        pytest.importorskip("imageio_ffmpeg")
    # frames 0-7 are drawn and encoded, then frame 8 raises
    with pytest.raises(FrameStreamError, match="frame 8 is corrupted"):
        render_run(run, work / out, size=(64, 48), value_range=None if out == "m8.gif" else "0:1", progress=False)
    assert listing(work) == set()


def test_render_whose_encoder_fails_part_way_leaves_no_partial_output(damaged, monkeypatch):
    from cli_script import listing
    from corpuscle import _video

    run, work = damaged
    real = _video.PngDirSink._add

    def fill_the_disk(self, image):
        if self.frames == 2:
            raise OSError(28, "No space left on device")
        real(self, image)

    monkeypatch.setattr(_video.PngDirSink, "_add", fill_the_disk)
    (work / "frames").mkdir()
    (work / "frames" / "notes.txt").write_text("mine")
    with pytest.raises(RenderError, match="cannot write .*frames: No space left on device"):
        render_run(run, work / "frames", size=(64, 48), value_range="0:1", frames="0:3", progress=False)
    # the frames written before are gone; what was in the folder stays
    assert listing(work) == {"frames", "frames/notes.txt"}


def test_png_whose_save_fails_leaves_nothing_and_keeps_the_old_file(damaged, monkeypatch):
    from PIL import Image

    from cli_script import listing

    run, work = damaged
    render_run(run, work / "m8.png", size=(64, 48), frame=0, progress=False)
    old = (work / "m8.png").read_bytes()

    def half_written(self, fp, *args, **kwargs):
        with open(fp, "wb") as f:
            f.write(b"\x89PNG\r\n\x1a\n half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Image.Image, "save", half_written)
    with pytest.raises(RenderError, match="No space left on device"):
        render_run(run, work / "m8.png", size=(64, 48), frame=1, progress=False)
    assert listing(work) == {"m8.png"} and (work / "m8.png").read_bytes() == old


def test_live_render_left_by_an_exception_leaves_nothing(damaged):
    import corpuscle
    from cli_script import listing

    run, work = damaged
    frames = corpuscle.open(run)
    with pytest.raises(RuntimeError, match="simulation blew up"):
        with LiveRender(work / "live.gif", frames.header, size=(64, 48), value_range="0:1") as live:
            live.add_frame(frames[0])
            live.add_frame(frames[1])
            raise RuntimeError("simulation blew up")
    assert listing(work) == set()
    # closed normally, the output appears, with every frame, and only then
    with LiveRender(work / "live", frames.header, size=(64, 48), value_range="0:1") as live:
        for k in range(3):
            live.add_frame(frames[k])
            assert not list((work / "live").glob("frame_*.png"))
    assert listing(work) == {"live"} | {f"live/frame_{k:05d}.png" for k in range(3)}


def test_an_obstacle_is_drawn_turned_by_its_frames_diagnostic():
    from corpuscle._viz_common import turned_points

    ob = {"type": "polygon", "points": [[1.0, 0.0], [2.0, 0.0], [2.0, 1.0]],
          "turn": {"diagnostic": "pitch", "about": [1.0, 0.0], "sign": -1.0}}
    same = turned_points(ob, {"pitch": 0.0})
    assert np.array_equal(same, ob["points"]) and np.array_equal(turned_points(ob, {}), ob["points"])
    t = turned_points(ob, {"pitch": 90.0})  # a quarter turn clockwise about (1, 0)
    assert np.allclose(t, [[1.0, 0.0], [1.0, -1.0], [2.0, -1.0]])
    assert np.array_equal(turned_points(ob, {"pitch": float("nan")}), ob["points"])
    assert turned_points({"type": "box", "min": [0, 0, 0], "max": [1, 1, 1]}, {"pitch": 1.0}) is None
    bad = dict(ob, turn={"diagnostic": "pitch", "about": "here"})
    assert np.array_equal(turned_points(bad, {"pitch": 5.0}), ob["points"])
