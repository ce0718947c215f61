"""The dam break (Martin & Moyce 1952; Koshizuka & Oka 1996): a water column of width a and
height 2a against the back wall (x = 0) of a closed tank, released at t = 0. The surge front
Z = x_front / a and the column height at the back wall are recorded with every frame
(``front``, ``column``, in units of a, against ``T = t sqrt(2 g / a)``, diagnostic ``T``).
"""

from __future__ import annotations

import math

import numpy as np

from ..schema import KeySpec, SceneError
from ._sph_box import SphBox, column_height, common_keys, dam_front, make_schema

A_DEFAULT = 0.146  # m, Koshizuka & Oka's column width
T_END = 3.5        # T = t sqrt(2 g / a) at the default end


def dam_keys(dim: int, smoothing: float) -> dict[str, KeySpec]:
    end = T_END * math.sqrt(A_DEFAULT / (2.0 * 9.81))
    keys = common_keys(dim, end_time=round(end, 4), record_every=100, smoothing=smoothing, alpha=0.1)
    keys.update({
        "dam.a": KeySpec("float", A_DEFAULT, "m", 0.0, 1e3, "column width a (its height is dam.height a); "
                         "run.end_time's default is T = 3.5 for the default a", lo_open=True),
        "dam.height": KeySpec("float", 2.0, "a", 0.0, 100.0, "column height over a (Martin & Moyce: n^2 = 2)",
                              lo_open=True),
        "dam.tank_length": KeySpec("float", 5.0, "a", 0.0, 1000.0, "tank length over a (the front reaches "
                                   "about 4.4 a at T = 3.5)", lo_open=True),
        "dam.tank_height": KeySpec("float", 2.5, "a", 0.0, 1000.0, "tank height over a (closed lid)", lo_open=True),
    })
    if dim == 3:
        keys["dam.depth"] = KeySpec("float", 0.5, "a", 0.0, 100.0, "tank depth (y) over a", lo_open=True)
    return keys


def _fits(values, arrays) -> None:
    if values["dam.tank_length"] < 1.0 or values["dam.tank_height"] < values["dam.height"]:
        raise SceneError(f"dam.tank_length = {values['dam.tank_length']} must be >= 1 and dam.tank_height = "
                         f"{values['dam.tank_height']} must be >= dam.height = {values['dam.height']} (units of a)")


def tank_size(v) -> np.ndarray:
    """The tank's inner size (m): length and height (2-D), or length, depth and height."""
    a = float(v["dam.a"])
    if "dam.depth" not in v:
        return np.array([v["dam.tank_length"] * a, v["dam.tank_height"] * a])
    return np.array([v["dam.tank_length"] * a, float(v["dam.depth"]) * a, v["dam.tank_height"] * a])


class DamBreakBase(SphBox):
    def geometry(self, v):
        a = float(v["dam.a"])
        size = tank_size(v)
        hi = np.array([a, v["dam.height"] * a]) if self.dim == 2 else np.array([a, size[1], v["dam.height"] * a])
        return size, np.zeros(self.dim), hi

    def extra_info(self, v, info):
        # a and the time scale from the lattice's column (its width rounds to whole spacings)
        a = float(info["fluid_hi"][0] - info["fluid_lo"][0])
        return {"a": a, "time_scale": math.sqrt(2.0 * info["gravity"] / a) if info["gravity"] > 0 else 0.0}

    def front_and_column(self, sim) -> tuple[float, float]:
        pos = self.fluid_positions(sim)
        dp, a = sim.info["spacing"], sim.info["a"]
        return dam_front(pos, dp) / a, column_height(pos, dp) / a

    def extra_diagnostics(self, sim):
        z, h = self.front_and_column(sim)
        return {"T": float(sim.time) * sim.info["time_scale"], "front": z, "column": h}

    def result(self, sim, s):
        out = super().result(sim, s)
        z, h = self.front_and_column(sim)
        out.update({"T": float(sim.time) * sim.info["time_scale"], "front": z, "column": h, "a": sim.info["a"]})
        return out

    def summary(self, result):
        lines, rest = super().summary(result)
        if "front" in result:
            lines.append(f"at T = {result['T']:.3g}: surge front Z = x/a = {result['front']:.3f}, "
                         f"column height {result['column']:.3f} a")
        return lines, rest
