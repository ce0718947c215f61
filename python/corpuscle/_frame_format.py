"""The frame stream's format (docs/frame_format.md): its constants, limits and errors, and the
small encoders both the writer (corpuscle.io) and the reader (corpuscle._frame_reader) use."""

from __future__ import annotations

import json
import math
import re
import struct

import numpy as np

# format constants (docs/frame_format.md, "Constants")
FORMAT_VERSION = 1
FILE_MAGIC = b"\x89CPS\r\n\x1a\n"
FRAME_MAGIC = b"CPSFRAME"
ALIGN = 64

# fixed parts: file header (32 bytes) and frame header (64 bytes), little-endian
_FILE_HEAD = struct.Struct("<8sIIQII")
_FRAME_HEAD = struct.Struct("<8sQQqddIHHII")
assert _FILE_HEAD.size == 32 and _FRAME_HEAD.size == ALIGN

# frame kinds as stored in the frame header
_KIND_CODES = {"frame": 0, "checkpoint": 1}
_KIND_NAMES = {code: name for name, code in _KIND_CODES.items()}

# the array dtypes the stream carries, exactly as written in frame tables (NumPy's
# ``dtype.str``): bool, signed and unsigned integers, IEEE floats and complex numbers.
# Platform-dependent types (long double) are refused: their bytes mean different things
# on different machines.
DTYPES = ("|b1", "|i1", "|u1", "<i2", "<i4", "<i8", "<u2", "<u4", "<u8",
          "<f2", "<f4", "<f8", "<c8", "<c16")
_RESERVED_SERIES = ("step", "time", "dt")
_ZEROS = bytes(ALIGN)

# limits on what a reader accepts (and a writer writes), so a crafted file cannot make the
# reader recurse, allocate or loop without bound (docs/frame_format.md, "Limits")
MAX_JSON_DEPTH = 32             # nesting of arrays and objects in the header JSON and tables
MAX_HEADER_JSON = 64 << 20      # bytes of header JSON
MAX_TABLE_JSON = 16 << 20       # bytes of one frame's JSON table
MAX_NDIM = 32                   # dimensions of one array
MAX_ARRAY_EXTENT = 1 << 62      # product of an array's non-zero dimensions times its item size
_DIAGNOSTIC_STRINGS = ("nan", "inf", "-inf")

# a JSON string literal (escapes included), for measuring nesting outside strings
_JSON_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.S)


class FrameStreamError(ValueError):
    """A file is not a readable corpuscle frame stream, or one of its frames is corrupted.

    ``frame`` is the index of the offending frame, or ``None`` for file-level problems.
    """

    def __init__(self, message: str, frame: int | None = None):
        super().__init__(message)
        self.frame = frame


class TruncatedRunWarning(UserWarning):
    """A run file ends inside a frame (e.g. a crash mid-write); its whole frames were read."""


def _first_line(exc: BaseException) -> str:
    """An exception's message on one line (its first), or its type's name."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _align(n: int) -> int:
    """Round ``n`` up to the next multiple of ``ALIGN``."""
    return -(-n // ALIGN) * ALIGN


def _json_default(obj):
    """Let NumPy scalars and arrays into the JSON header."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"object of type {type(obj).__name__} is not JSON serialisable")


def _encode_scalar(value: float):
    """A float as JSON: non-finite values become the strings "nan", "inf", "-inf"."""
    return value if math.isfinite(value) else repr(value)


def _decode_scalar(value) -> float:
    """Inverse of ``_encode_scalar``: a JSON number, or "nan", "inf", "-inf"."""
    if isinstance(value, str):
        if value not in _DIAGNOSTIC_STRINGS:
            raise ValueError(f"not a diagnostic value: {value!r}")
        return float(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"not a diagnostic value: {value!r}")
    return float(value)


def _json_depth(raw: bytes) -> int:
    """Deepest nesting of arrays and objects in JSON text (brackets inside strings ignored)."""
    bare = np.frombuffer(_JSON_STRING.sub(b"", raw), dtype=np.uint8)
    if bare.size == 0:
        return 0
    step = ((bare == 0x5B) | (bare == 0x7B)).astype(np.int64) - ((bare == 0x5D) | (bare == 0x7D))
    return int(np.cumsum(step).max(initial=0))


def _reject_constant(name: str):
    """json.loads hook: NaN and Infinity are not JSON (RFC 8259)."""
    raise ValueError(f"{name} is not valid JSON")


def _load_json(raw: bytes):
    """Strict, bounded JSON: UTF-8, at most MAX_JSON_DEPTH deep, no NaN/Infinity literals.

    Raises ValueError (with a short reason) for anything else.
    """
    depth = _json_depth(raw)
    if depth > MAX_JSON_DEPTH:
        raise ValueError(f"JSON nested {depth} deep, more than {MAX_JSON_DEPTH}")
    try:
        return json.loads(raw.decode("utf-8"), parse_constant=_reject_constant)
    except RecursionError:  # not reachable under the depth limit; kept as a last guard
        raise ValueError("JSON nested too deep") from None


def _check_shape(shape, itemsize: int) -> tuple | None:
    """``shape`` as a tuple if it is a valid array shape for the stream, else None.

    Valid: a list of 1..MAX_NDIM non-negative integers whose non-zero entries, multiplied
    together and by ``itemsize``, stay within MAX_ARRAY_EXTENT.
    """
    if not isinstance(shape, (list, tuple)) or not 1 <= len(shape) <= MAX_NDIM:
        return None
    extent = itemsize
    for d in shape:
        if type(d) is not int or d < 0:
            return None
        extent *= max(d, 1)
        if extent > MAX_ARRAY_EXTENT:
            return None
    return tuple(shape)


def _as_le_array(value, what: str, dtype=None) -> np.ndarray:
    """``value`` as a C-contiguous little-endian array of a carried dtype."""
    arr = np.asarray(value, dtype=dtype)
    if arr.ndim == 0:
        raise ValueError(f"{what} must be an array with at least one dimension, got a scalar")
    le = arr.dtype.newbyteorder("<") if arr.dtype.kind in "biufc" else arr.dtype
    if le.str not in DTYPES:
        raise TypeError(f"{what} has unsupported dtype {arr.dtype} (carried: bool, 8- to 64-bit "
                        "integers, float16/32/64, complex64/128)")
    if _check_shape([int(d) for d in arr.shape], le.itemsize) is None:
        raise ValueError(f"{what} has shape {arr.shape}: at most {MAX_NDIM} dimensions "
                         f"and {MAX_ARRAY_EXTENT} bytes are carried")
    return np.ascontiguousarray(arr, dtype=le)
