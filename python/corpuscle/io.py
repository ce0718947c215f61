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
import errno
import json
import operator
import os
import stat
import struct
import warnings
import zlib

import numpy as np

__all__ = [
    "FORMAT_VERSION",
    "FileBusyError",
    "ForeignFileError",
    "Frame",
    "FrameStreamError",
    "FrameWriter",
    "Run",
    "TruncatedRunWarning",
    "open",
]

from ._frame_format import (  # noqa: F401  (the format's public names are this module's too)
    ALIGN, DTYPES, FILE_MAGIC, FORMAT_VERSION, FRAME_MAGIC, MAX_ARRAY_EXTENT, MAX_HEADER_JSON, MAX_JSON_DEPTH,
    MAX_NDIM, MAX_TABLE_JSON, _FILE_HEAD, _FRAME_HEAD, _KIND_CODES, _RESERVED_SERIES, _ZEROS, FrameStreamError,
    TruncatedRunWarning, _align, _as_le_array, _encode_scalar, _json_default, _json_depth)
from ._frame_reader import Frame, Run, open  # noqa: F401,A004  (corpuscle.io is their public home)
from . import _frame_claim as _claim
from ._frame_claim import FileBusyError, ForeignFileError  # noqa: F401  (public here)


def _copy_prefix(src: int, dst: int, length: int) -> None:
    """Copy the first ``length`` bytes of the file open at ``src`` to ``dst`` (at its start)."""
    done = 0
    while done < length:
        chunk = min(length - done, 1 << 24)
        try:
            k = os.copy_file_range(src, dst, chunk, done, done)
        except (AttributeError, OSError):
            data = os.pread(src, chunk, done)
            k = os.pwrite(dst, data, done) if data else 0
        if k <= 0:
            raise OSError(errno.EIO, "short copy of the kept frames")
        done += k


class FrameWriter:
    """Append frames to a new run file (``.cps``), or to an existing one (``append``).

    ``header`` is a JSON-serialisable dict describing the run (scene name, dim, backend,
    parameters, container geometry, rigid body descriptions ...); NumPy scalars and arrays
    in it are converted to JSON numbers and lists. The file header is written and handed
    to the operating system at once. Each frame is then appended with a single ``write()``,
    so a reader, or a crash, sees only whole frames plus at most one partial frame at the
    end, which the reader drops with a ``TruncatedRunWarning``.

    An existing frame stream at ``path`` is replaced (a new file renamed over it, so a reader
    of the old one keeps it whole); any other existing file only with ``force=True``
    (``ForeignFileError`` otherwise). The writer holds an exclusive lock on its file until it
    is closed: a second writer of the same file gets ``FileBusyError`` naming the holder's pid.
    Use as a context manager, or call ``close()``.
    ``header`` (attribute) is the header as a reader will see it (after the JSON round trip).
    """

    def __init__(self, path, header: dict, *, force: bool = False):
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
        head = b"".join((fixed, struct.pack("<I", crc), body, pad))
        self._end = 0
        self._count = 0
        real = _claim.target(self.path)
        try:
            mode = os.stat(real).st_mode
        except FileNotFoundError:
            mode = None
        if mode is not None and stat.S_ISDIR(mode):
            raise IsADirectoryError(errno.EISDIR, "is a folder", self.path)
        if mode is not None and not stat.S_ISREG(mode):
            # a device or a pipe (--out /dev/null): written as it is (unbuffered)
            self._file = builtins.open(real, "wb", buffering=0)
            try:
                self._write_all(head)
            except BaseException:
                self._file.close()
                raise
            return
        # a new file beside the old one, locked, renamed over it once its header is written:
        # a reader of the old one keeps it whole, and a second writer is refused
        with _claim.folder_lock(real):
            old = _claim.check_old(real, force)
            try:
                fd, tmp = _claim.new_file(real)
                self._file = os.fdopen(fd, "wb", buffering=0)  # unbuffered: straight to the system
                try:
                    self._write_all(head)
                    os.rename(tmp, real)
                except BaseException:
                    # not even the header fits (a full disk): the old file stays as it was
                    self._file.close()
                    os.unlink(tmp)
                    raise
            finally:
                if old is not None:
                    os.close(old)

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
        real = _claim.target(path)
        with _claim.folder_lock(real):
            # a run still writing the file is not resumed under its feet (under the folder's
            # lock, its own is taken again by the appending descriptor)
            old = _claim.check_old(real, True)
            if old is not None:
                os.close(old)
            return cls._append_locked(path, real, keep)

    @classmethod
    def _append_locked(cls, path: str, real: str, keep) -> "FrameWriter":
        """``append``, holding the folder's and the file's locks."""
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
        # continue after the last kept frame: in place when nothing follows it, else in a copy
        # of the kept frames renamed over the file (a reader of it is never cut short)
        self = cls.__new__(cls)
        self.path, self.header, self._count, self._end = path, header, n, end
        self._file = builtins.open(real, "r+b", buffering=0)
        try:
            if os.fstat(self._file.fileno()).st_size != end:
                fd, tmp = _claim.new_file(real)
                try:
                    _copy_prefix(self._file.fileno(), fd, end)
                    os.fsync(fd)
                    os.rename(tmp, real)
                except BaseException:
                    os.close(fd)
                    os.unlink(tmp)
                    raise
                self._file.close()
                self._file = os.fdopen(fd, "r+b", buffering=0)
            else:
                _claim.try_lock(self._file.fileno(), path)
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
