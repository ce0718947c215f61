"""Scenes: TOML files validated against a schema per scene kind.

A scene file has a ``[scene]`` table whose ``kind`` selects the schema, then one
table per group of keys (``[fluid]``, ``[die]``, ...) and, for kinds that have them,
arrays of tables such as ``[[shake]]``. Every key of a kind is declared once in
:data:`SCHEMAS` with its type, default, unit, valid range and a one-line doc; a
missing key takes its default, anything else is an error. Errors are
:class:`SceneError` with a one-line message naming the key and the bad value.

Built-in scenes ship in ``corpuscle/scenes/*.toml``::

    scene = load_scene("magic8ball", {"fluid.particles": 20000})
    scene["sph.h"], scene.shakes, scene.to_dict()

New kinds are added with :func:`register_kind`.
"""

from __future__ import annotations

import copy
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
    "builtin_scenes",
    "load_scene",
    "parse_set",
    "Scene",
]

VALUE_TYPES = ("float", "int", "bool", "str", "vec3", "list[str]")
INT64_MAX = 2**63 - 1
INT32_MAX = 2**31 - 1


class SceneError(ValueError):
    """A scene could not be read or failed validation (message is one line)."""

    def __init__(self, message: str) -> None:
        # keep every message on one line, whatever the caller passed
        super().__init__(" ".join(str(message).split()))


@dataclass(frozen=True)
class KeySpec:
    """Declaration of one scene key.

    ``type`` is one of ``float``, ``int``, ``bool``, ``str``, ``vec3``,
    ``list[str]``. ``lo``/``hi`` are bounds (inclusive unless ``lo_open`` /
    ``hi_open``; ``None`` for unbounded); for ``vec3`` they bound each component.
    ``length`` fixes the length of a ``list[str]``; ``choices`` restricts a ``str``.
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

    def __post_init__(self) -> None:
        # a schema typo should fail at import, not at the first bad scene
        if self.type not in VALUE_TYPES:
            raise TypeError(f"KeySpec type must be one of {VALUE_TYPES}, got {self.type!r}")

    def interval(self) -> str:
        """The valid range as text, e.g. ``(0, 1e6]``; empty when unbounded."""
        if self.lo is None and self.hi is None:
            return ""
        left = "(" if self.lo_open or self.lo is None else "["
        right = ")" if self.hi_open or self.hi is None else "]"
        lo = "-inf" if self.lo is None else _fmt_bound(self.lo)
        hi = "inf" if self.hi is None else _fmt_bound(self.hi)
        return f"{left}{lo}, {hi}{right}"

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
        if self.type == "str":
            if self.choices:
                return "one of " + ", ".join(json.dumps(c) for c in self.choices)
            return "a string"
        if self.type == "vec3":
            each = f" each in {rng}" if rng else ""
            return f"a list of 3 finite numbers{each}{unit}"
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


# kind name -> dotted key -> spec (the public view of KINDS)
SCHEMAS: dict[str, dict[str, KeySpec]] = {}
# kind name -> full kind description
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
    # Python's bool and NumPy's bool_ (which is not a subclass of it)
    return isinstance(v, bool) or type(v).__name__ == "bool_"


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


def check_value(key: str, spec: KeySpec, value: Any) -> Any:
    """Validate ``value`` for ``key`` and return it normalised (ints -> floats
    for float keys, tuples -> lists); raise SceneError naming key and value."""

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
    if t == "str":
        if not isinstance(value, str) or (spec.choices and value not in spec.choices):
            raise bad()
        return value
    # vectors: exactly 3 finite numbers, each within the bounds
    if t == "vec3":
        if hasattr(value, "tolist") and not isinstance(value, (list, tuple)):
            value = value.tolist()  # a NumPy array of three numbers
        if not isinstance(value, (list, tuple)) or len(value) != 3:
            raise bad()
        for x in value:
            if not _is_number(x) or not math.isfinite(x) or not _in_range(x, spec):
                raise bad()
        return [float(x) for x in value]
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


def _walk(doc: Mapping[str, Any], prefix: str, kind: SceneKind, tables: set[str], out: dict[str, Any]) -> None:
    """Flatten the key tables of ``doc`` into dotted keys, rejecting unknown ones."""
    for name, value in doc.items():
        dotted = f"{prefix}{name}"
        if dotted in kind.keys:
            out[dotted] = check_value(dotted, kind.keys[dotted], value)
        elif dotted in tables:
            if not isinstance(value, Mapping):
                raise SceneError(f"{dotted} must be a table, got {_fmt_value(value)}")
            _walk(value, dotted + ".", kind, tables, out)
        elif isinstance(value, Mapping):
            raise _unknown_table(dotted, kind)
        else:
            raise _unknown_key(dotted, kind)


def _check_array(name: str, entries: Any, kind: SceneKind) -> list[dict[str, Any]]:
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
            item[key] = check_value(f"{where}.{key}", specs[key], value)
        for key in required:
            if key not in item:
                raise SceneError(f"{where}.{key} is missing ({where} must set {', '.join(required)})")
        # fill the rest from defaults, in schema order
        out.append({k: item[k] if k in item else copy.deepcopy(s.default) for k, s in specs.items()})
    return out


def _validate(doc: Mapping[str, Any], kind: SceneKind) -> tuple[dict[str, Any], dict[str, list[dict[str, Any]]]]:
    """Check a parsed document (without its [scene] table) against ``kind``."""
    tables = _tables_of(kind.keys)
    values: dict[str, Any] = {}
    arrays: dict[str, list[dict[str, Any]]] = {name: [] for name in kind.arrays}
    # split the top level into arrays of tables and key tables
    rest = {}
    for name, value in doc.items():
        if name in kind.arrays:
            arrays[name] = _check_array(name, value, kind)
        else:
            rest[name] = value
    _walk(rest, "", kind, tables, values)
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
        self.values, self.arrays = _validate(body, kind)

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
        may not.
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
            node[leaf] = value
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
        raise SceneError(f"--set expects a dotted key before '=', got {_fmt_value(key)} in {_fmt_value(expr)}")
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
# kind: magic8ball (seed 001) — key names are read by the core, keep them
# ---------------------------------------------------------------------------

DEFAULT_ANSWERS = [
    "It is certain",
    "Ask again later",
    "Outlook good",
    "Don't count on it",
    "Signs point to yes",
    "Very doubtful",
]

_K = KeySpec
MAGIC8BALL_KEYS: dict[str, KeySpec] = {
    # run control
    "run.end_time": _K("float", 5.0, "s", 0.0, 1e6, "simulated time at which the run ends", lo_open=True),
    "run.seed": _K("int", 1, "", 0, INT64_MAX, "random seed for the Poisson-disk start"),
    "run.record_every": _K("int", 100, "steps", 1, 10**9, "record a frame every this many steps"),
    # spherical container
    "container.radius": _K("float", 0.15, "m", 0.0, 100.0, "radius of the spherical container", lo_open=True),
    "container.restitution": _K("float", 0.3, "", 0.0, 1.0, "fraction of normal wall velocity kept on contact"),
    "container.friction": _K("float", 0.1, "", 0.0, 1.0, "fraction of tangential wall velocity removed on contact"),
    "container.shell_inertia": _K(
        "float", 0.02, "kg·m²", 0.0, 1e6, "moment of inertia of the ball shell that a shake torque acts on", lo_open=True
    ),
    "container.spin_damping": _K("float", 2.0, "1/s", 0.0, 1e4, "decay rate of the shell's spin"),
    # fluid
    "fluid.particles": _K("int", 3500, "", 200, 2_000_000, "number of fluid particles"),
    "fluid.rest_density": _K("float", 1000.0, "kg/m³", 0.0, 1e5, "rest density of the fluid", lo_open=True),
    "fluid.stiffness": _K("float", 12000.0, "Pa", 0.0, 1e10, "Tait equation-of-state stiffness B", lo_open=True),
    "fluid.gamma": _K("float", 7.0, "", 1.0, 10.0, "Tait equation-of-state exponent"),
    "fluid.viscosity": _K("float", 10.0, "Pa·s", 0.0, 1e5, "dynamic viscosity (viscosity-kernel Laplacian)"),
    "fluid.xsph": _K("float", 0.1, "", 0.0, 1.0, "XSPH velocity smoothing factor"),
    "fluid.density_floor": _K(
        "float", 0.01, "", 0.0, 1.0, "lowest density allowed, as a fraction of rest density", lo_open=True
    ),
    # smoothing length
    "sph.h": _K("float", 0.05, "m", 0.0, 10.0, "SPH smoothing length (kernel support radius)", lo_open=True),
    "sph.scale_h": _K("bool", True, "", doc="scale h with particle count so neighbour counts stay fixed"),
    "sph.reference_particles": _K("int", 3500, "", 1, INT32_MAX, "particle count at which sph.h applies"),
    "sph.skin": _K("float", 0.2, "h", 0.0, 1.0,
                   "neighbour-list skin: lists reach h (1 + skin) and are reused until a particle moved too far; 0 rebuilds every step"),
    # gravity
    "gravity.g": _K("vec3", [0.0, 0.0, -9.81], "m/s²", -1e4, 1e4, "gravitational acceleration"),
    # rigid cube die
    "die.side": _K("float", 0.064, "m", 0.0, 10.0, "edge length of the cube die", lo_open=True),
    "die.density": _K(
        "float", 1000.0, "kg/m³", 0.0, 1e5, "die density (equal to fluid.rest_density = neutrally buoyant)", lo_open=True
    ),
    "die.contact_stiffness": _K(
        "float", 2.0e4, "1/s²", 0.0, 1e9, "spring acceleration per metre of penetration into the contact margin"
    ),
    "die.contact_margin": _K("float", 0.16, "h", 0.0, 5.0, "contact margin around the die, in units of h", lo_open=True),
    "die.drag": _K("float", 20.0, "1/s", 0.0, 1e6, "relative-velocity drag rate on particles in the margin"),
    "die.restitution": _K("float", 0.3, "", 0.0, 1.0, "fraction of normal velocity kept when the die hits the wall"),
    "die.linear_damping": _K("float", 0.0, "1/s", 0.0, 1e4, "linear velocity damping rate of the die"),
    "die.angular_damping": _K("float", 0.0, "1/s", 0.0, 1e4, "angular velocity damping rate of the die"),
    "die.position": _K("vec3", [0.0, 0.0, 0.0], "m", None, None, "initial centre of the die (inside the container)"),
    "die.answers": _K("list[str]", list(DEFAULT_ANSWERS), "", doc="answers printed on faces 1..6", length=6),
    # adaptive time step
    "timestep.dt_min": _K("float", 2e-5, "s", 0.0, 1.0, "smallest time step", lo_open=True),
    "timestep.dt_max": _K("float", 1.5e-3, "s", 0.0, 1.0, "largest time step", lo_open=True),
    "timestep.cfl_advective": _K("float", 0.4, "", 0.0, 1.0, "advective CFL number (h / max speed)", lo_open=True),
    "timestep.cfl_acoustic": _K("float", 0.4, "", 0.0, 1.0, "acoustic CFL number (h / sound speed)", lo_open=True),
    "timestep.cfl_force": _K("float", 0.25, "", 0.0, 1.0, "force limit factor (sqrt(h / max acceleration))", lo_open=True),
    "timestep.cfl_viscous": _K("float", 0.125, "", 0.0, 1.0, "viscous limit factor (h² rho / mu)", lo_open=True),
}
del _K

SHAKE_KEYS: dict[str, KeySpec] = {
    "start": KeySpec("float", 0.0, "s", 0.0, 1e6, "time the shake starts (required)"),
    "end": KeySpec("float", 0.0, "s", 0.0, 1e6, "time the shake ends (required)", lo_open=True),
    "acceleration": KeySpec("vec3", [0.0, 0.0, 0.0], "m/s²", -1e4, 1e4, "container linear acceleration"),
    "torque": KeySpec("vec3", [0.0, 0.0, 0.0], "N·m", -1e6, 1e6, "torque applied to the container shell"),
}


def _die_inside_container(values: dict[str, Any], arrays: dict[str, list[dict[str, Any]]]) -> None:
    """The die's bounding sphere must lie inside the container."""
    p = values["die.position"]
    side = values["die.side"]
    radius = values["container.radius"]
    reach = math.sqrt(sum(x * x for x in p)) + side * math.sqrt(3.0) / 2.0
    if not reach < radius:
        raise SceneError(
            f"die.position must keep the die inside the container (|position| + die.side*sqrt(3)/2 < "
            f"container.radius), got die.position = {_fmt_value(p)}, die.side = {_fmt_value(side)}, "
            f"container.radius = {_fmt_value(radius)}"
        )


register_kind(
    SceneKind(
        name="magic8ball",
        description="3-D SPH fluid in a sphere with a rigid cube die (seed 001)",
        keys=MAGIC8BALL_KEYS,
        arrays={"shake": SHAKE_KEYS},
        required_in_arrays={"shake": ("start", "end")},
        checks=[check_le("timestep.dt_min", "timestep.dt_max"), check_windows("shake"), _die_inside_container],
    )
)
