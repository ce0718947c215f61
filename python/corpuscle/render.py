"""``corpuscle render``: pictures and videos of recorded runs.

2-D scenes are drawn as a heat map of a per-particle value (by default pressure on the seed's
7-stop ramp over log(p+1)) with the obstacles filled and the walls drawn; 3-D scenes as lit
sphere impostors with a depth buffer, the container outlined and rigid bodies as lit meshes
(the die with its pips). The rasterizer is the compiled ``corpuscle._render`` module.

Python API::

    render_run("run.cps", "run.mp4", size=(1280, 720), fps=30, color="speed")

    with LiveRender("run.mp4", header, fps=30) as live:     # while a run records
        for frame in frames:
            live.add_frame(frame)

    img = FrameRenderer(header).render(frame)                # one (H, W, 3) uint8 picture
"""

from __future__ import annotations

import argparse
import math
import os
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from . import _camera, _colors, _overlay
from ._video import VideoSink, open_sink, output_kind
from ._errors import write_failure
from ._viz_common import (os_reason, cli_warnings, open_run, parse_frames, parse_index, parse_size, render_hint,
                          require, scene_info, turned_points, units_of)


class RenderError(ValueError):
    """Bad input to ``corpuscle render`` (one-line message)."""


# ---- look ----------------------------------------------------------------------------------

# background gradients (top, bottom) for 2-D and 3-D frames
BACKGROUND_2D = ((44, 48, 58), (44, 48, 58))
BACKGROUND_3D = ((58, 64, 78), (16, 18, 24))
# outline colours: container, walls, obstacles
CONTAINER_RGB = (200, 212, 228)
WALL_RGB = (214, 218, 228)
OBSTACLE_FILL = (150, 156, 168)
OBSTACLE_EDGE = (236, 238, 242)
GHOST_RGB = (150, 150, 160)
DIE_RGB = (238, 233, 220)
PIP_RGB = (26, 26, 32)
# smallest particle disc in pixels: every particle covers at least its nearest pixel centre
MIN_RADIUS_PX = 0.75
# percentiles used for the default colour range (robust to a few extreme particles)
ROBUST_PERCENTILES = (1.0, 99.0)
# pip layouts on a face, in units of the pip spacing, for 1..6
PIPS = {
    1: [(0, 0)],
    2: [(-1, -1), (1, 1)],
    3: [(-1, -1), (0, 0), (1, 1)],
    4: [(-1, -1), (-1, 1), (1, -1), (1, 1)],
    5: [(-1, -1), (-1, 1), (0, 0), (1, -1), (1, 1)],
    6: [(-1, -1), (-1, 0), (-1, 1), (1, -1), (1, 0), (1, 1)],
}
# key light direction in camera space (+z toward the viewer), as in raster.h
LIGHT = np.array([-0.42, 0.56, 0.71])


def _raster():
    """The compiled rasterizer, or a one-line error saying how to get it."""
    try:
        from . import _render
    except ImportError as exc:
        raise RenderError(f"the compiled renderer corpuscle._render is missing ({exc}); reinstall with: pip install .") from None
    return _render


# ---- option parsing ------------------------------------------------------------------------


def parse_range(spec: str | tuple[float, float] | None) -> tuple[float, float] | None:
    """``lo:hi`` -> (lo, hi) with finite lo < hi."""
    if spec is None:
        return None
    if isinstance(spec, str):
        m = re.fullmatch(r"\s*([^:]+?)\s*:\s*([^:]+?)\s*", spec)
        try:
            lo, hi = float(m.group(1)), float(m.group(2))  # type: ignore[union-attr]
        except (AttributeError, ValueError):
            raise RenderError(f"--range must be lo:hi with two numbers (e.g. 0:2000; use --range=-5:5 for negatives), got '{spec}'") from None
    else:
        try:
            lo, hi = (float(v) for v in spec)
        except (TypeError, ValueError):
            raise RenderError(f"range must be (lo, hi), got {spec!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise RenderError(f"--range bounds must be finite numbers, got {lo}:{hi}")
    if not lo < hi:
        raise RenderError(f"--range needs lo < hi, got {lo:g}:{hi:g}")
    return lo, hi


def parse_camera(spec: str | tuple | None) -> tuple[float, float, float | None] | None:
    """``AZ,EL[,DIST]`` (degrees, degrees, world units) -> (az, el, dist or None)."""
    if spec is None:
        return None
    parts = spec.replace(":", ",").split(",") if isinstance(spec, str) else list(spec)
    try:
        vals = [float(p) for p in parts]
    except (TypeError, ValueError):
        raise RenderError(f"--camera must be AZIMUTH,ELEVATION[,DISTANCE] in degrees and metres, got '{spec}'") from None
    if len(vals) not in (2, 3) or not all(math.isfinite(v) for v in vals):
        raise RenderError(f"--camera must be AZIMUTH,ELEVATION[,DISTANCE] in degrees and metres, got '{spec}'")
    if not -90.0 <= vals[1] <= 90.0:
        raise RenderError(f"--camera elevation must be within -90..90 degrees, got {vals[1]:g}")
    if len(vals) == 3 and vals[2] <= 0:
        raise RenderError(f"--camera distance must be positive, got {vals[2]:g}")
    return vals[0], vals[1], vals[2] if len(vals) == 3 else None


def parse_fps(fps: float | str) -> float:
    """Frames per second, in (0, 240]."""
    try:
        f = float(fps)
    except (TypeError, ValueError):
        raise RenderError(f"--fps must be a number, got '{fps}'") from None
    if not 0 < f <= 240:
        raise RenderError(f"--fps must be in (0, 240], got {f:g}")
    return f


# ---- scene description from the run header ----------------------------------------------------


def up_axis(info: dict) -> str:
    """World up axis ('+z', '-y', ...): the header's 'up', else opposite gravity, else +z."""
    up = info.get("up")
    if isinstance(up, str) and re.fullmatch(r"[+-]?[xyz]", up):
        return up if up[0] in "+-" else "+" + up
    g = info.get("gravity")
    if g is not None and any(g):
        k = int(np.argmax(np.abs(g)))
        return ("-" if g[k] > 0 else "+") + "xyz"[k]
    return "+z"


@dataclass
class _Scene:
    """What the header says about the scene's geometry."""

    dim: int
    container: dict | None
    obstacles: list
    bodies: dict
    radius: float | None
    name: str
    up: str


def _scene(header: dict, dim: int) -> _Scene:
    info = scene_info(header)
    bodies = {b.get("name", f"body{i}"): b for i, b in enumerate(info["bodies"])}
    return _Scene(dim, info["container"], info["obstacles"], bodies, info["particle_radius"], info["name"], up_axis(info))


def monotone_triangles(p2: np.ndarray) -> list[tuple[int, int, int]]:
    """Triangles (vertex index triples) covering a simple polygon that is monotone along its
    longest extent (an airfoil section along its chord: two chains from the vertex furthest
    one way to the vertex furthest the other), by zipping the two chains in order along that
    direction: each triangle joins the chains' current vertices and the next vertex of
    whichever chain comes first. A chain that is not monotone gives no triangles (the sides
    are still drawn)."""
    p = np.asarray(p2, dtype=np.float64)
    n = len(p)
    if n < 3:
        return []
    lo, hi = p.min(axis=0), p.max(axis=0)
    c = 0.5 * (lo + hi)
    # the direction of the longest extent: the pair of vertices furthest apart from the centre's two extremes
    far = int(np.argmax(((p - c) ** 2).sum(1)))
    other = int(np.argmax(((p - p[far]) ** 2).sum(1)))
    u = p[other] - p[far]
    if not np.any(u):
        return []
    t = p @ (u / np.linalg.norm(u))
    a, b = int(np.argmin(t)), int(np.argmax(t))
    chain1 = [(a + k) % n for k in range((b - a) % n + 1)]          # a -> b forwards
    chain2 = [(a - k) % n for k in range((a - b) % n + 1)]          # a -> b backwards
    for ch in (chain1, chain2):
        if np.any(np.diff(t[ch]) < 0):
            return []
    out = []
    i = j = 0
    while i < len(chain1) - 1 or j < len(chain2) - 1:
        if j == len(chain2) - 1 or (i < len(chain1) - 1 and t[chain1[i + 1]] <= t[chain2[j + 1]]):
            tri = (chain1[i], chain1[i + 1], chain2[j])
            i += 1
        else:
            tri = (chain1[i], chain2[j + 1], chain2[j])
            j += 1
        if len(set(tri)) == 3:
            out.append(tri)
    return out


def _field_label(name: str, header: dict) -> str:
    u = units_of(name, header)
    return f"{name} [{u}]" if u and u != "-" else name


# ---- the renderer ---------------------------------------------------------------------------


class FrameRenderer:
    """Turns frames of one run into pictures.

    ``header`` is the run header. Options: ``size`` (width, height) in pixels; ``color`` a
    per-particle field, ``"speed"`` or ``"none"`` (default: the kind's choice in the header's
    ``render`` entry when its field was recorded, e.g. the wind tunnel's number density over 0 to
    4 times the free stream's; else pressure in 2-D, speed or density in 3-D); ``value_range``
    (lo, hi) in field units (default: the kind's range for its field, else robust percentiles
    of ``sample_frames``, or of the frames seen so far, widened as needed); ``log`` colour on
    log(1+v) (default: the kind's, else on for 2-D pressure); ``ramp`` a name in
    ``_colors.RAMPS``;
    ``camera`` (azimuth, elevation[, distance]) for 3-D; ``ghosts`` draws ghost particles;
    ``cutaway`` leaves out the particles nearer the camera than the rigid bodies' centres (or
    than the scene centre without bodies) so a die inside the fluid shows (default: on in
    3-D scenes with a rigid body); ``overlay`` the time/step text; ``colorbar`` the colour bar.
    """

    def __init__(self, header: dict, *, size=(1280, 720), color: str | None = None, value_range=None,
                 log: bool | None = None, ramp: str | None = None, camera=None, ghosts: bool = False,
                 cutaway: bool | None = None, overlay: bool = True, colorbar: bool = True,
                 sample_frames: Iterable = ()):
        self.header = dict(header or {})
        self.size = parse_size(size, RenderError)
        self.color_request = color
        self.value_range = parse_range(value_range)
        self.log_request = log
        if ramp is not None and ramp not in _colors.RAMPS:
            raise RenderError(f"unknown --ramp '{ramp}': choose one of {', '.join(_colors.RAMPS)}")
        self.ramp_request = ramp
        self.camera_request = parse_camera(camera)
        self.ghosts = bool(ghosts)
        self.cutaway = cutaway
        self.overlay = bool(overlay)
        self.colorbar = bool(colorbar)
        self._samples = list(sample_frames)
        self._ready = False
        self._cap_cache: dict = {}  # an extruded obstacle's cap triangles (vertex indices)
        self._raster = _raster()
        if self.overlay or self.colorbar:
            require("PIL", "pillow", "frame text and colour bars", RenderError)

    # -- set-up on the first frame --

    def _setup(self, frame) -> None:
        fields = frame.fields
        if "position" not in fields:
            raise RenderError("frames have no 'position' field: nothing to draw")
        pos = fields["position"]
        dim = int(scene_info(self.header)["dim"] or (pos.shape[1] if pos.ndim == 2 else 3))
        if dim not in (2, 3):
            raise RenderError(f"can only render 2-D or 3-D scenes, got dim={dim}")
        self.dim = dim
        self.scene = _scene(self.header, dim)
        if dim == 2 and self.camera_request is not None:
            raise RenderError("--camera applies to 3-D scenes; this run is 2-D")
        self._resolve_color(frame)
        self.panel = _overlay.colorbar_width(self.size[1]) if self.colorbar and self.field is not None else 0
        self._choose_camera(frame)
        self._background = self._make_background()
        self._ready = True
        if self.field is not None and self.value_range is None and self._samples:
            self._grow_range(np.concatenate([self._sample_values(self._values(f)) for f in self._samples]))
        self._samples = []

    def _per_particle_fields(self, frame) -> dict[str, np.ndarray]:
        n = len(frame.fields["position"])
        groups = getattr(frame, "groups", {}) or {}
        return {k: v for k, v in frame.fields.items()
                if k != "position" and groups.get(k, "fluid") == "fluid" and v.ndim in (1, 2) and len(v) == n}

    def _resolve_color(self, frame) -> None:
        per = self._per_particle_fields(frame)
        req = self.color_request
        hint = render_hint(self.header)
        hinted = hint.get("color")
        if hinted is not None and not (hinted in per or (hinted == "speed" and "velocity" in per)):
            hint, hinted = {}, None  # the kind's field was not recorded: the generic defaults
        if req is None and hinted is not None:
            req = hinted  # the kind's choice (the wind tunnel: number density over the free stream's)
        if req is None:
            if self.dim == 2:
                req = "pressure" if "pressure" in per else ("speed" if "velocity" in per else "none")
            else:
                req = "speed" if "velocity" in per else ("density" if "density" in per else "none")
        if req in ("none", "uniform"):
            self.field = None
        elif req == "speed":
            if "velocity" not in per:
                raise RenderError(f"--color speed needs a recorded 'velocity' field; recorded: {', '.join(sorted(per)) or 'none'}")
            self.field = "speed"
        elif req in per:
            self.field = req
        elif req in frame.fields:
            raise RenderError(f"--color field '{req}' is not a per-particle fluid field")
        else:
            options = sorted(per) + (["speed"] if "velocity" in per else [])
            raise RenderError(f"unknown --color field '{req}': recorded fields are {', '.join(options) or 'none'}")
        by_hint = self.field is not None and self.field == hinted
        if by_hint and self.value_range is None and "range" in hint:
            self.value_range = hint["range"]  # fixed from the scene (the free stream's), not the frames'
        if self.log_request is not None:
            self.log = self.log_request
        elif by_hint and "log" in hint:
            self.log = hint["log"]
        else:
            self.log = self.dim == 2 and self.field == "pressure"
        hint_ramp = hint.get("ramp") if by_hint and hint.get("ramp") in _colors.RAMPS else None
        ramp = self.ramp_request or hint_ramp or ("heat" if self.dim == 2 else "ocean")
        self.lut = _colors.make_lut(ramp)
        self._trange = None if self.value_range is None else tuple(float(v) for v in _colors.transform(np.array(self.value_range), self.log))
        self.label = _field_label(self.field, self.header) if self.field else ""
        if self.field and self.log:
            self.label = f"{self.label} (log)"

    def _values(self, frame) -> np.ndarray | None:
        """The colouring array for the rasterizer: (n, 1) scalars or (n, D) vectors (magnitude)."""
        if self.field is None:
            return None
        name = "velocity" if self.field == "speed" else self.field
        v = frame.fields.get(name)
        n = len(frame.fields["position"])
        if v is None or len(v) != n:
            raise RenderError(f"frame {getattr(frame, 'index', '?')} has no per-particle '{name}' field")
        v = np.ascontiguousarray(v, dtype=np.float32)
        return v.reshape(-1, 1) if v.ndim == 1 else v

    def _sample_values(self, v: np.ndarray, limit: int = 200_000) -> np.ndarray:
        """Transformed, finite values of every k-th particle (at most ``limit``) of a colouring array."""
        v = v[:: max(1, len(v) // limit)]
        v = v[:, 0] if v.shape[1] == 1 else np.linalg.norm(v, axis=1)
        t = _colors.transform(v, self.log)
        return t[np.isfinite(t)]

    def _grow_range(self, t: np.ndarray) -> None:
        """Widen the colour range to cover the robust percentiles of ``t`` (transformed values)."""
        if self.value_range is not None or t.size == 0:
            return
        lo, hi = (float(x) for x in np.percentile(t, ROBUST_PERCENTILES))
        if self._trange is not None:
            lo, hi = min(lo, self._trange[0]), max(hi, self._trange[1])
        if hi - lo <= 1e-12 * max(1.0, abs(lo), abs(hi)):
            # a uniform field: centre it (all zero: show 0..1)
            pad = 0.05 * abs(lo)
            lo, hi = (0.0, 1.0) if pad == 0 else (lo - pad, hi + pad)
        self._trange = (lo, hi)

    @property
    def color_range(self) -> tuple[float, float] | None:
        """The colour range in field units (None until known or when not colouring)."""
        if self._trange is None:
            return None
        lo, hi = _colors.inverse_transform(np.array(self._trange), self.log)
        return float(lo), float(hi)

    def _bounds(self, frame) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds of the scene: container, obstacles, else the particles."""
        c = self.scene.container or {}
        d = self.dim
        if c.get("type") == "box" and "min" in c and "max" in c:
            return np.asarray(c["min"], float)[:d], np.asarray(c["max"], float)[:d]
        if c.get("type") == "sphere":
            ctr, r = np.asarray(c.get("center", [0] * d), float)[:d], float(c["radius"])
            return ctr - r, ctr + r
        pts = [np.asarray(frame.fields["position"], float)]
        for ob in self.scene.obstacles:
            if ob.get("points"):
                pts.append(np.asarray(ob["points"], float)[:, :d])
            elif ob.get("type") == "box" and len(ob.get("min", ())) >= d:
                pts.append(np.array([ob["min"], ob["max"]], float)[:, :d])
        allp = np.concatenate([p for p in pts if len(p)]) if any(len(p) for p in pts) else np.zeros((1, d))
        lo, hi = np.nanmin(allp, axis=0), np.nanmax(allp, axis=0)
        pad = 0.02 * float(np.max(hi - lo) or 1.0)
        return lo - pad, hi + pad

    def _choose_camera(self, frame) -> None:
        w, h = self.size
        vw = w - self.panel
        lo, hi = self._bounds(frame)
        if self.dim == 2:
            self.camera = _camera.fit_2d(lo, hi, vw, h)
            self.extent = float(np.max(hi - lo))
        else:
            c = self.scene.container or {}
            if c.get("type") == "sphere":
                target, radius = np.asarray(c.get("center", [0, 0, 0]), float), float(c["radius"])
                az, el = 30.0, 20.0
            else:
                target, radius = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
                az, el = 35.0, 25.0
            dist = None
            if self.camera_request is not None:
                az, el, dist = self.camera_request
            if dist is None:
                dist = _camera.fit_distance(radius * 1.02, vw, h)
            self.camera = _camera.orbit(target, az, el, dist, self.scene.up, vw, h)
            self.target = target
            self.extent = 2 * radius
        if self.scene.radius is None:
            n = max(1, len(frame.fields["position"]))
            self.scene.radius = 0.5 * float(np.prod(hi - lo)) ** (1 / self.dim) / n ** (1 / self.dim)

    def _make_background(self) -> np.ndarray:
        w, h = self.size
        top, bottom = BACKGROUND_2D if self.dim == 2 else BACKGROUND_3D
        u = np.linspace(0.0, 1.0, h)[:, None]
        col = (np.asarray(top, float) * (1 - u) + np.asarray(bottom, float) * u).astype(np.uint8)
        return np.ascontiguousarray(np.broadcast_to(col[:, None, :], (h, w, 3)))

    # -- drawing --

    def render(self, frame) -> np.ndarray:
        """Draw one frame (anything with ``fields``, ``groups``, ``rigid``, ``time``, ``step``)
        and return it as an (H, W, 3) uint8 array."""
        if not self._ready:
            self._setup(frame)
        R = self._raster
        w, h = self.size
        img = self._background.copy()
        depth = np.full((h, w), np.inf, np.float32) if self.dim == 3 else None
        cam = self.camera.packed()
        pos = np.ascontiguousarray(frame.fields["position"], dtype=np.float32)
        if pos.ndim != 2 or pos.shape[1] not in (2, 3):
            raise RenderError(f"'position' must have shape (n, 2) or (n, 3), got {pos.shape}")
        values = self._values(frame)
        if values is not None and self.value_range is None:
            self._grow_range(self._sample_values(values))
        lo, hi = self._trange if self._trange is not None else (0.0, 1.0)
        sphere = self.dim == 3
        clip = self._clip_depth(frame)
        # fluid particles
        R.splat(img, depth, pos, values, cam, self.camera.ortho, self.scene.radius, MIN_RADIUS_PX,
                self.lut if values is not None else None, lo, hi, 1 if self.log else 0,
                np.array(_colors.UNIFORM, np.uint8), np.array(_colors.NAN_COLOR, np.uint8), sphere, sphere, clip)
        # ghost particles, smaller and grey
        if self.ghosts:
            gp = self._ghost_positions(frame)
            if gp is not None and len(gp):
                R.splat(img, depth, gp, None, cam, self.camera.ortho, 0.6 * self.scene.radius, MIN_RADIUS_PX, None,
                        0.0, 1.0, 0, np.array(GHOST_RGB, np.uint8), np.array(GHOST_RGB, np.uint8), sphere, sphere, clip)
        if self.dim == 3:
            self._draw_bodies_3d(img, depth, frame)
            self._draw_container_3d(img, depth)
        else:
            self._draw_scene_2d(img, frame)
        if self.overlay:
            self._draw_overlay(img, frame)
        if self.panel:
            _overlay.draw_colorbar(img, self.lut, lo, hi, self.log, self.label)
        return img

    def _clip_depth(self, frame) -> float:
        """View depth of the cutaway plane: the nearest rigid-body centre (or the scene centre)."""
        if self.dim != 3 or self.cutaway is False:
            return -math.inf
        centres = [np.asarray(st.get("position", [0, 0, 0]), float)[:3]
                   for name, st in (getattr(frame, "rigid", None) or {}).items() if name in self.scene.bodies]
        if not centres:
            if not self.cutaway:
                return -math.inf
            centres = [self.target]
        return float(np.min(self.camera.view(np.array(centres))[:, 2]))

    def _ghost_positions(self, frame) -> np.ndarray | None:
        groups = getattr(frame, "groups", {}) or {}
        for name in ("ghost_position",) + tuple(k for k, g in groups.items() if g == "ghost" and k.endswith("position")):
            if name in frame.fields:
                return np.ascontiguousarray(frame.fields[name], dtype=np.float32)
        return None

    def _lines(self, img, depth, pts3: np.ndarray, closed: bool, rgb, width: float, opacity: float, depth_test: bool):
        """A polyline through world points, projected and drawn anti-aliased."""
        p = self.camera.project(pts3)[:, :3]
        if closed:
            p = np.vstack([p, p[:1]])
        segs = np.ascontiguousarray(np.hstack([p[:-1], p[1:]]), dtype=np.float32)
        self._raster.lines(img, depth, segs, np.array(rgb, np.uint8), width, opacity, depth_test,
                           1e-3 * self.extent, self.camera.ortho)

    def _draw_container_3d(self, img, depth) -> None:
        c = self.scene.container or {}
        lw = max(1.0, self.size[1] / 500)
        if c.get("type") == "sphere":
            ctr, r = np.asarray(c.get("center", [0, 0, 0]), float), float(c["radius"])
            theta = np.linspace(0, 2 * np.pi, 193)[:-1]
            # silhouette: the circle where rays from the eye graze the sphere
            if self.camera.eye is not None:
                wv = self.camera.eye - ctr
                d = float(np.linalg.norm(wv))
                if d > r:
                    axis = wv / d
                    centre, rho = ctr + wv * (r * r / (d * d)), r * math.sqrt(1 - r * r / (d * d))
                    a = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
                    a /= np.linalg.norm(a)
                    b = np.cross(axis, a)
                    ring = centre + rho * (np.cos(theta)[:, None] * a + np.sin(theta)[:, None] * b)
                    self._lines(img, depth, ring, True, CONTAINER_RGB, 1.5 * lw, 0.9, False)
            # equator around the up axis, hidden where particles are in front of it
            e1, e2, _ = _camera.basis(self.scene.up)
            ring = ctr + r * (np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2)
            self._lines(img, depth, ring, True, CONTAINER_RGB, lw, 0.45, True)
        elif c.get("type") == "box":
            lo, hi = np.asarray(c["min"], float), np.asarray(c["max"], float)
            corners = np.array([[(hi if (k >> a) & 1 else lo)[a] for a in range(3)] for k in range(8)])
            for k in range(8):
                for a in range(3):
                    if not (k >> a) & 1:
                        self._lines(img, depth, corners[[k, k | (1 << a)]], False, CONTAINER_RGB, 1.5 * lw, 0.85, True)

    def _shade(self, normal_world: np.ndarray) -> float:
        """Lambert factor of a face normal under the key light (camera space)."""
        nv = self.camera.matrix[:, :3] @ normal_world
        return 0.38 + 0.62 * max(0.0, float(np.dot([nv[0], nv[1], -nv[2]], LIGHT)))

    def _draw_bodies_3d(self, img, depth, frame) -> None:
        tris, cols = [], []
        for name, state in (getattr(frame, "rigid", None) or {}).items():
            spec = self.scene.bodies.get(name, {})
            pos = np.asarray(state.get("position", [0, 0, 0]), float)[:3]
            rot = _camera.quat_matrix(state.get("orientation", [1, 0, 0, 0]))
            shape = spec.get("shape", "box" if "half_extents" in spec else None)
            if shape == "sphere" and spec.get("radius"):
                self._raster.splat(img, depth, pos[None].astype(np.float32), None, self.camera.packed(), self.camera.ortho,
                                   float(spec["radius"]), MIN_RADIUS_PX, None, 0.0, 1.0, 0, np.array(DIE_RGB, np.uint8),
                                   np.array(DIE_RGB, np.uint8), True, True)
                continue
            if shape != "box" or "half_extents" not in spec:
                continue
            he = np.asarray(spec["half_extents"], float)[:3]
            faces = spec.get("faces") or {}  # numbered faces only where the header gives them
            self._box_triangles(pos, rot, he, faces, tris, cols)
        # fixed box obstacles (3-D), unrotated
        for ob in self.scene.obstacles:
            if ob.get("type") == "box" and len(ob.get("min", ())) == 3:
                lo, hi = np.asarray(ob["min"], float), np.asarray(ob["max"], float)
                self._box_triangles(0.5 * (lo + hi), np.eye(3), 0.5 * (hi - lo), {}, tris, cols, OBSTACLE_FILL)
        # extruded sections (3-D): an x-y polygon swept along z over its `extrude` range (the 3-D
        # wind tunnel's airfoil), turned as the frame's diagnostics say: lit sides and end caps
        for ob in self.scene.obstacles:
            ext = ob.get("extrude")
            pts = turned_points(ob, getattr(frame, "diagnostics", None)) if ext is not None else None
            if pts is not None and len(pts) >= 3 and len(ext) == 2:
                self._extruded_triangles(ob, pts[:, :2], float(ext[0]), float(ext[1]), tris, cols)
        if tris:
            v = self.camera.project(np.concatenate(tris).reshape(-1, 3))[:, :3].reshape(-1, 9)
            self._raster.triangles(img, depth, np.ascontiguousarray(v, np.float32),
                                   np.ascontiguousarray(np.array(cols, np.uint8)), self.camera.ortho, True)

    def _extruded_triangles(self, ob, p2: np.ndarray, z0: float, z1: float, tris, cols) -> None:
        """The sides (one quad per edge, facing the camera) and the two caps of a polygon
        p2 (n, 2) swept from z0 to z1."""
        n = len(p2)
        area = 0.5 * float(np.sum(p2[:, 0] * np.roll(p2[:, 1], -1) - np.roll(p2[:, 0], -1) * p2[:, 1]))
        orient = 1.0 if area >= 0 else -1.0  # outward normals for either orientation
        for i in range(n):
            a, b = p2[i], p2[(i + 1) % n]
            d = b - a
            length = float(np.hypot(d[0], d[1]))
            if length == 0.0:
                continue
            n_w = orient * np.array([d[1], -d[0], 0.0]) / length
            q = [np.array([a[0], a[1], z0]), np.array([b[0], b[1], z0]), np.array([b[0], b[1], z1]),
                 np.array([a[0], a[1], z1])]
            if not self.camera.facing(0.25 * (q[0] + q[1] + q[2] + q[3]), n_w):
                continue
            k = self._shade(n_w)
            col = tuple(int(min(255, ch * k)) for ch in OBSTACLE_FILL)
            tris += [np.array([q[0], q[1], q[2]]), np.array([q[0], q[2], q[3]])]
            cols += [col, col]
        key = id(ob)
        if key not in self._cap_cache:
            self._cap_cache[key] = monotone_triangles(np.asarray(ob["points"], float)[:, :2])
        for z, nz in ((z0, -1.0), (z1, 1.0)):
            n_w = np.array([0.0, 0.0, nz])
            if not self.camera.facing(np.array([p2[:, 0].mean(), p2[:, 1].mean(), z]), n_w):
                continue
            k = self._shade(n_w)
            col = tuple(int(min(255, ch * k)) for ch in OBSTACLE_FILL)
            for i, j, m in self._cap_cache[key]:
                tris.append(np.array([[p2[i, 0], p2[i, 1], z], [p2[j, 0], p2[j, 1], z], [p2[m, 0], p2[m, 1], z]]))
                cols.append(col)

    def _box_triangles(self, pos, rot, he, faces, tris, cols, rgb=DIE_RGB) -> None:
        """Lit faces of a box and the pips of its numbered faces that face the camera."""
        for a in range(3):
            for s in (-1.0, 1.0):
                n_b = np.zeros(3)
                n_b[a] = s
                n_w = rot @ n_b
                centre = pos + rot @ (n_b * he)
                if not self.camera.facing(centre, n_w):
                    continue
                b, c = (a + 1) % 3, (a + 2) % 3
                eb, ec = np.zeros(3), np.zeros(3)
                eb[b], ec[c] = he[b], he[c]
                quad = [n_b * he + sb * eb + sc * ec for sb, sc in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
                qw = [pos + rot @ q for q in quad]
                k = self._shade(n_w)
                col = tuple(int(min(255, ch * k)) for ch in rgb)
                tris += [np.array([qw[0], qw[1], qw[2]]), np.array([qw[0], qw[2], qw[3]])]
                cols += [col, col]
        for label, normal in faces.items():
            try:
                number = int(label)
            except ValueError:
                continue
            if number not in PIPS:
                continue
            n_b = np.asarray(normal, float)
            n_b = n_b / max(np.linalg.norm(n_b), 1e-300)
            n_w = rot @ n_b
            reach = float(np.abs(n_b) @ he)
            centre_b = n_b * reach * 1.004
            if not self.camera.facing(pos + rot @ centre_b, n_w):
                continue
            # face axes: the box axis least aligned with the normal, and the one completing the frame
            u = np.zeros(3)
            u[int(np.argmin(np.abs(n_b)))] = 1.0
            u -= n_b * (u @ n_b)
            u /= np.linalg.norm(u)
            v = np.cross(n_b, u)
            half = min(float(np.abs(u) @ he), float(np.abs(v) @ he))
            spacing, pr = 0.5 * half, 0.17 * half
            k = self._shade(n_w)
            col = tuple(int(ch * (0.6 + 0.4 * k)) for ch in PIP_RGB)
            ang = np.linspace(0, 2 * np.pi, 13)[:-1]
            for pu, pv in PIPS[number]:
                c0 = centre_b + spacing * (pu * u + pv * v)
                ring = [c0 + pr * (math.cos(t) * u + math.sin(t) * v) for t in ang]
                cw, rw = pos + rot @ c0, [pos + rot @ q for q in ring]
                for i in range(len(rw)):
                    tris.append(np.array([cw, rw[i], rw[(i + 1) % len(rw)]]))
                    cols.append(col)

    def _draw_scene_2d(self, img, frame) -> None:
        # rigid bodies (boxes) rotated in the plane
        for name, state in (getattr(frame, "rigid", None) or {}).items():
            spec = self.scene.bodies.get(name, {})
            if "half_extents" not in spec:
                continue
            he = np.asarray(spec["half_extents"], float)[:2]
            rot = _camera.quat_matrix(state.get("orientation", [1, 0, 0, 0]))[:2, :2]
            pos = np.asarray(state.get("position", [0, 0]), float)[:2]
            quad = pos + (np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * he) @ rot.T
            self._polygon(img, quad, DIE_RGB, OBSTACLE_EDGE)
        # obstacles filled and outlined (turned as the frame's diagnostics say: the wind tunnel's pitch)
        for ob in self.scene.obstacles:
            pts = turned_points(ob, getattr(frame, "diagnostics", None))
            if pts is not None and len(pts) >= 3:
                self._polygon(img, pts[:, :2], OBSTACLE_FILL, OBSTACLE_EDGE)
        # walls: the container's edges
        c = self.scene.container or {}
        if c.get("type") == "box":
            lo, hi = np.asarray(c["min"], float)[:2], np.asarray(c["max"], float)[:2]
            box = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
            self._lines(img, None, box, True, WALL_RGB, max(1.5, self.size[1] / 360), 0.95, False)
        elif c.get("type") == "sphere":
            ctr, r = np.asarray(c.get("center", [0, 0]), float)[:2], float(c["radius"])
            t = np.linspace(0, 2 * np.pi, 193)[:-1]
            self._lines(img, None, ctr + r * np.stack([np.cos(t), np.sin(t)], 1), True, WALL_RGB, 1.5, 0.95, False)

    def _polygon(self, img, pts2: np.ndarray, fill, edge) -> None:
        p = self.camera.project(pts2)
        self._raster.polygon(img, np.ascontiguousarray(p[:, :2], np.float32), np.array(fill, np.uint8), 1.0)
        self._lines(img, None, pts2, True, edge, 1.5, 0.9, False)

    def _draw_overlay(self, img, frame) -> None:
        size = max(11, int(round(self.size[1] / 40)))
        parts = [self.scene.name] if self.scene.name else []
        t = getattr(frame, "time", None)
        if t is not None:
            parts.append(f"t = {float(t):.4f} s")
        step = getattr(frame, "step", None)
        if step is not None:
            parts.append(f"step {int(step)}")
        if parts:
            _overlay.draw_text(img, "   ".join(parts), 10, 8, size)


# ---- outputs ------------------------------------------------------------------------------


def _open_sink(out, size, fps) -> VideoSink:
    """The output sink, or a one-line RenderError when it cannot be started (no ffmpeg ...)."""
    try:
        return open_sink(out, size, fps, RenderError)
    except OSError as exc:
        raise write_failure(RenderError, f"cannot write {out}: {os_reason(exc)}", exc) from None


@dataclass
class RenderResult:
    """What ``render_run`` wrote."""

    path: Path
    frames: int
    size: tuple[int, int]
    seconds: float
    color_range: tuple[float, float] | None


class LiveRender:
    """Render a run while it records: ``add_frame(frame)`` after each recorded frame, then
    ``close()`` (or use it as a context manager). ``out`` and the options are those of
    :func:`render_run`; the colour range, unless given, widens to cover the frames seen."""

    def __init__(self, out, header: dict, *, fps: float = 30.0, size=(1280, 720), **options):
        self.renderer = FrameRenderer(header, size=size, **options)
        self.sink: VideoSink = _open_sink(out, self.renderer.size, parse_fps(fps))

    def add_frame(self, frame) -> np.ndarray:
        """Render ``frame`` and append it to the output; returns the picture."""
        img = self.renderer.render(frame)
        try:
            self.sink.add(img)
        except OSError as exc:
            raise write_failure(RenderError, f"cannot write {self.sink.path}: {os_reason(exc)}", exc) from None
        return img

    def close(self) -> None:
        """Finish the output and move it into place (it appears only now, complete)."""
        try:
            self.sink.close()
        except OSError as exc:
            raise write_failure(RenderError, f"cannot write {self.sink.path}: {os_reason(exc)}", exc) from None

    def abort(self) -> None:
        """Give up on the output: nothing of it is left behind."""
        self.sink.abort()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        if exc_type is None:
            self.close()
        else:
            self.abort()

    @classmethod
    def from_args(cls, args: argparse.Namespace, header: dict) -> "LiveRender | None":
        """The live renderer ``corpuscle run --render OUT`` asked for (None without --render)."""
        out = getattr(args, "render", None)
        if not out:
            return None
        return cls(out, header, fps=args.render_fps, size=args.render_size, color=args.render_color,
                   value_range=args.render_range, camera=args.render_camera, ghosts=args.render_ghosts)


def add_live_render_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--render OUT`` and its ``--render-*`` options to ``corpuscle run``'s parser."""
    g = parser.add_argument_group("rendering while recording")
    g.add_argument("--render", metavar="OUT", help="render frames as they are recorded to OUT (.mp4, .gif, .png or a directory)")
    g.add_argument("--render-size", metavar="WxH", default="1280x720", help="frame size in pixels (default 1280x720)")
    g.add_argument("--render-fps", metavar="FPS", default=30.0, help="video frame rate (default 30)")
    g.add_argument("--render-color", metavar="FIELD", help="colour field (default: the kind's choice, e.g. the wind tunnel's number_density "
                   "over 0 to 4x the free stream's; else pressure in 2-D, speed in 3-D)")
    g.add_argument("--render-range", metavar="LO:HI", help="colour range in field units (default: the kind's range for its "
                   "field, else robust percentiles)")
    g.add_argument("--render-camera", metavar="AZ,EL[,DIST]", help="3-D camera: azimuth, elevation (degrees), distance (m)")
    g.add_argument("--render-ghosts", action="store_true", help="draw ghost particles too")


def render_run(run, out, *, frames=None, frame=None, size=(1280, 720), fps: float = 30.0, color: str | None = None,
               value_range=None, log: bool | None = None, ramp: str | None = None, camera=None, ghosts: bool = False,
               cutaway: bool | None = None, overlay: bool = True, colorbar: bool = True,
               progress: bool | None = None) -> RenderResult:
    """Render a recorded run (path or opened Run) to ``out``.

    ``out`` decides the output: ``.mp4`` (H.264), ``.gif``, ``.png`` (one frame: ``frame``,
    default the last) or a directory of numbered PNGs. ``frames`` selects frames as
    ``"a:b[:step]"`` (or a slice). The other options are those of :class:`FrameRenderer`.
    ``progress``: a progress bar on stderr (None: only when stderr is a terminal).
    Raises :class:`RenderError` for bad input.
    """
    kind = output_kind(out, RenderError)
    size = parse_size(size, RenderError)
    fps = parse_fps(fps)
    run = open_run(run, RenderError)
    count = len(run)
    if kind == "png":
        if frames is not None:
            raise RenderError("--frames selects frames for videos and PNG directories; use --frame I for one .png")
        indices = [parse_index(frame, count, RenderError)]
    else:
        if frame is not None:
            raise RenderError("--frame picks the frame of a .png; use --frames a:b[:step] for videos and directories")
        indices = parse_frames(frames, count, RenderError)
    # colour range from up to 12 frames spread over the selection (stable over the whole video);
    # a range given by the caller needs no samples
    picks = [] if value_range is not None else sorted(
        {indices[int(round(k))] for k in np.linspace(0, len(indices) - 1, min(12, len(indices)))})
    renderer = FrameRenderer(run.header, size=size, color=color, value_range=value_range, log=log, ramp=ramp,
                             camera=camera, ghosts=ghosts, cutaway=cutaway, overlay=overlay, colorbar=colorbar,
                             sample_frames=[run[i] for i in picks])
    start = time.perf_counter()
    from tqdm import tqdm

    # the output appears only when complete: any failure (a corrupted frame, a full disk, an
    # encoder that died, Ctrl-C) removes what was written so far
    sink = _open_sink(out, size, fps)
    try:
        with tqdm(total=len(indices), unit="frame", desc="render", disable=None if progress is None else not progress,
                  leave=False) as bar:
            for i in indices:
                sink.add(renderer.render(run[i]))
                bar.update(1)
        sink.close()
    except OSError as exc:
        sink.abort()
        raise write_failure(RenderError, f"cannot write {out}: {os_reason(exc)}", exc) from None
    except BaseException:
        sink.abort()
        raise
    return RenderResult(Path(os.fspath(out)), len(indices), size, time.perf_counter() - start, renderer.color_range)


# ---- command line --------------------------------------------------------------------------


def run_command(args: argparse.Namespace) -> int:
    """Run ``corpuscle render`` from parsed arguments; returns the exit code."""
    with cli_warnings():
        return _run_command(args)


def _run_command(args: argparse.Namespace) -> int:
    res = render_run(args.run, args.output, frames=args.frames, frame=args.frame, size=args.size, fps=args.fps,
                     color=args.color, value_range=args.range, log=args.log, ramp=args.ramp, camera=args.camera,
                     ghosts=args.ghosts, cutaway=args.cutaway, overlay=not args.no_overlay, colorbar=not args.no_colorbar,
                     progress=False if args.quiet else None)
    if not args.quiet:
        print(f"wrote {res.path} ({res.frames} frame{'s' if res.frames != 1 else ''}, {res.size[0]}x{res.size[1]}, {res.seconds:.1f} s)")
    return 0


# one-line help and description of the subcommand (for a command table such as corpuscle.cli's)
HELP = "render a recorded run to a video, GIF, PNG or PNG frames"
DESCRIPTION = ("Render a recorded run. OUT decides the output: .mp4 (H.264), .gif, .png (one frame) "
               "or a directory of numbered PNGs.")


def configure_parser(p: argparse.ArgumentParser) -> None:
    """Add ``corpuscle render``'s arguments to a (sub)parser."""
    p.add_argument("run", metavar="RUN", help="recorded run (frame stream file)")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output: .mp4, .gif, .png or a directory")
    p.add_argument("--frame", metavar="I", help="frame of a .png output (default: the last; negatives count from the end)")
    p.add_argument("--frames", metavar="A:B[:STEP]", help="frames of a video or directory (Python slice; default all)")
    p.add_argument("--size", metavar="WxH", default="1280x720", help="picture size in pixels (default 1280x720)")
    p.add_argument("--fps", metavar="FPS", default=30.0, help="video frame rate (default 30)")
    p.add_argument("--color", metavar="FIELD", help="colour by a recorded per-particle field, 'speed' or 'none' "
                                                    "(default: the kind's choice, e.g. the wind tunnel's number_density over "
                                                    "0 to 4x the free stream's; else pressure in 2-D, speed or density "
                                                    "in 3-D)")
    p.add_argument("--range", metavar="LO:HI", help="colour range in field units (default: the kind's range for its "
                                                   "field, else the 1st-99th percentile)")
    scale = p.add_mutually_exclusive_group()
    scale.add_argument("--log", dest="log", action="store_true", default=None, help="colour on log(1+value) (default for 2-D pressure)")
    scale.add_argument("--linear", dest="log", action="store_false", help="colour on the value itself")
    p.add_argument("--ramp", choices=sorted(_colors.RAMPS), help="colour ramp (default: heat in 2-D, ocean in 3-D)")
    p.add_argument("--camera", metavar="AZ,EL[,DIST]", help="3-D camera: azimuth and elevation in degrees, distance in m")
    p.add_argument("--ghosts", action="store_true", help="draw ghost (boundary) particles too")
    cut = p.add_mutually_exclusive_group()
    cut.add_argument("--cutaway", dest="cutaway", action="store_true", default=None,
                     help="leave out particles in front of the die (or the scene centre) so it shows "
                          "(default in 3-D scenes with a rigid body)")
    cut.add_argument("--no-cutaway", dest="cutaway", action="store_false", help="draw every particle")
    p.add_argument("--no-overlay", action="store_true", help="leave out the time/step text")
    p.add_argument("--no-colorbar", action="store_true", help="leave out the colour bar")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``corpuscle render`` on an argparse subparsers object (handler in ``func``)."""
    p = subparsers.add_parser("render", help=HELP, description=DESCRIPTION)
    configure_parser(p)
    p.set_defaults(func=run_command)
    return p
