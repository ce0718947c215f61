"""Scenes: TOML files validated against a schema per scene kind.

A scene file has a ``[scene]`` table whose ``kind`` selects the schema, then one
table per group of keys (``[fluid]``, ``[die]``, ...) and, for kinds that have them,
arrays of tables such as ``[[shake]]``. Every key of a kind is declared once, with its
type, default, unit, valid range and a one-line doc, by the kind's module in
``corpuscle/kinds/`` (see :mod:`corpuscle.kinds`) against :mod:`corpuscle.schema`, which
holds :class:`KeySpec`, :class:`SceneKind` and the registry :data:`KINDS` / :data:`SCHEMAS`
(its names are importable from here too); this module is the loader and validator of a
whole scene file. A missing
key takes its default, anything else is an error. Errors are :class:`SceneError` with a
one-line message naming the key and the bad value.

Built-in scenes ship in ``corpuscle/scenes/*.toml``::

    scene = load_scene("magic8ball", {"fluid.particles": 20000})
    scene["sph.h"], scene.shakes, scene.to_dict()

A new kind is a module in ``corpuscle/kinds/`` (which registers its schema through
:func:`register_kind`); a schema alone, without a simulation, can be registered with
:func:`register_kind` directly (tests do).
"""

from __future__ import annotations

import copy
import os
import pathlib
import re
import tomllib
from importlib import resources
from typing import Any, Iterable, Mapping

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

from . import kinds as _kinds  # noqa: F401  (imports every kind, which registers its schema)
from ._files import SCENE_FILE_BYTES, read_bounded
from .schema import (  # noqa: F401  (the schema's public names are this module's too)
    INT32_MAX, INT64_MAX, KINDS, SCENE_TABLE_KEYS, SCHEMAS, VALUE_TYPES, CrossCheck, KeySpec, SceneError, SceneKind,
    _fmt_value, _suggest, check_le, check_value, check_windows, register_kind)


# ---------------------------------------------------------------------------
# validation of a whole document
# ---------------------------------------------------------------------------

#: arrays and tables nest at most this deep in a scene (the deepest key of a kind is a few
#: levels: a [[shake]] entry's vector is 3); deeper is refused before anything walks it
MAX_NESTING = 32


def _nesting_error(where: str) -> SceneError:
    return SceneError(f"{where} nests arrays or tables more than {MAX_NESTING} levels deep")


def check_nesting(value: Any, where: str) -> None:
    """Refuse ``value`` nested more than :data:`MAX_NESTING` levels of arrays or tables
    (walked without recursion, so any depth gives this one-line SceneError, never a
    RecursionError from a later copy, walk or repr)."""
    stack = [(value, 0)]
    while stack:
        node, depth = stack.pop()
        if isinstance(node, Mapping):
            children = node.values()
        elif isinstance(node, (list, tuple)):
            children = node
        else:
            continue
        if depth >= MAX_NESTING:
            raise _nesting_error(where)
        stack.extend((c, depth + 1) for c in children)


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


def _check_array_size(name: str, entries: Any, kind: SceneKind) -> None:
    """At most ``kind.max_in_arrays[name]`` entries (the core's capacity): checked before
    any entry is validated, walked or copied."""
    most = kind.max_in_arrays.get(name)
    if most is not None and isinstance(entries, (list, tuple)) and len(entries) > most:
        raise SceneError(f"{name}: {len(entries):,} [[{name}]] entries, at most {most}")


def _check_array(name: str, entries: Any, kind: SceneKind,
                 base: str | os.PathLike | None = None) -> list[dict[str, Any]]:
    """Validate an array of tables (``[[shake]]``); entries are numbered from 1."""
    specs = kind.arrays[name]
    required = kind.required_in_arrays.get(name, ())
    if not isinstance(entries, (list, tuple)):
        raise SceneError(f"{name} must be an array of tables ([[{name}]]), got {_fmt_value(entries)}")
    _check_array_size(name, entries, kind)
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
        kind, self.name, self.description = _scene_table(doc, fallback_name)
        for name in kind.arrays:  # the cheap limits first: before anything walks or copies the document
            _check_array_size(name, doc.get(name), kind)
        check_nesting(doc, "the scene")
        # the raw document is kept so overrides re-validate everything together
        self._doc = copy.deepcopy(dict(doc))
        self.path = path
        self.builtin = builtin
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
            if key in kind.arrays:
                _check_array_size(key, value, kind)
            check_nesting(value, key)
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
        doc = tomllib.loads(data.decode("utf-8"))
    except RecursionError:
        raise SceneError(f"cannot read scene file {label}: it nests arrays or tables more than {MAX_NESTING} "
                         f"levels deep") from None
    except UnicodeDecodeError as exc:
        raise SceneError(f"cannot read scene file {label}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"cannot read scene file {label}: {exc}") from None
    check_nesting(doc, f"scene file {label}")
    return doc


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
        data = read_bounded(path, SCENE_FILE_BYTES, "a scene file")
    except ValueError as exc:  # past the bound
        raise SceneError(f"cannot read scene file {exc}") from None
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
        value = tomllib.loads(f"v = {raw}")["v"]
    except RecursionError:
        raise _nesting_error(f"--set {key}") from None
    except tomllib.TOMLDecodeError:
        pass
    else:
        check_nesting(value, f"--set {key}")
        return key, value
    # bare words fall back to strings; broken structured values are errors
    if raw[0] in "[{\"'":
        raise SceneError(f"--set {key}: cannot parse {_fmt_value(raw)} as a TOML value")
    return key, raw
