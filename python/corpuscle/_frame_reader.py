"""Reading the frame stream (docs/frame_format.md): :class:`Run` (a memory-mapped ``.cps``
file, its frames checked and indexed, a torn tail cut off) and :class:`Frame` (one frame's
read-only views). The public names are :mod:`corpuscle.io`'s; the format is
:mod:`corpuscle._frame_format`'s."""

from __future__ import annotations

import io as _io
import math
import mmap
import operator
import os
import stat
import struct
import warnings
import zlib

import numpy as np

from ._frame_format import (ALIGN, DTYPES, FILE_MAGIC, FORMAT_VERSION, FRAME_MAGIC, MAX_HEADER_JSON, MAX_TABLE_JSON,
                            _FILE_HEAD, _FRAME_HEAD, _KIND_NAMES, FrameStreamError, TruncatedRunWarning, _align,
                            _check_shape, _decode_scalar, _first_line, _load_json)


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
        self._fh = None
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
            # the descriptor stays open: a file cut short under the map (by another program;
            # corpuscle's writers never do it) is found before a read past its end would be
            # a SIGBUS
            self._fh = _io.FileIO(fd, "rb", closefd=True)
        except BaseException:
            os.close(fd)
            raise
        # header and frame index; unmap again if either is unreadable
        try:
            self.version, self.header, first = self._read_file_header(mm)
            trailing = self._scan(mm, first)
        except BaseException:
            mm.close()
            self._fh.close()
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
        """Refuse to read from a closed run, or from a file cut short since it was opened."""
        if self._mm is None:
            raise ValueError(f"{self.path}: run is closed")
        try:
            size = os.fstat(self._fh.fileno()).st_size
        except (OSError, ValueError):
            return
        if size < len(self._mm):
            raise FrameStreamError(f"{self.path}: the file was cut to {size} bytes while it was read "
                                   f"({len(self._mm)} when opened): another program rewrote it; open it again")

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
        fh = getattr(self, "_fh", None)
        if fh is not None:
            fh.close()
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
