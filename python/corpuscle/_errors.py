"""The errors a simulation raises (re-exported by :mod:`corpuscle.simulation`), in a module
of their own so that scene kinds (:mod:`corpuscle.kinds`) can raise them without importing
the simulation."""

from __future__ import annotations

import errno as _errno

#: the exit code of a command whose output could not be written (disk full, file too large)
EXIT_WRITE = 4
#: the errno values of a full disk or a file size limit: the disk, not the input
DISK_FULL_ERRNOS = frozenset(getattr(_errno, name) for name in ("ENOSPC", "EFBIG", "EDQUOT") if hasattr(_errno, name))


def write_failure(error: type[Exception], message: str, exc: BaseException) -> Exception:
    """``error(message)``, with exit code 4 when ``exc`` is a full disk (else the usual 2)."""
    err = error(message)
    if getattr(exc, "errno", None) in DISK_FULL_ERRNOS:
        err.exit_code = EXIT_WRITE
    return err


class BackendError(ValueError):
    """A backend was asked for that this build or machine cannot run."""


class UnstableRunError(RuntimeError):
    """The run went unstable (non-finite state); `step` names where."""

    def __init__(self, step: int, message: str):
        super().__init__(message)
        self.step = step


class MemoryNeedError(ValueError):
    """A scene needs more memory than the backend has; the message names the keys."""
