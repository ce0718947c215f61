"""The schema of a scene kind: its keys (:class:`KeySpec`: type, default, unit, range, doc),
arrays of tables and cross-key checks (:class:`SceneKind`), the check of one value against
its key, and the registry of schemas (:data:`KINDS`, :data:`SCHEMAS`) that the kinds of
:mod:`corpuscle.kinds` fill and :mod:`corpuscle.scene` reads scene files against. Errors are
:class:`SceneError` with a one-line message naming the key and the bad value."""

from __future__ import annotations

import datetime
import difflib
import json
import math
import numbers
import os
import pathlib
import re
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Mapping

VALUE_TYPES = ("float", "int", "bool", "str", "enum", "vec2", "vec3", "points", "path", "list[str]")
INT64_MAX = 2**63 - 1
INT32_MAX = 2**31 - 1
# the fixed-length vector types and their lengths
_VECTORS = {"vec2": 2, "vec3": 3}


class SceneError(ValueError):
    """A scene could not be read or failed validation (message is one line)."""

    def __init__(self, message: str) -> None:
        # keep every message on one line, whatever the caller passed
        super().__init__(" ".join(str(message).split()))


@dataclass(frozen=True)
class KeySpec:
    """Declaration of one scene key.

    ``type`` is one of:

    - ``float``, ``int``, ``bool``: a number (bounded by ``lo``/``hi``) or true/false;
    - ``str``: any string (``choices``, if given, restricts it as for ``enum``);
    - ``enum``: one of the strings in ``choices`` (required);
    - ``vec2``, ``vec3``: exactly 2 or 3 finite numbers, each within ``lo``/``hi``;
    - ``points``: a list of points, each 2 or 3 finite numbers within ``lo``/``hi``
      (``dim`` fixes 2 or 3; without it either, but every point the same),
      ``min_length``/``max_length`` bound how many;
    - ``path``: a file path; a relative one is taken relative to the scene file's folder
      (the current folder for scenes not read from a file, and for overrides); the file
      must exist; the value is stored as the absolute path;
    - ``list[str]``: a list of non-empty strings (``length`` fixes how many).

    ``lo``/``hi`` are bounds (inclusive unless ``lo_open`` / ``hi_open``; ``None`` for
    unbounded).
    """

    type: str
    default: Any
    unit: str = ""
    lo: float | int | None = None
    hi: float | int | None = None
    doc: str = ""
    lo_open: bool = False
    hi_open: bool = False
    length: int | None = None
    choices: tuple[str, ...] | None = None
    dim: int | None = None
    min_length: int | None = None
    max_length: int | None = None
    #: ``str`` keys that may name a file (``airfoil.shape``): a relative value naming a file in
    #: the scene file's folder is that file (made absolute), as a ``path`` key's would be
    file_beside_scene: bool = False

    def __post_init__(self) -> None:
        # a schema typo should fail at import, not at the first bad scene
        if self.type not in VALUE_TYPES:
            raise TypeError(f"KeySpec type must be one of {VALUE_TYPES}, got {self.type!r}")
        if self.type == "enum" and not self.choices:
            raise TypeError("KeySpec of type enum needs choices")
        if self.choices is not None and (isinstance(self.choices, str)
                                         or not all(isinstance(c, str) for c in self.choices)):
            raise TypeError(f"KeySpec choices must be a tuple of strings, got {self.choices!r}")
        if self.dim not in (None, 2, 3):
            raise TypeError(f"KeySpec dim must be 2 or 3, got {self.dim!r}")
        lo, hi = self.min_length, self.max_length
        if (lo is not None and lo < 0) or (lo is not None and hi is not None and hi < lo):
            raise TypeError(f"KeySpec min_length/max_length must satisfy 0 <= min <= max, got {lo}, {hi}")

    def interval(self) -> str:
        """The valid range as text, e.g. ``(0, 1e6]``; empty when unbounded."""
        if self.lo is None and self.hi is None:
            return ""
        left = "(" if self.lo_open or self.lo is None else "["
        right = ")" if self.hi_open or self.hi is None else "]"
        lo = "-inf" if self.lo is None else _fmt_bound(self.lo)
        hi = "inf" if self.hi is None else _fmt_bound(self.hi)
        return f"{left}{lo}, {hi}{right}"

    def count_text(self) -> str:
        """How many points a ``points`` value holds, e.g. ``3 to 1000``; empty when any."""
        lo, hi = self.min_length, self.max_length
        if lo is not None and hi is not None:
            return f"exactly {lo}" if lo == hi else f"{lo} to {hi}"
        if lo is not None:
            return f"at least {lo}"
        if hi is not None:
            return f"at most {hi}"
        return ""

    def describe(self) -> str:
        """What a valid value looks like, for error messages."""
        rng = self.interval()
        unit = f" {self.unit}" if self.unit else ""
        if self.type == "float":
            return f"a number in {rng}{unit}" if rng else f"a finite number{unit}"
        if self.type == "int":
            return f"an integer in {rng}{unit}" if rng else f"an integer{unit}"
        if self.type == "bool":
            return "true or false"
        if self.type in ("str", "enum"):
            if self.choices:
                return "one of " + ", ".join(json.dumps(c) for c in self.choices)
            return "a string"
        if self.type in _VECTORS:
            each = f" each in {rng}" if rng else ""
            return f"a list of {_VECTORS[self.type]} finite numbers{each}{unit}"
        if self.type == "points":
            count = self.count_text()
            numbers = f"{self.dim}" if self.dim else "2 or 3"
            each = f" in {rng}" if rng else ""
            return (f"a list of {count + ' ' if count else ''}points, each {numbers} finite numbers{each}{unit}"
                    + ("" if self.dim else " (all the same)"))
        if self.type == "path":
            return "the path of an existing file"
        n = f"exactly {self.length} " if self.length is not None else ""
        return f"a list of {n}non-empty strings"


# a cross-key check gets (values, arrays) and raises SceneError
CrossCheck = Callable[[dict[str, Any], dict[str, list[dict[str, Any]]]], None]


@dataclass
class SceneKind:
    """A scene kind: its keys, its arrays of tables and its cross-key checks."""

    name: str
    description: str
    keys: dict[str, KeySpec]
    arrays: dict[str, dict[str, KeySpec]] = field(default_factory=dict)
    checks: list[CrossCheck] = field(default_factory=list)
    required_in_arrays: dict[str, tuple[str, ...]] = field(default_factory=dict)
    #: the most entries of each array of tables (the core's capacity), checked before any entry
    max_in_arrays: dict[str, int] = field(default_factory=dict)


# kind name -> dotted key -> spec (the public view of KINDS); filled by corpuscle.kinds
SCHEMAS: dict[str, dict[str, KeySpec]] = {}
# kind name -> full kind description; filled by corpuscle.kinds
KINDS: dict[str, SceneKind] = {}

# keys of the [scene] table; kind is fixed by the file, name/description may be set
SCENE_TABLE_KEYS = ("kind", "name", "description")


def register_kind(kind: SceneKind) -> None:
    """Add a scene kind (its schema, arrays of tables and cross-key checks)."""
    # array names and table names share the top level of the file
    tables = {k.split(".", 1)[0] for k in kind.keys}
    clash = tables & (set(kind.arrays) | {"scene"})
    if clash:
        raise ValueError(f"scene kind {kind.name!r}: names used twice at top level: {sorted(clash)}")
    KINDS[kind.name] = kind
    SCHEMAS[kind.name] = kind.keys


# ---------------------------------------------------------------------------
# value formatting (one line, TOML-like, for messages)
# ---------------------------------------------------------------------------


def _clean_exponent(text: str) -> str:
    """``1e+06`` -> ``1e6``, ``2e-05`` -> ``2e-5``."""
    return re.sub(r"e([+-])0*(\d)", lambda m: "e" + ("-" if m.group(1) == "-" else "") + m.group(2), text)


def _fmt_bound(x: float | int) -> str:
    # integers print in full, floats compactly
    if isinstance(x, int):
        return str(x)
    return _clean_exponent(f"{x:g}")


def _fmt_value(v: Any) -> str:
    """Format a value the way it would be written in TOML, on one line."""
    if getattr(v, "ndim", None) == 0 and hasattr(v, "item"):
        v = v.item()  # a NumPy scalar
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return _clean_exponent(repr(v))
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_fmt_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{k} = {_fmt_value(x)}" for k, x in v.items()) + "}"
    if isinstance(v, (datetime.date, datetime.time)):  # TOML dates and times, as TOML writes them
        return v.isoformat()
    return repr(v)


def _suggest(word: str, candidates: Iterable[str]) -> str | None:
    """The closest candidate to ``word``, or None."""
    candidates = list(candidates)
    hits = difflib.get_close_matches(word, candidates, n=1, cutoff=0.6)
    if hits:
        return hits[0]
    # abbreviations: a unique candidate that starts with the word
    starts = [c for c in candidates if len(word) >= 3 and c.startswith(word)]
    return starts[0] if len(starts) == 1 else None


# ---------------------------------------------------------------------------
# validation of single values
# ---------------------------------------------------------------------------


def _is_bool(v: Any) -> bool:
    # Python's bool and NumPy's bool_ (which is not a subclass of it; its type is named
    # "bool_" in NumPy 1 and "bool" in NumPy 2)
    return isinstance(v, bool) or (type(v).__module__ == "numpy" and type(v).__name__ in ("bool_", "bool"))


def _is_integer(v: Any) -> bool:
    # Python ints and NumPy integer scalars (numbers.Integral), never bools
    return isinstance(v, numbers.Integral) and not _is_bool(v)


def _is_number(v: Any) -> bool:
    return isinstance(v, numbers.Real) and not _is_bool(v)


def _in_range(x: float, spec: KeySpec) -> bool:
    # NaN fails every comparison, so it is rejected here too
    if spec.lo is not None and not (x > spec.lo if spec.lo_open else x >= spec.lo):
        return False
    if spec.hi is not None and not (x < spec.hi if spec.hi_open else x <= spec.hi):
        return False
    return True


def _as_list(value: Any) -> Any:
    """A NumPy array as a list (other values unchanged)."""
    if hasattr(value, "tolist") and not isinstance(value, (list, tuple, str)):
        return value.tolist()
    return value


def _check_points(key: str, spec: KeySpec, value: Any) -> list[list[float]]:
    """A ``points`` value: the list, then each point; errors name the point."""
    value = _as_list(value)
    what = spec.describe()
    if not isinstance(value, (list, tuple)):
        raise SceneError(f"{key} must be {what}, got {_fmt_value(value)}")
    n = len(value)
    if (spec.min_length is not None and n < spec.min_length) or (spec.max_length is not None and n > spec.max_length):
        raise SceneError(f"{key} must be {what}, got {n} point{'' if n == 1 else 's'}")
    out: list[list[float]] = []
    for i, p in enumerate(value):
        p = _as_list(p)
        dims = (spec.dim,) if spec.dim else (len(out[0]),) if out else (2, 3)
        ok = isinstance(p, (list, tuple)) and len(p) in dims
        ok = ok and all(_is_number(x) and math.isfinite(x) and _in_range(x, spec) for x in p)
        if not ok:
            rng = spec.interval()
            numbers = " or ".join(str(d) for d in dims)
            each = f" each in {rng}" if rng else ""
            same = " (as the first point)" if not spec.dim and out else ""
            raise SceneError(f"{key}[{i}] must be {numbers} finite numbers{each}{same}, got {_fmt_value(p)}")
        out.append([float(x) for x in p])
    return out


def _check_path(key: str, value: Any, base: str | os.PathLike | None) -> str:
    """A ``path`` value: resolved against ``base`` (the scene file's folder) when relative,
    the file must exist; returns the absolute path."""
    if not isinstance(value, (str, os.PathLike)) or not os.fspath(value).strip():
        raise SceneError(f"{key} must be the path of an existing file, got {_fmt_value(value)}")
    text = os.fspath(value)
    path = pathlib.Path(os.path.expanduser(text))
    if not path.is_absolute():
        path = pathlib.Path(base if base is not None else os.getcwd()) / path
    path = pathlib.Path(os.path.abspath(path))
    if path.is_dir():
        raise SceneError(f"{key} must be the path of an existing file, got {_fmt_value(text)} ({path} is a folder)")
    if not path.is_file():
        raise SceneError(f"{key} must be the path of an existing file, got {_fmt_value(text)} "
                         f"({path} does not exist)")
    return str(path)


def check_value(key: str, spec: KeySpec, value: Any, base: str | os.PathLike | None = None) -> Any:
    """Validate ``value`` for ``key`` and return it normalised (ints -> floats
    for float keys, tuples -> lists, paths absolute); raise SceneError naming key and
    value. ``base`` is the folder relative paths are resolved against (default: the
    current folder)."""

    def bad() -> SceneError:
        return SceneError(f"{key} must be {spec.describe()}, got {_fmt_value(value)}")

    t = spec.type
    # scalars
    if t == "float":
        if not _is_number(value) or not math.isfinite(value) or not _in_range(value, spec):
            raise bad()
        return float(value)
    if t == "int":
        if not _is_integer(value) or not _in_range(value, spec):
            raise bad()
        return int(value)
    if t == "bool":
        if not _is_bool(value):
            raise bad()
        return bool(value)
    if t in ("str", "enum"):
        if not isinstance(value, str):
            raise bad()
        if spec.choices and value not in spec.choices:
            hint = _suggest(value, spec.choices)
            extra = f" (did you mean {json.dumps(hint)}?)" if hint else ""
            raise SceneError(f"{key} must be {spec.describe()}, got {_fmt_value(value)}{extra}")
        if spec.file_beside_scene and base is not None and value.strip():
            beside = pathlib.Path(base) / os.path.expanduser(value.strip())
            if beside.is_file():
                return str(pathlib.Path(os.path.abspath(beside)))
        return value
    # vectors: exactly 2 or 3 finite numbers, each within the bounds
    if t in _VECTORS:
        value = _as_list(value)  # a NumPy array of numbers
        if not isinstance(value, (list, tuple)) or len(value) != _VECTORS[t]:
            raise bad()
        for x in value:
            if not _is_number(x) or not math.isfinite(x) or not _in_range(x, spec):
                raise bad()
        return [float(x) for x in value]
    if t == "points":
        return _check_points(key, spec, value)
    if t == "path":
        return _check_path(key, value, base)
    # list of non-empty strings, optionally of a fixed length
    if not isinstance(value, (list, tuple)):
        raise bad()
    if spec.length is not None and len(value) != spec.length:
        raise bad()
    for x in value:
        if not isinstance(x, str) or not x.strip():
            raise bad()
    return list(value)


# ---------------------------------------------------------------------------
# cross-key checks shared by kinds
# ---------------------------------------------------------------------------


def check_le(a: str, b: str) -> CrossCheck:
    """A check that key ``a`` <= key ``b``."""

    def check(values: dict[str, Any], arrays: dict[str, list[dict[str, Any]]]) -> None:
        if values[a] > values[b]:
            raise SceneError(
                f"{a} must be <= {b}, got {a} = {_fmt_value(values[a])} > {b} = {_fmt_value(values[b])}"
            )

    return check


def check_windows(array: str) -> CrossCheck:
    """A check that every entry of ``array`` has 0 <= start < end."""

    def check(values: dict[str, Any], arrays: dict[str, list[dict[str, Any]]]) -> None:
        for i, entry in enumerate(arrays.get(array, []), start=1):
            if not (0.0 <= entry["start"] < entry["end"]):
                raise SceneError(
                    f"{array}[{i}] must have 0 <= start < end, got start = {_fmt_value(entry['start'])}, "
                    f"end = {_fmt_value(entry['end'])}"
                )

    return check
