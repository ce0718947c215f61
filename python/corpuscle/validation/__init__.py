"""Validations (``corpuscle validate NAME``): runs checked against experiments and theory.

Each module of this package defines ``add_arguments(parser)`` (its own options) and
``run(args) -> list[Check]``; its default size runs on 2 CPU cores in well under a minute,
``--full`` (or a larger ``--particles``) is for the GPU. :data:`VALIDATIONS` maps the CLI's
names to the modules; :func:`load` imports one.
"""

from __future__ import annotations

import importlib
from dataclasses import asdict, dataclass
from types import ModuleType

__all__ = ["Check", "VALIDATIONS", "load", "options_parser", "as_dicts"]


@dataclass
class Check:
    """One check: ``measured`` against ``reference`` within ``tolerance`` (difference =
    measured - reference)."""

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


# CLI name -> module of this package
VALIDATIONS = {"dam-break": "dam_break", "hydrostatic": "hydrostatic", "wind-tunnel": "wind_tunnel",
               "wind-tunnel-sphere": "wind_tunnel_sphere",  # a mesh body's drag, free-molecular
               # the canonical flows (periodic boundaries, moving walls: docs/sph_box.md)
               "taylor-green": "taylor_green", "poiseuille": "poiseuille", "lid-driven-cavity": "lid_driven_cavity"}


def load(name: str) -> ModuleType:
    """The validation module of a CLI name (ValueError naming the known ones)."""
    if name not in VALIDATIONS:
        raise ValueError(f"unknown validation {name!r} (validations: {', '.join(VALIDATIONS)})")
    try:
        return importlib.import_module(f"{__name__}.{VALIDATIONS[name]}")
    except ModuleNotFoundError as exc:
        if exc.name == f"{__name__}.{VALIDATIONS[name]}":
            raise ValueError(f"validation {name!r} is not part of this build") from None
        raise


def options_parser(name: str, parser_class=None):
    """(the validation module, an argparse parser of its own options); ``parser_class``: the
    parser's class (the command line passes its own, whose errors are one line)."""
    import argparse

    module = load(name)
    cls = parser_class or argparse.ArgumentParser
    parser = cls(prog=f"corpuscle validate {name}", description=(module.__doc__ or "").strip().splitlines()[0])
    module.add_arguments(parser)
    return module, parser


def within(name: str, measured: float, reference: float, tolerance: float, unit: str = "", detail: str = "") -> Check:
    """A check that |measured - reference| <= tolerance (NaN fails)."""
    m, r = float(measured), float(reference)
    ok = bool(abs(m - r) <= tolerance)
    return Check(name, m, r, float(tolerance), ok, unit, detail)


def as_dicts(checks: list[Check]) -> list[dict]:
    return [asdict(c) | {"difference": c.measured - c.reference} for c in checks]
