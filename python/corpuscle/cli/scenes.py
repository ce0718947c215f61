"""``corpuscle scenes``: the built-in scenes, and with ``--keys`` every key of each kind."""

from __future__ import annotations

import argparse
import importlib
import json

from .. import kinds as _kinds
from ..scene import builtin_scenes
from ._options import EXIT_OK, Command, register


def _configure_scenes(p: argparse.ArgumentParser) -> None:
    p.add_argument("--keys", action="store_true", help="also list every key of each scene kind (type, default, unit, range)")


def _core_kinds() -> dict[str, list[str]]:
    """The core's kinds and their index plug-ins ({} when the core is not built)."""
    try:
        core = importlib.import_module("corpuscle._core")
    except ImportError:
        return {}
    return {str(k): list(v) for k, v in dict(core.kinds()).items()}


def _cmd_scenes(args: argparse.Namespace) -> int:
    # built-in scenes, one a line
    scenes = builtin_scenes()
    width = max((len(n) for n, _ in scenes), default=4)
    for name, description in scenes:
        print(f"{name:<{width}}  {description}")
    if not args.keys:
        return EXIT_OK
    # the schema of every kind, for --set
    for kind_name, registered in _kinds.registry().items():
        kind = registered.schema
        keys = kind.keys
        print(f"\nkind {kind_name}: {kind.description}")
        indexes = _core_kinds().get(kind_name)
        if indexes:
            print(f"  --neighbors: {', '.join(indexes)} (default {indexes[0]})")
        kw = max(len(k) for k in keys)
        for key, spec in keys.items():
            default = json.dumps(spec.default, ensure_ascii=False)
            rng = spec.interval()
            unit = spec.unit
            print(f"  {key:<{kw}}  {spec.type:<9} {default:<22} {unit:<7} {rng:<20} {spec.doc}")
        for array, specs in kind.arrays.items():
            print(f"  [[{array}]] (repeatable; `--set {array}=[{{...}}, ...]` replaces them all)")
            for key, spec in specs.items():
                default = json.dumps(spec.default, ensure_ascii=False)
                print(f"    {key:<{kw - 2}}  {spec.type:<9} {default:<22} {spec.unit:<7} {spec.interval():<20} {spec.doc}")
    return EXIT_OK


register(Command("scenes", "list the built-in scenes", _configure_scenes, _cmd_scenes))
