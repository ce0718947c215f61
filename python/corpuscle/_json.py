"""Strict JSON out: what the command line prints (run, bench, validate, info, polar) and the
live viewer sends. JSON has no NaN or infinity, and strict readers (jq, JavaScript's
JSON.parse, Python's json.loads with parse_constant) reject the ``NaN`` that ``json.dumps``
writes by default: a value that is not a finite number is written as ``null`` (the human-
readable output says why it is missing). NumPy scalars and arrays become plain numbers and
lists; any other object its ``str``."""

from __future__ import annotations

import json
import math
from typing import Any

__all__ = ["finite", "dumps", "dump"]


def finite(obj: Any) -> Any:
    """``obj`` as plain JSON values, NaN and infinities as None (recursively)."""
    if obj is None or isinstance(obj, (bool, str, int)):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k if isinstance(k, (str, int, float, bool)) or k is None else str(k): finite(v)
                for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite(v) for v in obj]
    for attr in ("tolist", "item"):  # NumPy arrays and scalars
        if hasattr(obj, attr):
            return finite(getattr(obj, attr)())
    return str(obj)


def dumps(obj: Any, **kwargs: Any) -> str:
    """``json.dumps`` of :func:`finite` (obj): never ``NaN`` or ``Infinity``."""
    return json.dumps(finite(obj), allow_nan=False, **kwargs)


def dump(obj: Any, fp, **kwargs: Any) -> None:
    """``json.dump`` of :func:`finite` (obj) to a file."""
    json.dump(finite(obj), fp, allow_nan=False, **kwargs)
