"""The errors a simulation raises (re-exported by :mod:`corpuscle.simulation`), in a module
of their own so that scene kinds (:mod:`corpuscle.kinds`) can raise them without importing
the simulation."""

from __future__ import annotations


class BackendError(ValueError):
    """A backend was asked for that this build or machine cannot run."""


class UnstableRunError(RuntimeError):
    """The run went unstable (non-finite state); `step` names where."""

    def __init__(self, step: int, message: str):
        super().__init__(message)
        self.step = step


class MemoryNeedError(ValueError):
    """A scene needs more memory than the backend has; the message names the keys."""
