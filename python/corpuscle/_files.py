"""Reading the files a user names, with a bound suited to each kind.

A path on the command line or in a scene can name anything: ``/dev/zero``, a named pipe, a
log that never ends, a disk image. Each kind of small text input (a scene file, an airfoil
``.dat``) is read through :func:`read_bounded` with the most bytes such a file can sensibly
hold: past it the read stops and the error says so in one line, never a ``MemoryError`` or
all of the machine's memory. A named pipe with no writer reads as empty (it is opened without
waiting for one). Frame streams and checkpoints are mapped, not read, and check their own
lengths against the file's size (``_frame_reader.py``)."""

from __future__ import annotations

import os
import stat

__all__ = ["MiB", "SCENE_FILE_BYTES", "AIRFOIL_FILE_BYTES", "read_bounded", "FileTooLarge"]

MiB = 1 << 20
#: a scene file: a few dozen keys and at most a few dozen [[...]] entries (a shipped one is ~3 KiB)
SCENE_FILE_BYTES = 1 * MiB
#: an airfoil .dat: at most 1,024 vertices of a line each (a shipped one is ~5 KiB)
AIRFOIL_FILE_BYTES = 1 * MiB


class FileTooLarge(ValueError):
    """A file holds more bytes than its kind may (the message names the file and the bound)."""


def _size_text(n: int) -> str:
    return f"{n // MiB} MiB" if n % MiB == 0 else f"{n:,} bytes"


def read_bounded(path: str | os.PathLike, limit: int, what: str) -> bytes:
    """The bytes of ``path``, at most ``limit`` of them; ``what`` names the kind of file in
    the error (``"a scene file"``). Raises :class:`FileTooLarge` past the bound, OSError as
    ``open``/``read`` do (a folder: IsADirectoryError)."""
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0)
    fd = os.open(path, flags)
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise IsADirectoryError(21, "Is a directory", os.fspath(path))
        if stat.S_ISREG(st.st_mode) and st.st_size > limit:
            raise FileTooLarge(f"{os.fspath(path)}: {st.st_size:,} bytes ({what} holds at most {_size_text(limit)})")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)  # opened without waiting for a pipe's writer; now read as usual
        chunks, got = [], 0
        while got <= limit:
            chunk = os.read(fd, min(limit + 1 - got, MiB))
            if not chunk:
                break
            chunks.append(chunk)
            got += len(chunk)
        if got > limit:
            raise FileTooLarge(f"{os.fspath(path)}: more than {_size_text(limit)} ({what} holds at most "
                               f"{_size_text(limit)}: is it the file you meant?)")
        return b"".join(chunks)
    finally:
        os.close(fd)
