"""Plumbing shared by ``corpuscle render``, ``plot`` and ``export``.

Opening a recorded run, parsing frame selections, importing optional dependencies with a
one-line ``pip install`` hint, checking that outputs can be written, and the units of the
quantities a run records. Every function takes the caller's error class (a ``ValueError``
subclass) so each subcommand reports bad input in its own name.
"""

from __future__ import annotations

import contextlib
import contextvars
import importlib
import math
import os
import re
import secrets
import stat
import sys
import warnings
from pathlib import Path
from typing import Any

# units of recorded per-particle fields and per-frame diagnostics (SI; 2-D forces per unit depth)
# where the run header does not give them ("units", written by every kind since the header
# described the kind)
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
    "id": "-",
}


def units_of(name: str, header: dict | None = None) -> str:
    """Unit of a field or diagnostic: the run header's ``units`` (the kind's: a 2-D DEM
    kind's "pressure", a sum of contact forces, is N/m), else the table above."""
    units = header.get("units") if isinstance(header, dict) else None
    if isinstance(units, dict) and isinstance(units.get(name), str):
        return units[name]
    return UNITS.get(name, "")


def render_hint(header: dict | None) -> dict[str, Any]:
    """The kind's preferred colouring from the run header's ``render`` entry, checked:
    ``color`` (a field name, or "speed"), ``range`` ((lo, hi) in the field's units, finite, lo <
    hi), ``log`` (bool) and ``ramp`` (a name); keys that are absent or malformed are left out
    (an old or hand-written header then gets the generic defaults)."""
    raw = (header or {}).get("render")
    out: dict[str, Any] = {}
    if not isinstance(raw, dict):
        return out
    if isinstance(raw.get("color"), str) and raw["color"]:
        out["color"] = raw["color"]
    r = raw.get("range")
    if (isinstance(r, (list, tuple)) and len(r) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                              and math.isfinite(v) for v in r) and r[0] < r[1]):
        out["range"] = (float(r[0]), float(r[1]))
    if isinstance(raw.get("log"), bool):
        out["log"] = raw["log"]
    if isinstance(raw.get("ramp"), str):
        out["ramp"] = raw["ramp"]
    return out


def is_run_like(obj: Any) -> bool:
    """True for an opened run (or anything with its interface) rather than a path."""
    return hasattr(obj, "header") and hasattr(obj, "__getitem__") and hasattr(obj, "__len__")


def one_line(exc: BaseException | str) -> str:
    """A message on one line: its first non-empty line, or the exception's type name."""
    text = str(exc).strip()
    if not text:
        return type(exc).__name__ if isinstance(exc, BaseException) else ""
    return text.splitlines()[0].strip()


def os_reason(exc: OSError) -> str:
    """``No such file or directory``, not ``[Errno 2] No such file or directory: 'x'``."""
    return exc.strerror or one_line(exc)


def open_run(run: Any, error: type[ValueError]):
    """Open ``run`` (a path or an already opened Run) or raise ``error`` with one line."""
    if is_run_like(run):
        return run
    path = Path(os.fspath(run))
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise error(f"run file not found: {path}") from None
    except OSError as exc:
        raise error(f"cannot read run {path}: {os_reason(exc)}") from None
    if stat.S_ISDIR(mode):
        raise error(f"run must be a recorded frame stream file, got a directory: {path}")
    if not stat.S_ISREG(mode):
        raise error(f"run must be a recorded frame stream file, got a special file: {path}")
    try:
        from corpuscle import io as cio

        return cio.open(path)
    except ImportError as exc:
        raise error(f"cannot read runs: corpuscle.io is unavailable ({one_line(exc)})") from None
    except OSError as exc:
        raise error(f"cannot read run {path}: {os_reason(exc)}") from None
    except (ValueError, EOFError) as exc:
        # the reader's messages start with the path already
        msg = one_line(exc)
        prefix = f"{path}: "
        raise error(f"cannot read run {path}: {msg[len(prefix):] if msg.startswith(prefix) else msg}") from None


# ---- warnings on the command line ----------------------------------------------------------


@contextlib.contextmanager
def cli_warnings(prog: str = "corpuscle"):
    """Print each warning raised inside as one line, ``corpuscle: warning: <message>``.

    The ``warnings`` module's default format shows an internal path and source line; on the
    command line a warning about the user's file (a truncated run, say) is one clean line.
    Repeats of the same message print once. The Python API keeps normal warnings.
    """
    try:
        from corpuscle.io import TruncatedRunWarning
    except ImportError:  # a stand-in io module (tests): every warning is then "other"
        TruncatedRunWarning = type("TruncatedRunWarning", (UserWarning,), {})

    shown = set()

    def show(message, category, filename, lineno, file=None, line=None):
        text = one_line(message)
        if not (issubclass(category, TruncatedRunWarning) or category.__module__.startswith("corpuscle")):
            text = f"{category.__name__}: {text}"
        if text not in shown:
            shown.add(text)
            print(f"{prog}: warning: {text}", file=sys.stderr, flush=True)

    with warnings.catch_warnings():
        warnings.simplefilter("always", TruncatedRunWarning)
        warnings.showwarning = show
        yield


# ---- outputs written whole or not at all ---------------------------------------------------


def temp_path(final: str | os.PathLike) -> Path:
    """A fresh hidden name next to ``final`` with the same suffix (encoders pick the format by it)."""
    p = Path(os.fspath(final))
    return p.with_name(f".{p.name}.{secrets.token_hex(4)}.part{p.suffix}")


class AtomicOutputs:
    """Files written under temporary names in their own folders and moved into place together.

    ``path(final)`` gives the temporary name to write ``final`` to; ``commit()`` moves every
    one into place (``os.replace``, in the order they were asked for, so the file that lists
    the others can come last); ``discard()`` removes the temporaries. A failed render or
    export thus leaves no partial file behind: either the whole output or none of it.
    Use as a context manager: leaving with an exception discards, otherwise nothing happens
    until ``commit()``.
    """

    def __init__(self):
        self._pending: dict[Path, Path] = {}

    def path(self, final: str | os.PathLike) -> Path:
        """The temporary name for ``final`` (the same one when asked again)."""
        final = Path(os.fspath(final))
        if final not in self._pending:
            self._pending[final] = temp_path(final)
        return self._pending[final]

    def commit(self) -> list[Path]:
        """Move every written temporary into place; returns the final paths."""
        done = []
        try:
            for final, tmp in list(self._pending.items()):
                if tmp.exists():
                    os.replace(tmp, final)
                    done.append(final)
                del self._pending[final]
        except BaseException:
            self.discard()
            raise
        return done

    def discard(self) -> None:
        """Remove every temporary not yet moved into place."""
        pending, self._pending = self._pending, {}
        for tmp in pending.values():
            with contextlib.suppress(FileNotFoundError, OSError):
                os.unlink(tmp)

    def __enter__(self) -> "AtomicOutputs":
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if exc_type is not None:
            self.discard()


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


# what an output file of each kind starts with: an existing file that does not is someone
# else's (a scene, a recorded run, notes) and is replaced only with --force
_OUTPUT_STARTS = {
    ".png": (b"\x89PNG\r\n\x1a\n",), ".gif": (b"GIF87a", b"GIF89a"), ".pdf": (b"%PDF",),
    ".svg": (b"<?xml", b"<svg"), ".json": (b"[", b"{"), ".csv": None,
    ".md": (b"# Validation report",),  # `validate all`'s report (any other Markdown is someone's notes)
    # surface meshes (corpuscle.surface): an OBJ is ours only with our first line
    ".obj": (b"# corpuscle surface mesh",), ".ply": (b"ply\n",), ".vtu": (b"<?xml",), ".pvd": (b"<?xml",),
}
FORCE_OUTPUT = contextvars.ContextVar("corpuscle_force_output", default=False)


def _ours(p: Path, start: bytes) -> bool:
    """Whether an existing output file's first bytes are those of the kind its name says."""
    suffix = p.suffix.lower()
    if suffix in (".mp4", ".m4v", ".mov"):
        return start[4:8] == b"ftyp"
    if suffix == ".csv":
        return start.lstrip()[:1].isalpha() and b"\0" not in start
    starts = _OUTPUT_STARTS.get(suffix)
    return bool(starts) and start.lstrip().startswith(starts)


def check_file_output(path: str | os.PathLike, error: type[ValueError], force: bool | None = None) -> Path:
    """An output file path whose folder exists and is writable, and that is not an existing
    file of another kind than its name says (unless ``force``; default: the command's
    ``--force``, :data:`FORCE_OUTPUT`)."""
    p = Path(os.fspath(path))
    if p.is_dir():
        raise error(f"cannot write {p}: it is a directory")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise error(f"cannot write {p}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK) or (p.exists() and not os.access(p, os.W_OK)):
        raise error(f"cannot write {p}: permission denied")
    if not (FORCE_OUTPUT.get() if force is None else force):
        start = b""
        try:
            fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))  # a pipe is not waited on
        except OSError:
            fd = None
        if fd is not None:
            try:
                start = os.read(fd, 64) if stat.S_ISREG(os.fstat(fd).st_mode) else b""
            except OSError:
                pass
            finally:
                os.close(fd)
        if start and not _ours(p, start):
            raise error(f"cannot write {p}: it exists and is not a {p.suffix or 'file of this'} output "
                        f"(it starts {start[:16]!r}); --force replaces it")
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


def missing_dirs(path: str | os.PathLike) -> list[Path]:
    """The folders ``prepare_dir(path)`` would create, the deepest first."""
    p = Path(os.path.abspath(os.fspath(path)))
    return [q for q in (p, *p.parents) if not q.exists()]


def remove_dirs(dirs: list[Path]) -> None:
    """Remove folders made for an output that failed, deepest first, as long as they are empty."""
    for d in dirs:
        try:
            d.rmdir()
        except OSError:
            return


def run_stem(run: Any, default: str = "run") -> str:
    """A file-name stem for outputs derived from a run: its file name, else its scene."""
    path = getattr(run, "path", None)
    if path:
        stem = Path(os.fspath(path)).name.split(".")[0]
        if stem:
            return stem
    name = scene_name(getattr(run, "header", None))
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
