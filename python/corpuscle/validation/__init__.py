"""Validations: `corpuscle validate NAME` runs a module of this package and prints its checks.

Each module (the values of :data:`VALIDATIONS`) defines ``add_arguments(parser)`` (its own
options) and ``run(args) -> list[Check]``; the default size runs on two CPU cores in well
under a minute, ``--full`` (or a larger ``--particles``) is the size for the GPU.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass

__all__ = ["Check", "VALIDATIONS", "load"]


@dataclass
class Check:
    """One compared quantity: passed when |measured - reference| <= tolerance."""

    name: str
    measured: float
    reference: float
    tolerance: float
    passed: bool
    unit: str = ""
    detail: str = ""

    @property
    def difference(self) -> float:
        return self.measured - self.reference


# CLI name -> module name in this package
VALIDATIONS = {"dam-break": "dam_break", "hydrostatic": "hydrostatic", "wind-tunnel": "wind_tunnel"}


def load(name: str):
    """The module of validation `name` (ValueError naming the known ones otherwise)."""
    if name not in VALIDATIONS:
        raise ValueError(f"unknown validation {name!r} (known: {', '.join(sorted(VALIDATIONS))})")
    try:
        return importlib.import_module(f"{__name__}.{VALIDATIONS[name]}")
    except ModuleNotFoundError as exc:
        if exc.name == f"{__name__}.{VALIDATIONS[name]}":
            raise ValueError(f"validation {name!r} is not available in this build") from None
        raise
