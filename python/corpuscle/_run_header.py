"""A recorded run's header as the viewers read it (render, plot, export, the live page): the
scene's name, container, obstacles and bodies checked and normalised, with a one-line
:class:`HeaderError` naming what is malformed; the points of an obstacle at a frame's pose."""

from __future__ import annotations

import math
from typing import Any


def _find_key(obj: Any, key: str) -> Any:
    """First value stored under ``key`` anywhere in nested dicts (depth first)."""
    if isinstance(obj, dict):
        if key in obj:
            return obj[key]
        for v in obj.values():
            found = _find_key(v, key)
            if found is not None:
                return found
    return None


def _vector3(value: Any) -> list[float] | None:
    """A 3-vector from a list, or the first 3-vector inside a dict (``{"g": [0, 0, -9.81]}``)."""
    if isinstance(value, dict):
        for v in value.values():
            if (vec := _vector3(v)) is not None:
                return vec
        return None
    if isinstance(value, (list, tuple)) and len(value) == 3 and all(isinstance(x, (int, float)) for x in value):
        return [float(x) for x in value]
    return None


class HeaderError(ValueError):
    """A run header whose scene description (container, bodies, obstacles ...) is malformed."""


def _number(value: Any, what: str, positive: bool = False) -> float:
    """A finite JSON number (not a bool), else HeaderError naming ``what``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise HeaderError(f"run header: {what} must be a finite number, got {_short(value)}")
    if positive and value <= 0:
        raise HeaderError(f"run header: {what} must be positive, got {value!r}")
    return float(value)


def _numbers(value: Any, what: str, lo: int = 1, hi: int = 3) -> list[float]:
    """A list of ``lo``..``hi`` finite numbers, else HeaderError."""
    if not isinstance(value, (list, tuple)) or not lo <= len(value) <= hi:
        raise HeaderError(f"run header: {what} must be a list of {lo}..{hi} numbers, got {_short(value)}")
    return [_number(v, what) for v in value]


def _short(value: Any) -> str:
    """A value for a one-line message, cut to 40 characters."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _check_container(c: dict) -> dict:
    """A container description with numbers where the renderer and exporter need them."""
    out = dict(c)
    if c["type"] == "box":
        out["min"], out["max"] = _numbers(c.get("min"), "container.min"), _numbers(c.get("max"), "container.max")
    elif c["type"] == "sphere":
        out["center"] = _numbers(c.get("center", [0.0, 0.0, 0.0]), "container.center")
        out["radius"] = _number(c.get("radius"), "container.radius", positive=True)
    return out


def _check_obstacle(ob: Any, k: int) -> dict:
    """An obstacle: a polygon (``points``) or a box (``min``, ``max``; a 2-D box also gets
    its four corners as ``points``, so it is drawn and exported as the polygon it is)."""
    if not isinstance(ob, dict):
        raise HeaderError(f"run header: obstacles[{k}] must be an object, got {_short(ob)}")
    out = dict(ob)
    if ob.get("type") == "box":
        lo, hi = _numbers(ob.get("min"), f"obstacles[{k}].min", 2, 3), _numbers(ob.get("max"), f"obstacles[{k}].max", 2, 3)
        if len(lo) != len(hi) or any(a > b for a, b in zip(lo, hi)):
            raise HeaderError(f"run header: obstacles[{k}] min must not exceed max (of the same length), "
                              f"got {_short(lo)} and {_short(hi)}")
        out["min"], out["max"] = lo, hi
        if len(lo) == 2 and ob.get("points") is None:
            out["points"] = [[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]]
    if ob.get("type") == "mesh":
        # a triangle mesh (a [[bodies]] entry of the SPH box kinds): world vertices and faces
        verts, faces = ob.get("vertices"), ob.get("faces")
        if not isinstance(verts, list) or not isinstance(faces, list) or not verts:
            raise HeaderError(f"run header: obstacles[{k}] (mesh) needs lists vertices and faces")
        out["vertices"] = [_numbers(q, f"obstacles[{k}].vertices", 3, 3) for q in verts]
        for f in faces:
            if (not isinstance(f, list) or len(f) != 3
                    or not all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < len(verts) for i in f)):
                raise HeaderError(f"run header: obstacles[{k}].faces must be triples of vertex indices, got {_short(f)}")
    if ob.get("points") is not None:
        pts = ob["points"]
        if not isinstance(pts, list):
            raise HeaderError(f"run header: obstacles[{k}].points must be a list of points")
        out["points"] = [_numbers(q, f"obstacles[{k}].points", 2, 3) for q in pts]
        if len({len(q) for q in out["points"]}) > 1:
            raise HeaderError(f"run header: obstacles[{k}].points mixes 2-D and 3-D points")
    return out


def turned_points(ob: dict, diagnostics: dict | None):
    """An obstacle's points (n, 2 or 3) as a frame shows them: turned counter-clockwise about
    ``turn.about`` by ``turn.sign`` times the frame's diagnostic ``turn.diagnostic`` (degrees),
    as the wind tunnel's pitch turns its airfoil (docs/frame_format.md, "Run header"); as
    given without a ``turn`` or that diagnostic; float64 arrays. None: the obstacle has no points."""
    import numpy as np

    pts = ob.get("points")
    if pts is None:
        return None
    p = np.asarray(pts, dtype=np.float64)
    pose = ob.get("pose") if isinstance(ob.get("pose"), dict) else None
    if pose is not None and diagnostics:
        moved = _posed_points(p, pose, diagnostics)
        if moved is not None:
            return moved
    turn = ob.get("turn") if isinstance(ob.get("turn"), dict) else None
    if turn is None or not diagnostics:
        return p
    try:
        angle = float(turn.get("sign", 1.0)) * float(diagnostics.get(str(turn.get("diagnostic")), math.nan))
        about = np.asarray(turn["about"], dtype=np.float64)[:2]
    except (KeyError, TypeError, ValueError):
        return p
    if not math.isfinite(angle) or angle == 0.0 or about.shape != (2,) or not np.all(np.isfinite(about)):
        return p
    a = math.radians(angle)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    out = p.copy()
    out[:, :2] = about + (p[:, :2] - about) @ rot.T
    return out


def posed_vertices(ob: dict, diagnostics: dict | None):
    """A mesh obstacle's vertices (n, 3) as a frame shows them: at the frame's pose when the
    obstacle has a ``pose`` (a moving body) and the frame its diagnostics, else as given."""
    import numpy as np

    v = np.asarray(ob["vertices"], dtype=np.float64)
    pose = ob.get("pose") if isinstance(ob.get("pose"), dict) else None
    if pose is None or not diagnostics:
        return v
    moved = _posed_points(v, pose, diagnostics)
    return v if moved is None else moved


def _posed_points(p, pose: dict, diagnostics: dict):
    """A moving body's points (given at its pose of t = 0: reference point ``pose.origin``,
    rotation ``pose.rotation``, D x D) at a frame's pose: its diagnostics ``<pose.diagnostic>_x``,
    ``_y`` (``_z``) and ``_angle`` (2-D, degrees) or ``_r00`` .. ``_r22`` (3-D). None when the
    frame lacks them (the points are then drawn as given)."""
    import numpy as np

    try:
        name = str(pose["diagnostic"])
        c0 = np.asarray(pose["origin"], dtype=np.float64)
        R0 = np.asarray(pose["rotation"], dtype=np.float64)
        D = len(c0)
        if D not in (2, 3) or R0.shape != (D, D) or p.ndim != 2 or p.shape[1] != D:
            return None
        c = np.array([float(diagnostics[f"{name}_{a}"]) for a in "xyz"[:D]])
        if D == 2:
            a = math.radians(float(diagnostics[f"{name}_angle"]))
            R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        else:
            R = np.array([[float(diagnostics[f"{name}_r{r}{q}"]) for q in range(3)] for r in range(3)])
    except (KeyError, TypeError, ValueError):
        return None
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(R))):
        return None
    return c + (p - c0) @ R0 @ R.T


def _check_body(b: Any, k: int) -> dict:
    if not isinstance(b, dict):
        raise HeaderError(f"run header: bodies[{k}] must be an object, got {_short(b)}")
    out = dict(b)
    if not isinstance(b.get("name", ""), str) or not isinstance(b.get("shape", ""), str):
        raise HeaderError(f"run header: bodies[{k}] name and shape must be strings")
    if "half_extents" in b:
        out["half_extents"] = _numbers(b["half_extents"], f"bodies[{k}].half_extents")
    if b.get("radius") is not None:
        out["radius"] = _number(b["radius"], f"bodies[{k}].radius", positive=True)
    faces = b.get("faces")
    if faces is not None:
        if not isinstance(faces, dict):
            raise HeaderError(f"run header: bodies[{k}].faces must be an object")
        out["faces"] = {str(label): _numbers(n, f"bodies[{k}].faces", 3, 3) for label, n in faces.items()}
    return out


def _params(h: dict) -> dict:
    """The scene's parameter table in a header ("parameters", or "scene" as a dict)."""
    params = h.get("parameters") if isinstance(h.get("parameters"), dict) else None
    if params is None and isinstance(h.get("scene"), dict):
        params = h["scene"]
    return params or {}


def scene_name(header: dict | None) -> str:
    """The scene's name: the header's "scene" string, else the scene table's name or kind.

    Never fails, so plots and file names work whatever the rest of the header holds.
    """
    h = header if isinstance(header, dict) else {}
    name = h.get("scene") if isinstance(h.get("scene"), str) else None
    if name is None:
        params = _params(h)
        meta = params.get("scene") if isinstance(params.get("scene"), dict) else {}
        name = meta.get("name") or h.get("kind") or meta.get("kind") or ""
    return name if isinstance(name, str) else ""


def scene_info(header: dict | None) -> dict:
    """The scene geometry a run header describes, in the simulator's conventions.

    Returns ``{"name", "dim", "container", "obstacles", "bodies", "particle_radius",
    "gravity", "up"}`` (missing ones None or empty), from the header's own keys as
    ``Simulation.header()`` writes them for every kind (docs/frame_format.md, "Run
    header"); nothing is guessed from the scene's parameters: a header without
    ``container`` or ``bodies`` has none drawn. Gravity (for the up axis) is the header's
    ``gravity``, else, for runs recorded before headers had it, the first 3-vector stored
    under a ``gravity`` key anywhere in the header (the parameters' ``gravity.g``).
    """
    if not isinstance(header or {}, dict):
        raise HeaderError(f"run header must be a JSON object, got {type(header).__name__}")
    h = dict(header or {})
    name = scene_name(h)
    container = h.get("container") if isinstance(h.get("container"), dict) and "type" in h["container"] else None
    if container is not None:
        container = _check_container(container)
    bodies = h.get("bodies") or []
    if not isinstance(bodies, list):
        raise HeaderError(f"run header: bodies must be a list, got {_short(bodies)}")
    obstacles = h.get("obstacles") or []
    if not isinstance(obstacles, list):
        raise HeaderError(f"run header: obstacles must be a list, got {_short(obstacles)}")
    dim = h.get("dim")
    if dim is not None:
        if isinstance(dim, bool) or not isinstance(dim, (int, float)) or dim not in (1, 2, 3):
            raise HeaderError(f"run header: dim must be 1, 2 or 3, got {_short(dim)}")
        dim = int(dim)
    radius = h.get("particle_radius")
    up = h.get("up")
    return {
        "name": str(name),
        "dim": dim or None,
        "container": container,
        "obstacles": [_check_obstacle(ob, k) for k, ob in enumerate(obstacles)],
        "bodies": [_check_body(b, k) for k, b in enumerate(bodies)],
        "particle_radius": _number(radius, "particle_radius", positive=True) if radius else None,
        "gravity": _vector3(h["gravity"]) if h.get("gravity") is not None else _vector3(_find_key(h, "gravity")),
        "up": up if isinstance(up, str) else None,
    }
