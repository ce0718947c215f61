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
"""

from __future__ import annotations

import builtins
import json
import math
import mmap
import operator
import os
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

# array element kinds the stream carries: bool, signed, unsigned, float, complex
_DTYPE_KINDS = "biufc"
_RESERVED_SERIES = ("step", "time", "dt")
_ZEROS = bytes(ALIGN)


class FrameStreamError(ValueError):
    """A file is not a readable corpuscle frame stream, or one of its frames is corrupted.

    ``frame`` is the index of the offending frame, or ``None`` for file-level problems.
    """

    def __init__(self, message: str, frame: int | None = None):
        super().__init__(message)
        self.frame = frame


class TruncatedRunWarning(UserWarning):
    """A run file ends inside a frame (e.g. a crash mid-write); its whole frames were read."""


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
    """Inverse of ``_encode_scalar``."""
    return float(value)


def _as_le_array(value, what: str, dtype=None) -> np.ndarray:
    """``value`` as a C-contiguous little-endian array of a carried dtype."""
    arr = np.asarray(value, dtype=dtype)
    if arr.dtype.kind not in _DTYPE_KINDS:
        raise TypeError(f"{what} has unsupported dtype {arr.dtype} "
                        "(bool, integer, float and complex arrays are carried)")
    if arr.ndim == 0:
        raise ValueError(f"{what} must be an array with at least one dimension, got a scalar")
    return np.ascontiguousarray(arr, dtype=arr.dtype.newbyteorder("<"))


class FrameWriter:
    """Append frames to a new run file (``.cps``).

    ``header`` is a JSON-serialisable dict describing the run (scene name, dim, backend,
    parameters, container geometry, rigid body descriptions ...); NumPy scalars and arrays
    in it are converted to JSON numbers and lists. The file header is written and handed
    to the operating system at once. Each frame is then appended with a single ``write()``,
    so a reader, or a crash, sees only whole frames plus at most one partial frame at the
    end, which the reader drops with a ``TruncatedRunWarning``.

    An existing file at ``path`` is replaced. Use as a context manager, or call ``close()``.
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
        # fixed part, JSON, zero padding to the first frame; the CRC covers all but itself
        first = _align(_FILE_HEAD.size + len(body))
        pad = _ZEROS[: first - _FILE_HEAD.size - len(body)]
        fixed = _FILE_HEAD.pack(FILE_MAGIC, FORMAT_VERSION, 0, len(body), 0, 0)[:28]
        crc = zlib.crc32(pad, zlib.crc32(body, zlib.crc32(fixed)))
        # unbuffered: every write goes straight to the operating system
        self._file = builtins.open(self.path, "wb", buffering=0)
        self._end = 0
        self._count = 0
        self._write_all(b"".join((fixed, struct.pack("<I", crc), body, pad)))

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

    Field arrays are views on the memory map: they stay valid after ``close()``, which
    then leaves unmapping to the garbage collector.
    """

    def __init__(self, path, *, _stacklevel: int = 2):
        self.path = os.fspath(path)
        self._mm = None
        self._entries: list[_Entry] = []
        self._meta: dict[int, dict] = {}
        self._verified: set[int] = set()
        # map the whole file read-only; the descriptor is not needed afterwards
        with builtins.open(self.path, "rb") as f:
            if os.fstat(f.fileno()).st_size == 0:
                raise FrameStreamError(f"{self.path}: empty file, not a corpuscle frame stream")
            mm = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        # header and frame index; unmap again if either is unreadable
        try:
            self.version, self.header, first = self._read_file_header(mm)
            trailing = self._scan(mm, first)
        except BaseException:
            mm.close()
            raise
        self._mm = mm
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
        # the header JSON and its padding must be whole
        first = _align(_FILE_HEAD.size + json_len)
        if first > size:
            raise FrameStreamError(f"{self.path}: file header is truncated ({size} bytes)")
        # checksum over bytes 0..27 and 32..first, then the JSON itself
        if zlib.crc32(mm[32:first], zlib.crc32(mm[:28])) != crc:
            raise FrameStreamError(f"{self.path}: file header is corrupted (checksum mismatch)")
        # the run description is a JSON object
        try:
            header = json.loads(mm[32: 32 + json_len].decode("utf-8"))
        except ValueError:
            header = None
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
        # the table inside the file, header and table matching head_crc
        if off + ALIGN + meta_len > size:
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
            # (the frames skipped over must fit in the bytes skipped, 64 bytes at least each)
            pos = mm.find(FRAME_MAGIC, off)
            while pos != -1:
                if pos % ALIGN == 0:
                    found = self._frame_header(mm, pos)
                    if found is not None and 0 <= found[1] - len(entries) <= (pos - off) // ALIGN:
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
        """Decode a frame's JSON table and check its structure, so later code can trust it."""
        # the four sections with the expected types
        try:
            meta = json.loads(raw.decode("utf-8"))
            ok = (isinstance(meta, dict)
                  and isinstance(meta["groups"], dict) and isinstance(meta["fields"], list)
                  and isinstance(meta["rigid"], dict) and isinstance(meta["diagnostics"], dict)
                  and all(isinstance(s, dict) and isinstance(s["name"], str)
                          and isinstance(s["group"], str) for s in meta["fields"])
                  and all(isinstance(body, dict) and all(isinstance(s, dict) for s in body.values())
                          for body in meta["rigid"].values()))
            # diagnostics must decode to floats
            for value in meta["diagnostics"].values() if ok else ():
                _decode_scalar(value)
        except (ValueError, KeyError, TypeError):
            ok = False
        if not ok:
            raise FrameStreamError(f"{self.path}: frame {i} is malformed (bad table)", frame=i)
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
        """(dtype, shape, absolute offset) of an array description, checked against the frame."""
        # decode the description
        try:
            dtype = np.dtype(spec["dtype"])
            shape = tuple(int(s) for s in spec["shape"])
            rel = int(spec["offset"])
        except (KeyError, TypeError, ValueError):
            raise FrameStreamError(f"{self.path}: frame {i} is malformed (bad array entry)",
                                   frame=i) from None
        # a carried little-endian dtype, 64-byte aligned, inside the frame
        data_start = entry.offset + _align(ALIGN + entry.meta_len)
        nbytes = math.prod(shape) * dtype.itemsize
        if (dtype.kind not in _DTYPE_KINDS or dtype.byteorder == ">" or min(shape, default=0) < 0
                or rel % ALIGN or rel < 0 or data_start + rel + nbytes > entry.offset + entry.frame_len):
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
