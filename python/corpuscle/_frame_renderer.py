"""The renderer of ``corpuscle render``: :class:`FrameRenderer` draws one frame of a recorded
run into an (H, W, 3) uint8 picture (2-D heat maps, 3-D lit impostors with a depth buffer;
the rasterizer is the compiled ``corpuscle._render``). Public as ``corpuscle.render.FrameRenderer``."""

from __future__ import annotations

import math
from typing import Iterable

import numpy as np

from . import _camera, _colors, _overlay
from ._render_scene import (BACKGROUND_2D, BACKGROUND_3D, CONTAINER_RGB, DIE_RGB, GHOST_RGB, LIGHT, MIN_RADIUS_PX,
                            OBSTACLE_EDGE, OBSTACLE_FILL, PIP_RGB, PIPS, ROBUST_PERCENTILES, WALL_RGB, RenderError,
                            _field_label, _raster, _scene, monotone_triangles, parse_camera, parse_range)
from ._viz_common import parse_size, posed_vertices, render_hint, require, scene_info, turned_points


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
            elif ob.get("type") == "mesh":
                pts.append(np.asarray(ob["vertices"], float)[:, :d])
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
        # triangle meshes (3-D bodies of the SPH box kinds): their faces toward the camera, lit
        for ob in self.scene.obstacles:
            if ob.get("type") == "mesh":
                v = posed_vertices(ob, getattr(frame, "diagnostics", None))  # (a moving body: at the frame's pose)
                t = v[np.asarray(ob["faces"], np.int64).reshape(-1, 3)]
                n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
                for tri, nrm in zip(t, n):
                    if self.camera.facing(tri.mean(axis=0), nrm):
                        k = self._shade(nrm / max(float(np.linalg.norm(nrm)), 1e-300))
                        tris.append(tri)
                        cols.append(tuple(int(min(255, ch * k)) for ch in OBSTACLE_FILL))
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
