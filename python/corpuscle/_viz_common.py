"""Plumbing shared by ``corpuscle render``, ``plot`` and ``export``.

Opening a recorded run, parsing frame selections, importing optional dependencies with a
one-line ``pip install`` hint, checking that outputs can be written, and the units of the
quantities a run records. Every function takes the caller's error class (a ``ValueError``
subclass) so each subcommand reports bad input in its own name.
"""

from __future__ import annotations

import importlib
import os
import re
from pathlib import Path
from typing import Any

# units of recorded per-particle fields and per-frame diagnostics (SI; 2-D forces per unit depth)
UNITS = {
    "position": "m",
    "velocity": "m/s",
    "speed": "m/s",
    "density": "kg/m³",
    "mean_density": "kg/m³",
    "pressure": "Pa",
    "dt": "s",
    "time": "s",
    "kinetic_energy": "J",
    "density_error": "-",
    "die_height": "m",
    "die_speed": "m/s",
    "lift": "N/m",
    "drag": "N/m",
    "cl": "-",
    "cd": "-",
    "n_particles": "count",
    "n_ghosts": "count",
}


def units_of(name: str, header: dict | None = None) -> str:
    """Unit of a field or diagnostic; 2-D DEM "pressure" is a sum of contact forces (N/m)."""
    if name == "pressure" and header and _is_dem(header):
        return "N/m"
    return UNITS.get(name, "")


def _is_dem(header: dict) -> bool:
    """True for soft-sphere (DEM) scenes, whose "pressure" is a contact-force sum."""
    kind = header.get("kind") or _find_key(header.get("parameters") or header.get("scene") or {}, "kind")
    text = f"{kind} {scene_info(header)['name']}".lower()
    return any(w in text for w in ("dem", "wind", "tunnel", "gas", "granular"))


def is_run_like(obj: Any) -> bool:
    """True for an opened run (or anything with its interface) rather than a path."""
    return hasattr(obj, "header") and hasattr(obj, "__getitem__") and hasattr(obj, "__len__")


def open_run(run: Any, error: type[ValueError]):
    """Open ``run`` (a path or an already opened Run) or raise ``error`` with one line."""
    if is_run_like(run):
        return run
    path = Path(os.fspath(run))
    if not path.exists():
        raise error(f"run file not found: {path}")
    if path.is_dir():
        raise error(f"run must be a recorded frame stream file, got a directory: {path}")
    try:
        import corpuscle

        opener = getattr(corpuscle, "open", None)
        if opener is None:
            from corpuscle import io as cio

            opener = cio.open
        return opener(path)
    except ImportError as exc:
        raise error(f"cannot read runs: corpuscle.io is unavailable ({exc})") from None
    except (ValueError, OSError, EOFError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise error(f"cannot read run {path}: {msg}") from None


def require(module: str, pip_name: str, what: str, error: type[ValueError]):
    """Import an optional dependency, or raise ``error`` naming the ``pip install`` that fixes it."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise error(f"{what} needs the '{pip_name}' package: pip install {pip_name}  (or pip install 'corpuscle[viz]')") from None


def parse_frames(spec: str | slice | None, count: int, error: type[ValueError]) -> list[int]:
    """Frame indices selected by ``a:b[:step]`` (Python slice rules, negatives from the end)."""
    if count == 0:
        raise error("the run has no frames")
    if spec is None:
        return list(range(count))
    if isinstance(spec, slice):
        sl = spec
    else:
        m = re.fullmatch(r"\s*(-?\d*)\s*:\s*(-?\d*)\s*(?::\s*(-?\d*)\s*)?", str(spec))
        if not m:
            raise error(f"--frames must be a:b[:step] with integers, got '{spec}'")
        a, b, s = (int(g) if g not in (None, "") else None for g in m.groups())
        if s is not None and s <= 0:
            raise error(f"--frames step must be a positive integer, got {s}")
        sl = slice(a, b, s)
    picked = list(range(count))[sl]
    if not picked:
        raise error(f"--frames '{spec}' selects no frames (the run has {count})")
    return picked


def parse_index(index: int | str | None, count: int, error: type[ValueError], option: str = "--frame") -> int:
    """One frame index (negative from the end; default the last frame)."""
    if count == 0:
        raise error("the run has no frames")
    if index is None:
        return count - 1
    try:
        i = int(index)
    except (TypeError, ValueError):
        raise error(f"{option} must be an integer, got '{index}'") from None
    if not -count <= i < count:
        raise error(f"{option} {i} is out of range: the run has {count} frames (0..{count - 1})")
    return i % count


def parse_size(spec: str | tuple[int, int], error: type[ValueError], lo: int = 16, hi: int = 8192) -> tuple[int, int]:
    """``WxH`` (or a (width, height) pair) -> (width, height) in pixels, each in [lo, hi]."""
    if isinstance(spec, str):
        m = re.fullmatch(r"\s*(\d+)\s*[xX×]\s*(\d+)\s*", spec)
        if not m:
            raise error(f"--size must be WxH in pixels (e.g. 1280x720), got '{spec}'")
        w, h = int(m.group(1)), int(m.group(2))
    else:
        try:
            w, h = (int(v) for v in spec)
        except (TypeError, ValueError):
            raise error(f"size must be (width, height), got {spec!r}") from None
    if not (lo <= w <= hi and lo <= h <= hi):
        raise error(f"--size must be between {lo} and {hi} pixels each way, got {w}x{h}")
    return w, h


def check_file_output(path: str | os.PathLike, error: type[ValueError]) -> Path:
    """An output file path whose folder exists and is writable."""
    p = Path(os.fspath(path))
    if p.is_dir():
        raise error(f"cannot write {p}: it is a directory")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise error(f"cannot write {p}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK) or (p.exists() and not os.access(p, os.W_OK)):
        raise error(f"cannot write {p}: permission denied")
    return p


def prepare_dir(path: str | os.PathLike, error: type[ValueError]) -> Path:
    """An output folder, created if needed, that is writable."""
    p = Path(os.fspath(path))
    if p.exists() and not p.is_dir():
        raise error(f"cannot write into {p}: it exists and is not a directory")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise error(f"cannot create {p}: {exc.strerror or exc}") from None
    if not os.access(p, os.W_OK):
        raise error(f"cannot write into {p}: permission denied")
    return p


def run_stem(run: Any, default: str = "run") -> str:
    """A file-name stem for outputs derived from a run: its file name, else its scene."""
    path = getattr(run, "path", None)
    if path:
        stem = Path(os.fspath(path)).name.split(".")[0]
        if stem:
            return stem
    name = scene_info(getattr(run, "header", None))["name"]
    return re.sub(r"[^A-Za-z0-9_-]+", "_", name) if name else default


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


# standard die: face number -> outward normal in the body frame (opposite faces sum to 7)
DIE_FACES = {"1": [1, 0, 0], "6": [-1, 0, 0], "2": [0, 1, 0], "5": [0, -1, 0], "3": [0, 0, 1], "4": [0, 0, -1]}


def scene_info(header: dict | None) -> dict:
    """The scene geometry a run header describes, in the simulator's conventions.

    Returns ``{"name", "dim", "container", "obstacles", "bodies", "particle_radius",
    "gravity"}`` (missing ones None or empty). Headers written by ``Simulation.header()``
    carry these directly; a header holding only the scene's parameters (``"scene"`` or
    ``"parameters"`` as the nested scene dict) gets a sphere container from
    ``container.radius`` and a die box from ``die.side``.
    """
    h = dict(header or {})
    params = h.get("parameters") if isinstance(h.get("parameters"), dict) else None
    if params is None and isinstance(h.get("scene"), dict):
        params = h["scene"]
    params = params or {}
    # name: a string, or the scene table's name
    name = h.get("scene") if isinstance(h.get("scene"), str) else None
    if name is None:
        meta = params.get("scene") if isinstance(params.get("scene"), dict) else {}
        name = meta.get("name") or h.get("kind") or meta.get("kind") or ""
    container = h.get("container") if isinstance(h.get("container"), dict) and "type" in h["container"] else None
    if container is None and isinstance(params.get("container"), dict) and "radius" in params["container"]:
        container = {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": float(params["container"]["radius"])}
    bodies = list(h.get("bodies") or [])
    if not bodies and isinstance(params.get("die"), dict) and "side" in params["die"]:
        half = 0.5 * float(params["die"]["side"])
        bodies = [{"name": "die", "shape": "box", "half_extents": [half] * 3, "faces": DIE_FACES}]
    radius = h.get("particle_radius")
    return {
        "name": str(name),
        "dim": int(h["dim"]) if h.get("dim") else None,
        "container": container,
        "obstacles": list(h.get("obstacles") or []),
        "bodies": bodies,
        "particle_radius": float(radius) if radius else None,
        "gravity": _vector3(_find_key(h, "gravity")),
        "up": h.get("up"),
    }
