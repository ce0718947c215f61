"""Recorded runs: the append-only, checksummed, memory-mapped frame stream (``.cps``).

A run file is a file header (JSON scene description) followed by frames. Each frame
carries step, time, dt, named per-particle fields in particle groups, rigid-body poses,
scalar diagnostics and two CRC-32 checksums. Every array starts on a 64-byte boundary,
so the reader hands out read-only NumPy views on a memory map instead of copies.
The byte layout is specified in ``docs/frame_format.md``.

Writing::

    with FrameWriter("run.cps", {"scene": "dam_break", "dim": 3}) as w:
        w.write_frame(step, t, dt, {"position": x, "density": rho, "ghost_position": g},
                      groups={"ghost_position": "ghost"},
                      rigid={"die": {"position": p, "orientation": q}},
                      diagnostics={"kinetic_energy": ke})

Reading::

    with corpuscle.open("run.cps") as run:
        x = run[-1]["position"]            # float32 (n, 3) view, no copy
        ke = run.series("kinetic_energy")  # one value per frame
        cp = run.last_checkpoint()         # the state to resume from, or None

Resuming (a torn tail left by a crash is cut off; indices continue)::

    with FrameWriter.append("run.cps", keep=cp.index + 1) as w:
        w.write_frame(...)

The reader bounds what it accepts (JSON nesting and lengths, array shapes, table contents;
``docs/frame_format.md``, "Limits"), so a crafted file raises ``FrameStreamError``, never a
``RecursionError`` or an unbounded allocation.
"""

from __future__ import annotations

import builtins
import json
import math
import mmap
import operator
import os
import re
import stat
import struct
import warnings
import zlib

import numpy as np

__all__ = [
    "FORMAT_VERSION",
    "Frame",
    "FrameStreamError",
    "FrameWriter",
    "Run",
    "TruncatedRunWarning",
    "open",
]

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


class FrameWriter:
    """Append frames to a new run file (``.cps``), or to an existing one (``append``).

    ``header`` is a JSON-serialisable dict describing the run (scene name, dim, backend,
    parameters, container geometry, rigid body descriptions ...); NumPy scalars and arrays
    in it are converted to JSON numbers and lists. The file header is written and handed
    to the operating system at once. Each frame is then appended with a single ``write()``,
    so a reader, or a crash, sees only whole frames plus at most one partial frame at the
    end, which the reader drops with a ``TruncatedRunWarning``.

    An existing file at ``path`` is replaced. Use as a context manager, or call ``close()``.
    ``header`` (attribute) is the header as a reader will see it (after the JSON round trip).
    """

    def __init__(self, path, header: dict):
        self.path = os.fspath(path)
        self._file = None
        # the header must be a JSON object
        if not isinstance(header, dict):
            raise TypeError(f"{self.path}: header must be a dict, got {type(header).__name__}")
        # encode the header before creating the file, so a bad header leaves nothing behind
        try:
            body = json.dumps(header, default=_json_default, allow_nan=False,
                              ensure_ascii=False, separators=(",", ":")).encode("utf-8")
        except (TypeError, ValueError) as exc:
            raise type(exc)(f"{self.path}: header is not JSON-serialisable: {exc}") from None
        except RecursionError:
            raise ValueError(f"{self.path}: header is nested too deep") from None
        # what a reader accepts: bounded size and nesting
        if len(body) > MAX_HEADER_JSON:
            raise ValueError(f"{self.path}: header JSON is {len(body)} bytes, more than the "
                             f"{MAX_HEADER_JSON} a reader accepts")
        depth = _json_depth(body)
        if depth > MAX_JSON_DEPTH:
            raise ValueError(f"{self.path}: header is nested {depth} deep, more than the "
                             f"{MAX_JSON_DEPTH} a reader accepts")
        self.header = json.loads(body)
        # fixed part, JSON, zero padding to the first frame; the CRC covers all but itself
        first = _align(_FILE_HEAD.size + len(body))
        pad = _ZEROS[: first - _FILE_HEAD.size - len(body)]
        fixed = _FILE_HEAD.pack(FILE_MAGIC, FORMAT_VERSION, 0, len(body), 0, 0)[:28]
        crc = zlib.crc32(pad, zlib.crc32(body, zlib.crc32(fixed)))
        # unbuffered: every write goes straight to the operating system
        self._file = builtins.open(self.path, "wb", buffering=0)
        self._end = 0
        self._count = 0
        try:
            self._write_all(b"".join((fixed, struct.pack("<I", crc), body, pad)))
        except BaseException:
            # not even the header fits (a full disk): leave no empty, unreadable file behind
            self._file.close()
            if stat.S_ISREG(os.stat(self.path).st_mode):
                os.unlink(self.path)
            raise

    @classmethod
    def append(cls, path, *, keep: int | None = None) -> "FrameWriter":
        """Open an existing run file to append frames to it (e.g. to resume a run).

        Checks the file header and every frame (headers, tables and data checksums), cuts a
        torn tail (a partial last frame left by a crash) back to the last whole frame, and
        continues the frame indices from there. The header JSON is kept unchanged and is
        ``.header``. ``keep``: keep only the first ``keep`` frames and cut the rest (e.g.
        ``run.last_checkpoint().index + 1`` to resume from a checkpoint).

        Raises ``FrameStreamError`` (one line) when the file is not a frame stream, or when
        any frame before the torn tail (before ``keep``) is corrupted; the file is then
        left as it was.
        """
        path = os.fspath(path)
        # index and check the file with the reader; a torn tail is expected here, not warned
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", TruncatedRunWarning)
            run = Run(path)
        try:
            if run.version != FORMAT_VERSION:
                raise FrameStreamError(f"{path}: cannot append version-{FORMAT_VERSION} frames to "
                                       f"a version-{run.version} file")
            n = len(run)
            if keep is not None:
                keep = operator.index(keep)
                if not 0 <= keep <= n:
                    raise ValueError(f"{path}: keep must be in 0..{n} (the whole frames), got {keep}")
                n = keep
            # every kept frame must be whole and intact: headers, tables, data checksums
            for i in range(n):
                run._check_frame(i)
            end = run._entries[n - 1].offset + run._entries[n - 1].frame_len if n else run._first
            header = run.header
        finally:
            run.close()
        # cut what follows the last kept frame, then continue after it
        self = cls.__new__(cls)
        self.path, self.header, self._count, self._end = path, header, n, end
        self._file = builtins.open(path, "r+b", buffering=0)
        try:
            if os.fstat(self._file.fileno()).st_size != end:
                os.ftruncate(self._file.fileno(), end)
                os.fsync(self._file.fileno())
            self._file.seek(end)
        except BaseException:
            self._file.close()
            raise
        return self

    @property
    def frames_written(self) -> int:
        """Number of frames written so far."""
        return self._count

    def write_frame(self, step: int, time: float, dt: float, fields: dict,
                    groups: dict | None = None, rigid: dict | None = None,
                    diagnostics: dict | None = None, kind: str = "frame") -> None:
        """Append one frame.

        fields: name -> array (any shape with at least one dimension; bool, integer,
            float or complex dtype; stored little-endian with dtype and shape kept).
        groups: field name -> particle group name; fields not named here are in "fluid".
            All fields of one group must have the same length (first dimension), which
            becomes the group's count. Non-particle arrays of a checkpoint (rng state ...)
            go in a group of their own.
        rigid: body name -> {"position": (3,) or (2,), "orientation": (4,) quaternion
            w, x, y, z or (1,) angle in 2D, and optionally "velocity", "angular_velocity"
            or any other array}; stored as float64.
        diagnostics: name -> float, for time series (NaN and infinities allowed).
        kind: "frame", or "checkpoint" for a frame carrying the full state to resume from.
        """
        self._check_open()
        # validate the scalar header values
        if kind not in _KIND_CODES:
            raise ValueError(f"{self.path}: kind must be 'frame' or 'checkpoint', got {kind!r}")
        step, time, dt = operator.index(step), float(time), float(dt)
        groups = dict(groups or {})
        unknown = [name for name in groups if name not in fields]
        if unknown:
            raise ValueError(f"{self.path}: groups names fields that are not in fields: {unknown}")

        # lay out particle fields, deriving each group's count from its first field
        arrays, field_specs, counts, first_of = [], [], {}, {}
        offset = 0
        for name, value in fields.items():
            if not isinstance(name, str) or not name:
                raise TypeError(f"{self.path}: field names must be non-empty strings, got {name!r}")
            group = groups.get(name, "fluid")
            if not isinstance(group, str) or not group:
                raise TypeError(f"{self.path}: group of field {name!r} must be a non-empty string")
            arr = _as_le_array(value, f"{self.path}: field {name!r}")
            if group in counts and arr.shape[0] != counts[group]:
                raise ValueError(f"{self.path}: field {name!r} has {arr.shape[0]} rows but group "
                                 f"{group!r} has {counts[group]} (from field {first_of[group]!r})")
            counts.setdefault(group, arr.shape[0])
            first_of.setdefault(group, name)
            field_specs.append({"name": name, "group": group, "dtype": arr.dtype.str,
                                "shape": list(arr.shape), "offset": offset})
            arrays.append(arr)
            offset = _align(offset + arr.nbytes)

        # lay out rigid-body arrays after the fields, all float64
        rigid_specs = {}
        for body, state in (rigid or {}).items():
            if not isinstance(body, str) or not body:
                raise TypeError(f"{self.path}: rigid body names must be non-empty strings, got {body!r}")
            if not isinstance(state, dict) or "position" not in state or "orientation" not in state:
                raise ValueError(f"{self.path}: rigid body {body!r} needs a dict with "
                                 "'position' and 'orientation'")
            specs = {}
            for key, value in state.items():
                arr = _as_le_array(np.atleast_1d(np.asarray(value, dtype=np.float64)),
                                   f"{self.path}: rigid body {body!r} {key!r}", dtype="<f8")
                specs[key] = {"dtype": arr.dtype.str, "shape": list(arr.shape), "offset": offset}
                arrays.append(arr)
                offset = _align(offset + arr.nbytes)
            # check pose shapes: (3,) or (2,) position, (4,) quaternion or (1,) angle
            if specs["position"]["shape"] not in ([2], [3]):
                raise ValueError(f"{self.path}: rigid body {body!r} position must have shape (3,) "
                                 f"or (2,), got {tuple(specs['position']['shape'])}")
            if specs["orientation"]["shape"] not in ([1], [4]):
                raise ValueError(f"{self.path}: rigid body {body!r} orientation must have shape "
                                 f"(4,) or (1,), got {tuple(specs['orientation']['shape'])}")
            rigid_specs[body] = specs

        # diagnostics are floats in the frame's JSON table
        diag = {}
        for name, value in (diagnostics or {}).items():
            if not isinstance(name, str) or not name:
                raise TypeError(f"{self.path}: diagnostic names must be non-empty strings, got {name!r}")
            if name in _RESERVED_SERIES:
                raise ValueError(f"{self.path}: diagnostic name {name!r} is reserved "
                                 "(every frame carries step, time and dt)")
            try:
                diag[name] = _encode_scalar(float(value))
            except (TypeError, ValueError):
                raise TypeError(f"{self.path}: diagnostic {name!r} must be a float, "
                                f"got {value!r}") from None

        # the frame's JSON table of contents
        meta = json.dumps({"groups": counts, "fields": field_specs, "rigid": rigid_specs,
                           "diagnostics": diag}, allow_nan=False, ensure_ascii=False,
                          separators=(",", ":")).encode("utf-8")
        if len(meta) > MAX_TABLE_JSON:
            raise ValueError(f"{self.path}: the frame's table is {len(meta)} bytes of JSON, more than "
                             f"the {MAX_TABLE_JSON} a reader accepts (too many fields or bodies)")
        data_start = _align(ALIGN + len(meta))
        frame_len = data_start + offset

        # data region: padding after the table, then each array padded to 64 bytes
        parts = [_ZEROS[: data_start - ALIGN - len(meta)]]
        for arr in arrays:
            parts.append(arr.reshape(-1).view(np.uint8))
            parts.append(_ZEROS[: _align(arr.nbytes) - arr.nbytes])
        data_crc = 0
        for part in parts:
            data_crc = zlib.crc32(part, data_crc)

        # frame header; its CRC covers bytes 0..59 and the JSON table
        head = _FRAME_HEAD.pack(FRAME_MAGIC, frame_len, self._count, step, time, dt,
                                len(meta), _KIND_CODES[kind], 0, data_crc, 0)[:60]
        head_crc = zlib.crc32(meta, zlib.crc32(head))
        frame = b"".join([head, struct.pack("<I", head_crc), meta, *parts])
        assert len(frame) == frame_len

        # one write per frame
        self._write_all(frame)
        self._count += 1

    def flush(self, sync: bool = False) -> None:
        """Make written frames visible to readers (they already are: writes are unbuffered).

        With ``sync=True`` also ``fsync`` the file, so the frames survive a power loss, not
        only a crash of this process. That costs milliseconds; don't do it every frame.
        """
        self._check_open()
        if sync:
            os.fsync(self._file.fileno())

    def close(self) -> None:
        """Sync and close the file. Closing twice is harmless."""
        if self._file is None or self._file.closed:
            return
        try:
            # a device or a pipe (--out /dev/null) has nothing to sync, and fsync fails on it
            if stat.S_ISREG(os.fstat(self._file.fileno()).st_mode):
                os.fsync(self._file.fileno())
        finally:
            self._file.close()

    def __enter__(self) -> "FrameWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._file is None or self._file.closed else "open"
        return f"<corpuscle.io.FrameWriter {self.path!r}: {self._count} frames, {state}>"

    def _check_open(self) -> None:
        """Refuse to act on a closed writer."""
        if self._file is None or self._file.closed:
            raise ValueError(f"{self.path}: writer is closed")

    def _write_all(self, data: bytes) -> None:
        """Write ``data`` completely at the end; on failure cut the file back to whole frames."""
        view = memoryview(data)
        try:
            # a raw write may take fewer bytes than offered: loop until all are written
            while view:
                view = view[self._file.write(view):]
        except BaseException:
            # a partial frame would read as a torn tail; remove it so later frames can follow
            try:
                os.ftruncate(self._file.fileno(), self._end)
                self._file.seek(self._end)
            except OSError:
                pass
            raise
        self._end += len(data)


def _array_problem(spec, what: str) -> str | None:
    """Why an array description of a frame table is invalid, or None."""
    if not isinstance(spec, dict):
        return f"{what} is not an object"
    dtype = spec.get("dtype")
    if dtype not in DTYPES:
        return f"{what} has dtype {dtype!r}, not one of {' '.join(DTYPES)}"
    if _check_shape(spec.get("shape"), np.dtype(dtype).itemsize) is None:
        return f"{what} has a bad shape"
    offset = spec.get("offset")
    if type(offset) is not int or offset < 0 or offset % ALIGN:
        return f"{what} has a bad offset (not a non-negative multiple of {ALIGN})"
    return None


def _table_problem(meta) -> str | None:
    """Why a decoded frame table is invalid (docs/frame_format.md, "Frame"), or None."""
    if not isinstance(meta, dict):
        return "not a JSON object"
    groups, fields = meta.get("groups"), meta.get("fields")
    rigid, diagnostics = meta.get("rigid"), meta.get("diagnostics")
    if not (isinstance(groups, dict) and isinstance(fields, list) and isinstance(rigid, dict)
            and isinstance(diagnostics, dict)):
        return "needs the objects groups, rigid, diagnostics and the list fields"
    # groups: name -> particle count
    for name, count in groups.items():
        if type(count) is not int or count < 0:
            return f"group {name!r} has a bad count"
    # fields: unique names, each in a listed group whose count is its length
    seen = set()
    for spec in fields:
        name = spec.get("name") if isinstance(spec, dict) else None
        if not isinstance(name, str) or not name or name in seen:
            return "a field has a missing, empty or repeated name"
        seen.add(name)
        problem = _array_problem(spec, f"field {name!r}")
        if problem:
            return problem
        group = spec.get("group")
        if not isinstance(group, str) or group not in groups:
            return f"field {name!r} is in a group that is not listed"
        if spec["shape"][0] != groups[group]:
            return f"field {name!r} has {spec['shape'][0]} rows but group {group!r} has {groups[group]}"
    # rigid: body -> array name -> float64 array; a pose of the documented shapes
    for body, arrays in rigid.items():
        if not isinstance(arrays, dict):
            return f"rigid body {body!r} is not an object"
        for key, spec in arrays.items():
            problem = _array_problem(spec, f"rigid body {body!r} {key!r}")
            if problem:
                return problem
            if spec["dtype"] != "<f8":
                return f"rigid body {body!r} {key!r} is not <f8"
        if ([1, 2, 3] if "position" not in arrays else arrays["position"]["shape"]) not in ([2], [3]):
            return f"rigid body {body!r} needs a position of shape (3,) or (2,)"
        if ([0] if "orientation" not in arrays else arrays["orientation"]["shape"]) not in ([1], [4]):
            return f"rigid body {body!r} needs an orientation of shape (4,) or (1,)"
    # diagnostics: name -> number or "nan" / "inf" / "-inf"
    for name, value in diagnostics.items():
        try:
            _decode_scalar(value)
        except (TypeError, ValueError):
            return f"diagnostic {name!r} is not a number"
    return None


class Frame:
    """One frame of a recorded run.

    Attributes: ``index``, ``step``, ``time``, ``dt``, ``kind`` ("frame" or "checkpoint"),
    ``fields`` (name -> read-only array viewing the file's memory map, original dtype and
    shape), ``groups`` (field -> group), ``counts`` (group -> particle count), ``rigid``
    (body -> {name -> float64 array}), ``diagnostics`` (name -> float).
    ``frame["position"]`` is ``frame.fields["position"]``.
    """

    __slots__ = ("index", "step", "time", "dt", "kind", "fields", "groups", "counts",
                 "rigid", "diagnostics")

    def __init__(self, index, step, time, dt, kind, fields, groups, counts, rigid, diagnostics):
        self.index, self.step, self.time, self.dt, self.kind = index, step, time, dt, kind
        self.fields, self.groups, self.counts = fields, groups, counts
        self.rigid, self.diagnostics = rigid, diagnostics

    def __getitem__(self, name: str) -> np.ndarray:
        # a missing field names the ones present
        try:
            return self.fields[name]
        except KeyError:
            raise KeyError(f"frame {self.index} has no field {name!r} "
                           f"(fields: {', '.join(self.fields) or 'none'})") from None

    def __contains__(self, name) -> bool:
        return name in self.fields

    def __repr__(self) -> str:
        counts = ", ".join(f"{g}={n}" for g, n in self.counts.items())
        return (f"<corpuscle.Frame {self.index} ({self.kind}): step {self.step}, "
                f"time {self.time:g}, {counts or 'no particles'}>")


class _Entry:
    """Where one frame lives, from its header; ``offset`` is -1 when the header is unreadable."""

    __slots__ = ("offset", "frame_len", "meta_len", "data_crc", "step", "time", "dt", "kind")

    def __init__(self, offset=-1, frame_len=0, meta_len=0, data_crc=0,
                 step=-1, time=math.nan, dt=math.nan, kind=None):
        self.offset, self.frame_len, self.meta_len, self.data_crc = offset, frame_len, meta_len, data_crc
        self.step, self.time, self.dt, self.kind = step, time, dt, kind


class Run:
    """A recorded run, memory-mapped. Returned by ``corpuscle.open(path)``.

    Opening reads the file header and scans the frame headers (an index of offsets);
    payloads are read, and their checksums verified, only when a frame is accessed.
    ``run[i]`` (negative indices allowed) is a ``Frame``, ``run[a:b]`` a list of them.
    A file that ends inside a frame gives its whole frames and a ``TruncatedRunWarning``;
    accessing a corrupted frame raises ``FrameStreamError`` naming it; ``verify()``
    checks every frame.

    Attributes: ``path``, ``version``, ``header`` (the run description dict), ``steps``
    (int64, -1 where a frame header is unreadable) and ``times`` (float64, NaN there), both
    read-only arrays with one value per frame, ``kinds``, ``field_names``,
    ``diagnostic_names`` and ``torn_bytes`` (bytes ignored after the last whole frame).

    Field arrays are views on the memory map: they stay valid after ``close()``, which
    then leaves unmapping to the garbage collector.
    """

    def __init__(self, path, *, _stacklevel: int = 2):
        self.path = os.fspath(path)
        self._mm = None
        self._entries: list[_Entry] = []
        self._meta: dict[int, dict] = {}
        self._verified: set[int] = set()
        # map the whole file read-only; the descriptor is not needed afterwards (non-blocking
        # open: a FIFO or device is refused instead of waiting for a writer)
        fd = os.open(self.path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
        try:
            st = os.fstat(fd)
            if stat.S_ISDIR(st.st_mode):
                raise FrameStreamError(f"{self.path}: is a directory, not a corpuscle frame stream")
            if not stat.S_ISREG(st.st_mode):
                raise FrameStreamError(f"{self.path}: not a regular file, not a corpuscle frame stream")
            if st.st_size == 0:
                raise FrameStreamError(f"{self.path}: empty file, not a corpuscle frame stream")
            mm = mmap.mmap(fd, 0, access=mmap.ACCESS_READ)
        finally:
            os.close(fd)
        # header and frame index; unmap again if either is unreadable
        try:
            self.version, self.header, first = self._read_file_header(mm)
            trailing = self._scan(mm, first)
        except BaseException:
            mm.close()
            raise
        self._mm = mm
        self._first = first
        # bytes after the last whole frame that are not a frame: a torn tail, ignored
        self.torn_bytes = trailing
        # per-frame header values as read-only arrays
        self.steps = np.array([e.step for e in self._entries], dtype=np.int64)
        self.times = np.array([e.time for e in self._entries], dtype=np.float64)
        self._dts = np.array([e.dt for e in self._entries], dtype=np.float64)
        for arr in (self.steps, self.times, self._dts):
            arr.flags.writeable = False
        # a cut-off last frame is dropped with a warning
        if trailing:
            n = len(self._entries)
            warnings.warn(f"{self.path}: file ends inside frame {n} ({trailing} trailing bytes "
                          f"ignored); read {n} whole frames", TruncatedRunWarning,
                          stacklevel=_stacklevel)

    # ---- opening -------------------------------------------------------------------

    def _read_file_header(self, mm) -> tuple[int, dict, int]:
        """Check magic, version and checksum; return (version, header, first frame offset)."""
        # magic first: a file that does not start with it is not ours
        size = len(mm)
        magic = mm[:8]
        if magic != FILE_MAGIC[: len(magic)]:
            raise FrameStreamError(f"{self.path}: not a corpuscle frame stream (bad magic {magic!r})")
        if size < _FILE_HEAD.size:
            raise FrameStreamError(f"{self.path}: file header is truncated ({size} bytes)")
        _, version, _, json_len, _, crc = _FILE_HEAD.unpack_from(mm, 0)
        # version before checksum, so a newer file gets the helpful message
        if version > FORMAT_VERSION:
            raise FrameStreamError(f"{self.path}: format version {version} is newer than this "
                                   f"reader supports ({FORMAT_VERSION}); upgrade corpuscle")
        if version < 1:
            raise FrameStreamError(f"{self.path}: unsupported format version {version}")
        # the header JSON and its padding must be whole, and of a size a reader accepts
        first = _align(_FILE_HEAD.size + json_len)
        if first > size:
            raise FrameStreamError(f"{self.path}: file header is truncated ({size} bytes, "
                                   f"the header JSON alone claims {json_len})")
        if json_len > MAX_HEADER_JSON:
            raise FrameStreamError(f"{self.path}: file header is corrupted (header JSON of "
                                   f"{json_len} bytes, more than the limit {MAX_HEADER_JSON})")
        # checksum over bytes [0, 28) and [32, first): everything but the checksum itself
        with memoryview(mm) as whole, whole[:28] as fixed, whole[32:first] as rest:
            ok = zlib.crc32(rest, zlib.crc32(fixed)) == crc
        if not ok:
            raise FrameStreamError(f"{self.path}: file header is corrupted (checksum mismatch)")
        # the run description is a JSON object, strict and bounded
        try:
            header = _load_json(mm[32: 32 + json_len])
        except ValueError as exc:
            raise FrameStreamError(f"{self.path}: file header is corrupted (bad JSON: "
                                   f"{_first_line(exc)})") from None
        if not isinstance(header, dict):
            raise FrameStreamError(f"{self.path}: file header is corrupted (not a JSON object)")
        return version, header, first

    @staticmethod
    def _frame_header(mm, off: int):
        """The frame header at ``off`` as an _Entry plus its index, or None if unreadable.

        Readable means: magic, header and JSON table inside the file, header checksum,
        and a sane length. The frame's data may still extend past the end of the file.
        """
        # magic and fixed part inside the file
        size = len(mm)
        if off + ALIGN > size or mm[off: off + 8] != FRAME_MAGIC:
            return None
        (_, frame_len, index, step, time, dt, meta_len, kind, _, data_crc,
         head_crc) = _FRAME_HEAD.unpack_from(mm, off)
        # the table inside the file and of an accepted size, header and table matching head_crc
        if off + ALIGN + meta_len > size or meta_len > MAX_TABLE_JSON:
            return None
        if zlib.crc32(mm[off + ALIGN: off + ALIGN + meta_len], zlib.crc32(mm[off: off + 60])) != head_crc:
            return None
        # whole 64-byte blocks, at least header and table
        if frame_len % ALIGN or frame_len < _align(ALIGN + meta_len):
            return None
        kind_name = _KIND_NAMES.get(kind, f"unknown kind {kind}")
        return _Entry(off, frame_len, meta_len, data_crc, step, time, dt, kind_name), index

    def _scan(self, mm, off: int) -> int:
        """Index the frames from ``off``; return the number of trailing bytes of a cut frame."""
        size = len(mm)
        entries = self._entries
        # bytes the forward searches may checksum in all: crafted candidates (a frame magic
        # every 64 bytes, each claiming a long table) would otherwise cost size**2 / 128
        budget = 2 * size
        while off < size:
            # the common case: the next frame's header is readable and in sequence
            found = self._frame_header(mm, off)
            if found is not None and found[1] == len(entries):
                entry = found[0]
                if off + entry.frame_len > size:
                    return size - off
                entries.append(entry)
                off += entry.frame_len
                continue
            # damaged header: resume at the next readable header later in the sequence
            # (the frames skipped over must fit in the bytes skipped, 64 bytes at least each);
            # index and length are checked before the checksum, which is paid from the budget
            pos = mm.find(FRAME_MAGIC, off)
            while pos != -1:
                if pos % ALIGN == 0 and pos + ALIGN <= size:
                    index, = struct.unpack_from("<Q", mm, pos + 16)
                    if 0 <= index - len(entries) <= (pos - off) // ALIGN:
                        budget -= 60 + min(struct.unpack_from("<I", mm, pos + 48)[0], size - pos)
                        if budget < 0:
                            pos = -1
                            break
                        found = self._frame_header(mm, pos)
                        if found is not None:
                            break
                pos = mm.find(FRAME_MAGIC, pos + 1)
            if pos != -1:
                # frames between are unreadable placeholders that raise on access
                entries.extend(_Entry() for _ in range(found[1] - len(entries)))
                off = pos
                continue
            # nothing readable follows: a whole last frame with a damaged header, or a torn tail
            if size - off >= ALIGN and struct.unpack_from("<Q", mm, off + 8)[0] == size - off:
                entries.append(_Entry())
                return 0
            return size - off
        return 0

    # ---- frames --------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self._entries)

    def __getitem__(self, i):
        """Frame ``i`` (negative counts from the end), or a list of frames for a slice."""
        # a slice gives a list
        if isinstance(i, slice):
            return [self._frame(j) for j in range(*i.indices(len(self)))]
        # an integer, negative ones counting from the end
        i = operator.index(i)
        n = len(self)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"{self.path}: frame index out of range ({n} frames)")
        return self._frame(i)

    def __iter__(self):
        for i in range(len(self)):
            yield self._frame(i)

    @property
    def kinds(self) -> list:
        """Kind of every frame ("frame" or "checkpoint"; None where the header is unreadable)."""
        return [e.kind for e in self._entries]

    def last_checkpoint(self) -> Frame | None:
        """The last frame whose kind is "checkpoint", or None if there is none.

        Found from the frame headers; the checkpoint's payload is then read and checked
        like any frame (a corrupted one raises ``FrameStreamError``).
        """
        for i in reversed(range(len(self))):
            if self._entries[i].kind == "checkpoint":
                return self._frame(i)
        return None

    @property
    def field_names(self) -> list[str]:
        """Names of the fields in any frame, in order of first appearance."""
        # tables only, in frame order
        names = {}
        for i in range(len(self)):
            for spec in (self._meta_or_none(i) or {}).get("fields", []):
                names.setdefault(spec["name"], None)
        return list(names)

    @property
    def diagnostic_names(self) -> list[str]:
        """Names of the diagnostics in any frame, in order of first appearance."""
        names = {}
        for i in range(len(self)):
            names.update(dict.fromkeys((self._meta_or_none(i) or {}).get("diagnostics", {})))
        return list(names)

    def series(self, name: str) -> np.ndarray:
        """One float64 value per frame: a diagnostic, or "step", "time" or "dt".

        NaN where a frame lacks the diagnostic or its header is unreadable. Raises KeyError
        if no frame has it. Reads only the frames' tables, not their field data.
        """
        # header values come from the scan
        if name == "step":
            return np.where(self.steps >= 0, self.steps, np.nan).astype(np.float64)
        if name == "time":
            return self.times.copy()
        if name == "dt":
            return self._dts.copy()
        # gather the diagnostic from each frame's table
        out = np.full(len(self), np.nan)
        seen = False
        for i in range(len(self)):
            diag = (self._meta_or_none(i) or {}).get("diagnostics", {})
            if name in diag:
                out[i] = _decode_scalar(diag[name])
                seen = True
        if not seen and len(self):
            raise KeyError(f"{self.path}: no frame has a diagnostic named {name!r} "
                           f"(diagnostics: {', '.join(self.diagnostic_names) or 'none'})")
        return out

    def verify(self) -> None:
        """Check every frame's checksums and table; raise FrameStreamError at the first bad one."""
        self._check_open()
        for i in range(len(self)):
            self._check_frame(i)

    def _check_open(self) -> None:
        """Refuse to read from a closed run."""
        if self._mm is None:
            raise ValueError(f"{self.path}: run is closed")

    def _meta_or_none(self, i: int):
        """Frame ``i``'s table, or None if its header is unreadable (checked by its CRC)."""
        if i not in self._meta:
            entry = self._entries[i]
            if entry.offset < 0:
                return None
            self._check_open()
            raw = self._mm[entry.offset + ALIGN: entry.offset + ALIGN + entry.meta_len]
            self._meta[i] = self._parse_table(raw, i)
        return self._meta[i]

    def _parse_table(self, raw: bytes, i: int) -> dict:
        """Decode a frame's JSON table and check its structure, so later code can trust it.

        Array descriptions get their dtype, shape and offset checked here (``_locate``
        checks them against the frame's bytes); the result keeps the table's own keys.
        """
        try:
            meta = _load_json(raw)
            reason = _table_problem(meta)
        except ValueError as exc:
            reason = f"bad JSON: {_first_line(exc)}"
        if reason:
            raise FrameStreamError(f"{self.path}: frame {i} is malformed (bad table: {reason})", frame=i)
        return meta

    def _check_frame(self, i: int) -> dict:
        """Verify frame ``i``'s checksums (once) and return its table."""
        self._check_open()
        # a frame whose header was unreadable has nothing to give
        entry = self._entries[i]
        if entry.offset < 0:
            raise FrameStreamError(f"{self.path}: frame {i} is corrupted (frame header checksum "
                                   "mismatch)", frame=i)
        meta = self._meta_or_none(i)
        if i not in self._verified:
            # crc over the data region through a memoryview, without copying it
            start, end = entry.offset + ALIGN + entry.meta_len, entry.offset + entry.frame_len
            with memoryview(self._mm) as whole, whole[start:end] as data:
                crc = zlib.crc32(data)
            if crc != entry.data_crc:
                raise FrameStreamError(f"{self.path}: frame {i} is corrupted (checksum mismatch)",
                                       frame=i)
            # every array must lie inside the data region
            for spec in self._array_specs(meta):
                self._locate(spec, entry, i)
            self._verified.add(i)
        return meta

    @staticmethod
    def _array_specs(meta: dict) -> list:
        """All array descriptions of a frame table (fields, then rigid-body arrays)."""
        specs = list(meta["fields"])
        for body in meta["rigid"].values():
            specs.extend(body.values())
        return specs

    def _locate(self, spec: dict, entry: _Entry, i: int) -> tuple[np.dtype, tuple, int]:
        """(dtype, shape, absolute offset) of a checked array description, inside the frame."""
        dtype = np.dtype(spec["dtype"])
        shape = tuple(spec["shape"])
        rel = spec["offset"]
        # a 64-byte aligned array whose bytes lie in the data region
        data_start = entry.offset + _align(ALIGN + entry.meta_len)
        nbytes = math.prod(shape) * dtype.itemsize
        if data_start + rel + nbytes > entry.offset + entry.frame_len:
            raise FrameStreamError(f"{self.path}: frame {i} is malformed (array outside its frame)",
                                   frame=i)
        return dtype, shape, data_start + rel

    def _view(self, spec: dict, entry: _Entry, i: int) -> np.ndarray:
        """A read-only array viewing the memory map."""
        dtype, shape, off = self._locate(spec, entry, i)
        return np.frombuffer(self._mm, dtype=dtype, count=math.prod(shape), offset=off).reshape(shape)

    def _frame(self, i: int) -> Frame:
        """Build frame ``i`` from its verified table."""
        meta = self._check_frame(i)
        entry = self._entries[i]
        # fields and their groups
        fields, groups = {}, {}
        for spec in meta["fields"]:
            fields[spec["name"]] = self._view(spec, entry, i)
            groups[spec["name"]] = spec["group"]
        # rigid bodies and diagnostics
        rigid = {body: {key: self._view(spec, entry, i) for key, spec in arrays.items()}
                 for body, arrays in meta["rigid"].items()}
        diagnostics = {k: _decode_scalar(v) for k, v in meta["diagnostics"].items()}
        return Frame(i, entry.step, entry.time, entry.dt, entry.kind, fields, groups,
                     dict(meta["groups"]), rigid, diagnostics)

    # ---- lifetime ------------------------------------------------------------------

    def close(self) -> None:
        """Release the memory map; arrays still viewing it keep it alive until they go."""
        # close() fails while arrays view the map; the garbage collector unmaps it later
        mm, self._mm = self._mm, None
        if mm is not None:
            try:
                mm.close()
            except BufferError:
                pass

    def __enter__(self) -> "Run":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<corpuscle.Run {self.path!r}: {len(self)} frames, format version {self.version}>"


def open(path) -> Run:  # noqa: A001 - corpuscle.open mirrors the built-in on purpose
    """Open a recorded run (``.cps``) for reading; see ``Run``."""
    return Run(path, _stacklevel=3)
