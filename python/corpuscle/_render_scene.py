"""What ``corpuscle render`` draws and how it looks: the colours and sizes, the parsing of its
options (colour range, camera, frame rate), and the scene (container, walls, obstacles,
bodies) read from a run's header. The renderer is :mod:`corpuscle._frame_renderer`; the
public names are :mod:`corpuscle.render`'s."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from ._viz_common import scene_info, units_of


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
