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


# a run header's scene as the viewers read it (its own module; these names are the ones
# render, plot, export and the live page import from here)
from ._run_header import HeaderError, posed_vertices, scene_info, scene_name, turned_points  # noqa: E402,F401
