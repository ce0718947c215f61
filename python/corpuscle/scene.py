"""Scenes: TOML files validated against a schema per scene kind.

A scene file has a ``[scene]`` table whose ``kind`` selects the schema, then one
table per group of keys (``[fluid]``, ``[die]``, ...) and, for kinds that have them,
arrays of tables such as ``[[shake]]``. Every key of a kind is declared once, with its
type, default, unit, valid range and a one-line doc, by the kind's module in
``corpuscle/kinds/`` (see :mod:`corpuscle.kinds`); this module is the generic loader and
validator, and :data:`KINDS` / :data:`SCHEMAS` are filled from that registry. A missing
key takes its default, anything else is an error. Errors are :class:`SceneError` with a
one-line message naming the key and the bad value.

Built-in scenes ship in ``corpuscle/scenes/*.toml``::

    scene = load_scene("magic8ball", {"fluid.particles": 20000})
    scene["sph.h"], scene.shakes, scene.to_dict()

A new kind is a module in ``corpuscle/kinds/`` (which registers its schema here through
:func:`register_kind`); a schema alone, without a simulation, can be registered with
:func:`register_kind` directly (tests do).
"""

from __future__ import annotations

import copy
import datetime
import difflib
import json
import math
import numbers
import os
import pathlib
import re
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from typing import Any, Callable, Iterable, Mapping

__all__ = [
    "SceneError",
    "KeySpec",
    "SceneKind",
    "SCHEMAS",
    "KINDS",
    "register_kind",
    "check_value",
    "check_le",
    "check_windows",
    "builtin_scenes",
    "load_scene",
    "parse_set",
    "Scene",
]

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
# validation of a whole document
# ---------------------------------------------------------------------------


def _tables_of(keys: Iterable[str]) -> set[str]:
    """Every table prefix of the dotted keys (``a.b.c`` gives ``a`` and ``a.b``)."""
    out: set[str] = set()
    for k in keys:
        parts = k.split(".")
        for i in range(1, len(parts)):
            out.add(".".join(parts[:i]))
    return out


def _unknown_key(dotted: str, kind: SceneKind) -> SceneError:
    """'unknown key' with a did-you-mean on the full key, then on its last part."""
    keys = list(kind.keys)
    hint = _suggest(dotted, keys)
    if hint is None:
        leaf = dotted.rsplit(".", 1)[-1]
        by_leaf = {k.rsplit(".", 1)[-1]: k for k in keys}
        near = _suggest(leaf, by_leaf)
        hint = by_leaf[near] if near else None
    if hint is not None:
        return SceneError(f"unknown key {dotted!r} (did you mean {hint!r}?)")
    table = dotted.rsplit(".", 1)[0] if "." in dotted else None
    siblings = [k.rsplit(".", 1)[-1] for k in keys if table and k.rsplit(".", 1)[0] == table]
    if siblings:
        return SceneError(f"unknown key {dotted!r} ({table} keys: {', '.join(siblings)})")
    return SceneError(f"unknown key {dotted!r} (see `corpuscle scenes --keys`)")


def _unknown_table(dotted: str, kind: SceneKind) -> SceneError:
    tables = sorted(_tables_of(kind.keys) | set(kind.arrays) | {"scene"})
    hint = _suggest(dotted, tables)
    if hint is not None:
        return SceneError(f"unknown table {dotted!r} (did you mean {hint!r}?)")
    return SceneError(f"unknown table {dotted!r} (valid tables: {', '.join(tables)})")


def _walk(doc: Mapping[str, Any], prefix: str, kind: SceneKind, tables: set[str], out: dict[str, Any],
          base: str | os.PathLike | None = None) -> None:
    """Flatten the key tables of ``doc`` into dotted keys, rejecting unknown ones."""
    for name, value in doc.items():
        dotted = f"{prefix}{name}"
        if dotted in kind.keys:
            out[dotted] = check_value(dotted, kind.keys[dotted], value, base)
        elif dotted in tables:
            if not isinstance(value, Mapping):
                raise SceneError(f"{dotted} must be a table, got {_fmt_value(value)}")
            _walk(value, dotted + ".", kind, tables, out, base)
        elif isinstance(value, Mapping):
            raise _unknown_table(dotted, kind)
        else:
            raise _unknown_key(dotted, kind)


def _check_array(name: str, entries: Any, kind: SceneKind,
                 base: str | os.PathLike | None = None) -> list[dict[str, Any]]:
    """Validate an array of tables (``[[shake]]``); entries are numbered from 1."""
    specs = kind.arrays[name]
    required = kind.required_in_arrays.get(name, ())
    if not isinstance(entries, (list, tuple)):
        raise SceneError(f"{name} must be an array of tables ([[{name}]]), got {_fmt_value(entries)}")
    out = []
    for i, entry in enumerate(entries, start=1):
        where = f"{name}[{i}]"
        if not isinstance(entry, Mapping):
            raise SceneError(f"{where} must be a table, got {_fmt_value(entry)}")
        item: dict[str, Any] = {}
        for key, value in entry.items():
            if key not in specs:
                hint = _suggest(key, specs)
                extra = f"did you mean '{where}.{hint}'?" if hint else f"{name} keys: {', '.join(specs)}"
                raise SceneError(f"unknown key '{where}.{key}' ({extra})")
            item[key] = check_value(f"{where}.{key}", specs[key], value, base)
        for key in required:
            if key not in item:
                raise SceneError(f"{where}.{key} is missing ({where} must set {', '.join(required)})")
        # fill the rest from defaults, in schema order
        out.append({k: item[k] if k in item else copy.deepcopy(s.default) for k, s in specs.items()})
    return out


def _validate(doc: Mapping[str, Any], kind: SceneKind,
              base: str | os.PathLike | None = None) -> tuple[dict[str, Any], dict[str, list[dict[str, Any]]]]:
    """Check a parsed document (without its [scene] table) against ``kind``; relative
    paths are resolved against ``base``."""
    tables = _tables_of(kind.keys)
    values: dict[str, Any] = {}
    arrays: dict[str, list[dict[str, Any]]] = {name: [] for name in kind.arrays}
    # split the top level into arrays of tables and key tables
    rest = {}
    for name, value in doc.items():
        if name in kind.arrays:
            arrays[name] = _check_array(name, value, kind, base)
        else:
            rest[name] = value
    _walk(rest, "", kind, tables, values, base)
    # defaults for everything not set, in schema order
    full = {k: values[k] if k in values else copy.deepcopy(s.default) for k, s in kind.keys.items()}
    for check in kind.checks:
        check(full, arrays)
    return full, arrays


def _scene_table(doc: Mapping[str, Any], fallback_name: str) -> tuple[SceneKind, str, str]:
    """Read and check the [scene] table: (kind, name, description)."""
    table = doc.get("scene")
    known = ", ".join(sorted(KINDS)) or "none"
    if table is None:
        raise SceneError(f"scene.kind is missing: add a [scene] table with kind = one of {known}")
    if not isinstance(table, Mapping):
        raise SceneError(f"scene must be a table, got {_fmt_value(table)}")
    for key in table:
        if key not in SCENE_TABLE_KEYS:
            hint = _suggest(key, SCENE_TABLE_KEYS)
            extra = f"did you mean 'scene.{hint}'?" if hint else "scene keys: " + ", ".join(SCENE_TABLE_KEYS)
            raise SceneError(f"unknown key 'scene.{key}' ({extra})")
    if "kind" not in table:
        raise SceneError(f"scene.kind is missing (known kinds: {known})")
    kind_name = table["kind"]
    if not isinstance(kind_name, str) or kind_name not in KINDS:
        hint = _suggest(kind_name, KINDS) if isinstance(kind_name, str) else None
        extra = f" (did you mean {hint!r}?)" if hint else ""
        raise SceneError(f"scene.kind must be one of {known}, got {_fmt_value(kind_name)}{extra}")
    name = table.get("name", fallback_name)
    if not isinstance(name, str) or not name.strip():
        raise SceneError(f"scene.name must be a non-empty string, got {_fmt_value(name)}")
    description = table.get("description", "")
    if not isinstance(description, str):
        raise SceneError(f"scene.description must be a string, got {_fmt_value(description)}")
    return KINDS[kind_name], name, description


def _override_path(spec: KeySpec | None, value: Any) -> Any:
    """An override of a ``path`` key: a relative path is taken from the current folder
    (the command line's), not from the scene file's."""
    if spec is not None and spec.type == "path" and isinstance(value, str) and value.strip():
        expanded = os.path.expanduser(value)
        if not os.path.isabs(expanded):
            return os.path.abspath(expanded)
    if spec is not None and spec.file_beside_scene and isinstance(value, str) and os.path.isfile(value.strip()):
        return os.path.abspath(os.path.expanduser(value.strip()))
    return value


# ---------------------------------------------------------------------------
# the Scene object
# ---------------------------------------------------------------------------


class Scene:
    """A validated scene.

    Attributes: ``name``, ``kind``, ``description``, ``path`` (the file it was read
    from; for a built-in, the path of the packaged resource; ``None`` when built
    from a dict), ``builtin``, ``values`` (flat dotted key -> validated value, every
    key of the kind present), ``arrays`` (array name -> list of validated tables)
    and ``shakes`` (``arrays["shake"]``: dicts with ``start``, ``end``,
    ``acceleration``, ``torque``).
    """

    def __init__(
        self,
        doc: Mapping[str, Any],
        *,
        path: pathlib.Path | None = None,
        builtin: bool = False,
        fallback_name: str = "scene",
    ) -> None:
        # the raw document is kept so overrides re-validate everything together
        self._doc = copy.deepcopy(dict(doc))
        self.path = path
        self.builtin = builtin
        kind, self.name, self.description = _scene_table(self._doc, fallback_name)
        self.kind = kind.name
        body = {k: v for k, v in self._doc.items() if k != "scene"}
        base = pathlib.Path(os.fspath(path)).parent if path is not None else None
        self.values, self.arrays = _validate(body, kind, base)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], name: str = "scene") -> "Scene":
        """Build a scene from a nested dict such as :meth:`to_dict` returns."""
        return cls(data, fallback_name=name)

    @property
    def shakes(self) -> list[dict[str, Any]]:
        """The shake windows (empty for kinds without ``[[shake]]``)."""
        return self.arrays.get("shake", [])

    @property
    def schema(self) -> dict[str, KeySpec]:
        """The key specs of this scene's kind."""
        return SCHEMAS[self.kind]

    def __getitem__(self, key: str) -> Any:
        """The value of a dotted key, e.g. ``scene["fluid.particles"]``."""
        try:
            return self.values[key]
        except KeyError:
            raise KeyError(str(_unknown_key(key, KINDS[self.kind]))) from None

    def __contains__(self, key: object) -> bool:
        return key in self.values

    def get(self, key: str, default: Any = None) -> Any:
        """The value of a dotted key, or ``default``."""
        return self.values.get(key, default)

    def to_dict(self) -> dict[str, Any]:
        """Nested, JSON-serialisable form with every key (defaults filled in).

        Loading it back with :meth:`from_dict` gives an equal scene.
        """
        out: dict[str, Any] = {
            "scene": {"kind": self.kind, "name": self.name, "description": self.description}
        }
        # nest dotted keys back into tables
        for key, value in self.values.items():
            node = out
            *tables, leaf = key.split(".")
            for t in tables:
                node = node.setdefault(t, {})
            node[leaf] = copy.deepcopy(value)
        for name, entries in self.arrays.items():
            out[name] = copy.deepcopy(entries)
        return out

    def with_overrides(self, overrides: Mapping[str, Any] | None) -> "Scene":
        """A new scene with dotted-key overrides applied and everything re-validated.

        Keys are dotted (``fluid.particles``); an array name (``shake``) replaces the
        whole array; ``scene.name`` and ``scene.description`` may be set, ``scene.kind``
        may not. A relative path given here is relative to the current folder (a path
        written in the scene file is relative to the file's folder).
        """
        if not overrides:
            return self
        kind = KINDS[self.kind]
        doc = copy.deepcopy(self._doc)
        for key, value in overrides.items():
            key = str(key).strip()
            # the [scene] table: name and description only
            if key.startswith("scene.") or key == "scene":
                leaf = key[len("scene."):] if key.startswith("scene.") else ""
                if leaf == "kind":
                    raise SceneError(f"scene.kind cannot be overridden (got {_fmt_value(value)})")
                if leaf not in ("name", "description"):
                    raise SceneError(f"unknown key {key!r} (scene keys that can be set: scene.name, scene.description)")
                doc.setdefault("scene", {})[leaf] = value
                continue
            # whole arrays of tables
            if key in kind.arrays:
                specs = kind.arrays[key]
                if isinstance(value, (list, tuple)):
                    value = [{k: _override_path(specs.get(k), v) for k, v in e.items()} if isinstance(e, Mapping)
                             else e for e in value]
                doc[key] = value
                continue
            if key not in kind.keys:
                raise _unknown_key(key, kind)
            node = doc
            *tables, leaf = key.split(".")
            for t in tables:
                if not isinstance(node.get(t), dict):
                    node[t] = {}
                node = node[t]
            node[leaf] = _override_path(kind.keys[key], value)
        scene = Scene(doc, path=self.path, builtin=self.builtin, fallback_name=self.name)
        return scene

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Scene):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    def __repr__(self) -> str:
        src = f", path={str(self.path)!r}" if self.path else ""
        return f"Scene(name={self.name!r}, kind={self.kind!r}{src})"


# ---------------------------------------------------------------------------
# loading
# ---------------------------------------------------------------------------


def _builtin_dir():
    """The packaged scenes folder (an importlib.resources Traversable)."""
    return resources.files(__package__ or "corpuscle").joinpath("scenes")


def _builtin_names() -> list[str]:
    folder = _builtin_dir()
    if not folder.is_dir():
        return []
    return sorted(p.name[: -len(".toml")] for p in folder.iterdir() if p.name.endswith(".toml"))


def _parse_toml_bytes(data: bytes, label: str) -> dict[str, Any]:
    """Parse TOML, turning decode and syntax errors into one-line SceneErrors."""
    try:
        return tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise SceneError(f"cannot read scene file {label}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"cannot read scene file {label}: {exc}") from None


def builtin_scenes() -> list[tuple[str, str]]:
    """The built-in scenes as (name, description), sorted by name."""
    out = []
    for name in _builtin_names():
        doc = _parse_toml_bytes(_builtin_dir().joinpath(f"{name}.toml").read_bytes(), f"{name}.toml")
        table = doc.get("scene", {})
        out.append((name, table.get("description", "") if isinstance(table, dict) else ""))
    return out


def _looks_like_path(text: str) -> bool:
    return text.endswith(".toml") or "/" in text or os.sep in text or (os.altsep or "/") in text


def load_scene(name_or_path: str | os.PathLike, overrides: Mapping[str, Any] | None = None) -> Scene:
    """Load a built-in scene by name or a scene file by path, validate it and apply
    dotted-key ``overrides`` (validated the same way). Raises :class:`SceneError`."""
    # a path-like object is always a file; a bare name is a built-in first
    is_path = isinstance(name_or_path, os.PathLike)
    if not is_path and not isinstance(name_or_path, str):
        raise TypeError(f"scene must be a built-in scene name, a TOML file path or a Scene, got {name_or_path!r}")
    text = os.fspath(name_or_path)
    if not is_path and not _looks_like_path(text):
        names = _builtin_names()
        if text in names:
            res = _builtin_dir().joinpath(f"{text}.toml")
            doc = _parse_toml_bytes(res.read_bytes(), f"{text}.toml")
            scene = Scene(doc, path=pathlib.Path(str(res)), builtin=True, fallback_name=text)
            return scene.with_overrides(overrides)
        if not os.path.isfile(text):
            listing = ", ".join(names) or "none"
            hint = _suggest(text, names)
            if hint:
                raise SceneError(f"unknown scene {text!r} (did you mean {hint!r}? built-in scenes: {listing})")
            raise SceneError(f"unknown scene {text!r} (built-in scenes: {listing})")
    # a scene file
    path = pathlib.Path(text)
    try:
        data = path.read_bytes()
    except OSError as exc:
        reason = exc.strerror or exc.__class__.__name__
        raise SceneError(f"cannot read scene file {text}: {reason}") from None
    doc = _parse_toml_bytes(data, text)
    scene = Scene(doc, path=path, builtin=False, fallback_name=path.stem)
    return scene.with_overrides(overrides)


_KEY_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_-]*(\.[A-Za-z_][A-Za-z0-9_-]*)*$")


def parse_set(expr: str) -> tuple[str, object]:
    """Parse a ``--set`` expression ``key=value``.

    The value is read as a TOML value (``2e4`` -> float, ``3`` -> int, ``true`` ->
    bool, ``[0,0,-1]`` -> list, ``"text"`` -> str, inline tables too); a value that
    is not valid TOML and does not start with a quote or bracket is taken as a plain
    string (``scene.name=my run``).
    """
    if "=" not in expr:
        raise SceneError(f"--set expects key=value, got {_fmt_value(expr)}")
    key, _, raw = expr.partition("=")
    key, raw = key.strip(), raw.strip()
    if not _KEY_RE.match(key):
        head = key.split(".", 1)[0]
        if "." in key and any(head in k.arrays for k in KINDS.values()):
            # shake.0.start: one window of an array of tables cannot be set on its own
            raise SceneError(f"--set {key}: [[{head}]] entries are set all at once, as "
                             f"--set '{head}=[{{...}}, ...]' (see `corpuscle scenes --keys`)")
        raise SceneError(f"--set expects a dotted key (names joined by dots, each starting with a letter) before '=', "
                         f"got {_fmt_value(key)} in {_fmt_value(expr)}")
    if not raw:
        raise SceneError(f"--set {key}= has no value")
    try:
        return key, tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        pass
    # bare words fall back to strings; broken structured values are errors
    if raw[0] in "[{\"'":
        raise SceneError(f"--set {key}: cannot parse {_fmt_value(raw)} as a TOML value")
    return key, raw


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


# ---------------------------------------------------------------------------
# the kinds: every kind's schema comes from its module in corpuscle/kinds/, registered here
# when the registry is imported (the names above are all defined by now)
# ---------------------------------------------------------------------------

from . import kinds as _kinds  # noqa: E402,F401  (imports every kind, which registers its schema)
