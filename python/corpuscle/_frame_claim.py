"""How a :class:`~corpuscle.io.FrameWriter` takes its file, so that nobody else's data is lost.

- **One writer at a time.** The writer holds an advisory lock (``flock``, exclusive) on the
  file for as long as it writes; a second writer (another run, a resume) is refused at once
  with :class:`FileBusyError`, naming the file and, where the system says, the holder's pid.
- **Only frame streams are replaced.** An existing file that does not start with the frame
  stream's magic (a scene, an airfoil ``.dat``, notes) is replaced only with ``force``:
  :class:`ForeignFileError` otherwise.
- **Readers keep what they read.** A file is never truncated under a reader that has it
  mapped (that reader would die of SIGBUS): a new run is written to a new file in the same
  folder, renamed over the old one once its header is written; resuming appends in place, and
  when frames must be cut, the kept ones are copied to a new file that is renamed over it.

Choosing and renaming happen under a short lock on the folder, so two writers that start at
the same moment cannot both replace the file. Files that are not regular (``/dev/null``, a
pipe) are written as they are, without a lock.
"""
from __future__ import annotations

import contextlib
import errno
import os
import stat

try:
    import fcntl
except ImportError:  # not POSIX: no advisory locks
    fcntl = None

from ._frame_format import FILE_MAGIC


class FileBusyError(BlockingIOError):
    """The file is being written by another writer (``pid``: the holder's, or None)."""

    def __init__(self, path: str, pid: int | None):
        holder = f"process {pid}" if pid is not None else "another process"
        super().__init__(errno.EAGAIN, f"is being written by {holder} (it holds the file's lock)", path)
        self.pid = pid

    def __str__(self) -> str:
        return f"{self.filename}: {self.strerror}"


class ForeignFileError(FileExistsError):
    """The file exists and is not a frame stream: it is replaced only with ``force``."""

    def __init__(self, path: str, start: bytes):
        what = f"it starts {start[:16]!r}"
        super().__init__(errno.EEXIST, f"exists and is not a corpuscle frame stream ({what}); "
                                       "pass --force (force=True) to replace it", path)

    def __str__(self) -> str:
        return f"{self.filename}: {self.strerror}"


def lock_holder(fd: int) -> int | None:
    """The pid holding a ``flock`` on the file open at ``fd`` (Linux ``/proc/locks``), or None."""
    try:
        st = os.fstat(fd)
        want = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
        with open("/proc/locks", encoding="ascii", errors="replace") as f:
            for line in f:
                parts = line.split()
                if "->" in parts:  # a waiter, not a holder
                    continue
                if len(parts) >= 6 and parts[1] == "FLOCK" and parts[5] == want:
                    pid = int(parts[4])
                    return pid if pid > 0 else None
    except (OSError, ValueError):
        pass
    return None


def try_lock(fd: int, path: str) -> None:
    """Take the exclusive lock on ``fd`` without waiting; :class:`FileBusyError` if held."""
    if fcntl is None:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise FileBusyError(path, lock_holder(fd)) from None
    except OSError as exc:
        if exc.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
            raise  # a filesystem without locks: written unlocked, as before


def is_busy(path) -> FileBusyError | None:
    """The error a writer of ``path`` would meet now because another holds it, or None."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        try_lock(fd, os.fspath(path))
    except FileBusyError as exc:
        return exc
    except OSError:
        return None
    finally:
        os.close(fd)
    return None


def foreign_start(path) -> bytes | None:
    """The first bytes of ``path`` when it is a non-empty regular file that is not a frame
    stream (it does not start with the magic); None otherwise (absent, empty, a frame
    stream, not a regular file)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        start = os.read(fd, 64)
    finally:
        os.close(fd)
    if not start or start[: len(FILE_MAGIC)] == FILE_MAGIC:
        return None
    return start


@contextlib.contextmanager
def folder_lock(path: str):
    """A short exclusive lock on ``path``'s folder while a writer picks and renames its file."""
    folder = os.path.dirname(os.path.abspath(path)) or "."
    fd = None
    if fcntl is not None:
        try:
            fd = os.open(folder, os.O_RDONLY)
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError:
            if fd is not None:
                os.close(fd)
            fd = None  # no lock on this folder: the file's own lock still guards the run
    try:
        yield
    finally:
        if fd is not None:
            os.close(fd)  # releases the lock


def target(path: str) -> str:
    """The file a writer of ``path`` writes: a symbolic link's target, so the link stays."""
    return os.path.realpath(path) if os.path.islink(path) else path


def new_file(path: str):
    """A new, locked file beside ``path`` (to be renamed over it): (fd, its name)."""
    folder, name = os.path.split(path)
    for k in range(100):
        tmp = os.path.join(folder, f".{name}.{os.getpid()}.{k}.tmp")
        try:
            fd = os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
        except FileExistsError:
            continue
        try:
            try_lock(fd, path)
        except BaseException:
            os.close(fd)
            os.unlink(tmp)
            raise
        return fd, tmp
    raise FileExistsError(errno.EEXIST, "no free name for a temporary file beside it", path)


def check_old(path: str, force: bool):
    """Under the folder lock: refuse a file another writer holds, or one that is not a frame
    stream (unless ``force``). Returns the open, locked old file's descriptor (close it after
    the rename), or None when there is no old regular file."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            os.close(fd)
            return None
        try_lock(fd, path)
        if not force:
            start = os.pread(fd, 64, 0)
            if start and start[: len(FILE_MAGIC)] != FILE_MAGIC:
                raise ForeignFileError(path, start)
    except BaseException:
        os.close(fd)
        raise
    return fd
