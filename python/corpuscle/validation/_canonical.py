"""What the canonical-flow validations (taylor-green, poiseuille, lid-driven-cavity) share:
running a scene of the 2-D fluid box with overrides and reading its particles."""

from __future__ import annotations

import numpy as np


def make_sim(args, scene_name: str, overrides: dict):
    from ..scene import load_scene
    from ..simulation import Simulation

    scene = load_scene(scene_name).with_overrides(overrides)
    return Simulation(scene, args.backend, neighbors=args.neighbors, device=args.device)


def particles(sim) -> tuple[np.ndarray, np.ndarray]:
    """(positions, velocities) of the fluid, float64."""
    return (np.asarray(sim.core.download("position"), dtype=np.float64),
            np.asarray(sim.core.download("velocity"), dtype=np.float64))


def momentum(sim) -> np.ndarray:
    """The fluid's total momentum (kg m/s), summed in float64."""
    return sim.info["mass"] * particles(sim)[1].sum(axis=0)


def observed_order(h: list[float], err: list[float]) -> float:
    """The observed order p of err ~ h^p between the coarsest and the finest run (a
    least-squares slope over all of them when there are more than two)."""
    lh, le = np.log(np.asarray(h, dtype=np.float64)), np.log(np.asarray(err, dtype=np.float64))
    return float(np.polyfit(lh, le, 1)[0])


def lower_bound(name: str, measured: float, bound: float, unit: str = "", detail: str = ""):
    """A check that measured >= bound (the reference is the bound, the tolerance 0)."""
    from . import Check

    return Check(name, float(measured), float(bound), 0.0, bool(measured >= bound), unit, detail)


def upper_bound(name: str, measured: float, bound: float, unit: str = "", detail: str = ""):
    """A check that 0 <= measured <= bound (reported as within `bound` of 0)."""
    from . import within

    return within(name, measured, 0.0, bound, unit, detail)
