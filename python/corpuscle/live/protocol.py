"""The live viewer's wire protocol (no server library needed: tests and the benchmark use it).

Server -> page, over one websocket:

1. one text message, JSON: ``{"type": "hello", "mode": "live"|"view", "header": <run header>,
   "scene": <the header's geometry checked and normalised (render's ``scene_info``), or null>,
   "fields": [colourable field names], "color": <the field the page colours by at first: the
   kind's choice from the header's ``render`` entry, else density>, "controls": {name: length},
   "limits": {name: max norm},
   "control": {name: current values}, "sliders": [the kind's sliders, ``Kind.live_controls``],
   "frames": <recorded frames, view mode>, "paused": bool, "max_message": bytes}``;
2. then binary frames, each: a 48-byte little-endian header (:data:`HEAD`: magic ``CPSL``,
   version, flags, frame index, step, time, particle count, dimension, JSON length, colour
   bytes per particle), the JSON overlay (diagnostics, the kind's result, rigid poses, the
   quantisation box ``lo``/``hi``, the colour field and its range) padded to 4 bytes, the
   positions as uint16 ``count x dim`` (``x = lo + q / 65535 * (hi - lo)``, padded to 4
   bytes), then the colour field as uint8 (``0`` = its ``range[0]``, ``255`` = ``range[1]``)
   when the colour byte count is 1.

Page -> server: JSON text, at most :data:`MAX_MESSAGE` bytes: ``{"type": "control", <control
name>: [numbers], ...}`` (one or more of the run's controls; a control not named keeps its
value), ``{"type": "pause"}``, ``{"type": "resume"}``, ``{"type": "color", "field":
name|null}``, ``{"type": "ready"}`` (the page drew a frame: flow control, at most
``server.CREDITS`` frames are sent ahead of the page's drawing once it says it) and, for a
recorded run, ``{"type": "seek", "frame": i}``. :func:`parse_message`
checks one (size, JSON, type, exactly the keys the type takes, a control's length, finite
numbers, its norm bound and its sliders' range) and raises :class:`MessageError` naming what is
wrong.
"""
from __future__ import annotations

import json
import math
import struct
from typing import Any

import numpy as np

from .. import _json

MAGIC = b"CPSL"
VERSION = 1
HEAD = struct.Struct("<4sIIIqdIIII")  # magic, version, flags, index, step, time, n, dim, json_len, color_bytes
QMAX = 65535
MAX_MESSAGE = 4096  # bytes: larger messages from the page are rejected
# bounds on the norm of each control the page may send (others: DEFAULT_LIMIT)
LIMITS = {"acceleration": 200.0, "torque": 10.0}
DEFAULT_LIMIT = 1000.0


class MessageError(ValueError):
    """A message from the page that is rejected (the reason is one line)."""


def _pad4(n: int) -> int:
    return (-n) % 4


def dumps(obj: Any) -> str:
    return _json.dumps(obj)  # NaN and infinities as null (JSON has neither)


def domain_box(header: dict[str, Any], positions: np.ndarray | None = None) -> tuple[list[float], list[float]]:
    """The box positions are quantised in: the container's (with a 2 % margin), else the
    positions' own bounds."""
    dim = int(header.get("dim") or (positions.shape[1] if positions is not None and positions.ndim == 2 else 3))
    c = header.get("container") or {}
    try:
        if c.get("type") == "sphere":
            centre = np.asarray(c["center"], dtype=np.float64)[:dim]
            r = float(c["radius"]) * 1.02
            return (centre - r).tolist(), (centre + r).tolist()
        if c.get("type") == "box":
            lo, hi = np.asarray(c["min"], dtype=np.float64)[:dim], np.asarray(c["max"], dtype=np.float64)[:dim]
            pad = 0.02 * (hi - lo)
            return (lo - pad).tolist(), (hi + pad).tolist()
    except (KeyError, TypeError, ValueError):
        pass
    if positions is not None and len(positions):
        lo, hi = positions.min(axis=0).astype(np.float64), positions.max(axis=0).astype(np.float64)
        pad = np.maximum(1e-9, 0.02 * (hi - lo))
        return (lo - pad).tolist(), (hi + pad).tolist()
    return [-1.0] * dim, [1.0] * dim


def quantise(positions: np.ndarray, lo, hi) -> np.ndarray:
    """uint16 coordinates in the box [lo, hi] (clipped to it)."""
    lo = np.asarray(lo, dtype=np.float32)
    span = np.maximum(np.asarray(hi, dtype=np.float32) - lo, np.float32(1e-30))
    q = (np.asarray(positions, dtype=np.float32) - lo) * (np.float32(QMAX) / span)
    np.clip(q, 0, QMAX, out=q)
    q += np.float32(0.5)
    return q.astype(np.uint16)


def dequantise(q: np.ndarray, lo, hi) -> np.ndarray:
    lo = np.asarray(lo, dtype=np.float64)
    return lo + q.astype(np.float64) / QMAX * (np.asarray(hi, dtype=np.float64) - lo)


def color_bytes(values: np.ndarray, vrange: tuple[float, float] | None = None) -> tuple[np.ndarray, list[float]]:
    """A field as uint8 over its range (the 1st to 99th percentile of a sample by default)."""
    v = np.asarray(values, dtype=np.float32).reshape(len(values), -1)
    if v.shape[1] > 1:
        v = np.sqrt(np.einsum("ij,ij->i", v, v))
    else:
        v = v[:, 0]
    if vrange is None:
        sample = v[:: max(1, len(v) // 20000)]
        sample = sample[np.isfinite(sample)]
        lo, hi = (np.percentile(sample, [1, 99]).tolist() if sample.size else [0.0, 1.0])
        if not hi > lo:
            hi = lo + 1.0
    else:
        lo, hi = vrange
    c = (v - np.float32(lo)) * np.float32(255.0 / (hi - lo))
    np.nan_to_num(c, copy=False, nan=0.0)
    np.clip(c, 0, 255, out=c)
    return c.astype(np.uint8), [float(lo), float(hi)]


def encode_frame(index: int, step: int, time: float, positions: np.ndarray, lo, hi,
                 overlay: dict[str, Any] | None = None, color: np.ndarray | None = None) -> bytes:
    """One binary frame message (see the module docstring)."""
    pos = np.asarray(positions)
    n = int(pos.shape[0]) if pos.ndim else 0
    dim = int(pos.shape[1]) if pos.ndim == 2 else len(lo)
    meta = dict(overlay or {}, lo=list(lo), hi=list(hi))
    raw = dumps(meta).encode()
    raw += b" " * _pad4(len(raw))
    q = quantise(pos.reshape(n, dim), lo, hi).tobytes() if n else b""
    q += b"\0" * _pad4(len(q))
    cbytes = 0 if color is None else 1
    head = HEAD.pack(MAGIC, VERSION, 0, int(index), int(step), float(time), n, dim, len(raw), cbytes)
    parts = [head, raw, q]
    if color is not None:
        parts.append(np.asarray(color, dtype=np.uint8).tobytes())
    return b"".join(parts)


def decode_frame(data: bytes) -> dict[str, Any]:
    """The inverse of :func:`encode_frame` (positions dequantised to float64)."""
    if len(data) < HEAD.size:
        raise ValueError("frame message shorter than its header")
    magic, version, _flags, index, step, time, n, dim, jlen, cbytes = HEAD.unpack_from(data)
    if magic != MAGIC:
        raise ValueError(f"bad frame magic {magic!r}")
    off = HEAD.size
    meta = json.loads(bytes(data[off:off + jlen]))
    off += jlen
    q = np.frombuffer(data, dtype="<u2", count=n * dim, offset=off).reshape(n, dim)
    off += n * dim * 2 + _pad4(n * dim * 2)
    color = np.frombuffer(data, dtype=np.uint8, count=n, offset=off) if cbytes else None
    return {"index": index, "step": step, "time": time, "count": n, "dim": dim, "meta": meta,
            "quantised": q, "positions": dequantise(q, meta["lo"], meta["hi"]), "color": color,
            "version": version}


def slider_ranges(sliders: list[dict[str, Any]] | None) -> dict[str, list[tuple[float, float]]]:
    """The range of each control component a slider sets (control = scale * value + offset
    over the slider's [min, max]); components no slider sets are unbounded here."""
    out: dict[str, list[tuple[float, float]]] = {}
    for sl in sliders or []:
        name, i = str(sl["control"]), int(sl.get("index", 0))
        a, b = (float(sl.get("scale", 1.0)) * float(sl[k]) + float(sl.get("offset", 0.0)) for k in ("min", "max"))
        rng = out.setdefault(name, [])
        while len(rng) <= i:
            rng.append((-math.inf, math.inf))
        rng[i] = (min(a, b), max(a, b))
    return out


def parse_message(raw: str | bytes, controls: dict[str, int], fields: list[str] | None = None,
                  frames: int | None = None, limits: dict[str, float] | None = None,
                  ranges: dict[str, list[tuple[float, float]]] | None = None) -> dict[str, Any]:
    """One message from the page, checked: size, JSON object, known type, exactly the keys
    the type takes, finite numbers of the control's length within its norm bound (``limits``)
    and its components' ranges (``ranges``, :func:`slider_ranges`). Returns the message (a
    control message: only the controls it names); raises :class:`MessageError`."""
    if isinstance(raw, (bytes, bytearray, memoryview)):
        raise MessageError("binary message (only JSON text is accepted)")
    if len(raw) > MAX_MESSAGE or len(raw.encode("utf-8", "surrogatepass")) > MAX_MESSAGE:
        raise MessageError(f"message of {len(raw.encode('utf-8', 'surrogatepass'))} bytes (at most {MAX_MESSAGE})")
    try:
        msg = json.loads(raw, parse_constant=lambda c: (_ for _ in ()).throw(MessageError(f"non-finite number {c}")))
    except MessageError:
        raise
    except (ValueError, RecursionError) as exc:
        raise MessageError(f"not JSON ({' '.join(str(exc).split())[:80]})") from None
    if not isinstance(msg, dict):
        raise MessageError(f"not a JSON object ({type(msg).__name__})")
    kind = msg.get("type")
    limits = dict(LIMITS, **(limits or {}))

    def keys(allowed: set[str]) -> None:
        extra = sorted(set(msg) - allowed - {"type"})
        if extra:
            raise MessageError(f"{kind} message: unknown key {extra[0][:40]!r}")

    if kind in ("pause", "resume", "ready"):
        keys(set())
        return {"type": kind}
    if kind == "control":
        keys(set(controls))
        if len(msg) == 1:
            raise MessageError("control message names no control")
        out: dict[str, Any] = {"type": "control"}
        for name, length in controls.items():
            if name not in msg:
                continue
            value = msg[name]
            if (not isinstance(value, list) or len(value) != length
                    or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value)):
                raise MessageError(f"control {name!r} must be a list of {length} numbers")
            vec = [float(x) for x in value]
            if not all(math.isfinite(x) for x in vec):
                raise MessageError(f"control {name!r} has a non-finite number")
            bound = float(limits.get(name, DEFAULT_LIMIT))
            if math.sqrt(sum(x * x for x in vec)) > bound:
                raise MessageError(f"control {name!r} has norm above {bound:g}")
            for i, (x, (lo, hi)) in enumerate(zip(vec, (ranges or {}).get(name, []))):
                if not lo - 1e-9 * abs(lo) <= x <= hi + 1e-9 * abs(hi):
                    raise MessageError(f"control {name!r}[{i}] = {x:.6g} is outside [{lo:.6g}, {hi:.6g}]")
            out[name] = vec
        return out
    if kind == "color":
        keys({"field"})
        if "field" not in msg:
            raise MessageError("color message without its field (a name, or null for none)")
        field = msg["field"]
        if field is not None and (not isinstance(field, str) or field not in (fields or [])):
            raise MessageError(f"color: unknown field {str(field)[:40]!r}")
        return {"type": "color", "field": field}
    if kind == "seek" and frames is not None:
        keys({"frame"})
        i = msg.get("frame")
        if not isinstance(i, int) or isinstance(i, bool) or not 0 <= i < frames:
            raise MessageError(f"seek: frame must be an integer in [0, {frames})")
        return {"type": "seek", "frame": i}
    raise MessageError(f"unknown message type {str(kind)[:40]!r}")
