"""Every coefficient the wind tunnel reports (C_L, C_D, C_M and their standard errors, 2-D and
3-D) recomputed here from its definition and the forces the run stores: the block means of
lift, drag and moment the core keeps, the free stream's density rho = N m / free area (volume)
from the channel and the airfoil polygon, q = rho U^2 / 2, C_L = L' / (q c), C_M = M' / (q c^2).
A coefficient with the dynamic pressure missing its 1/2 (or the chord, or the span) fails."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corpuscle import Simulation
from corpuscle.scene import load_scene


def _polygon_area(p):
    x, y = np.asarray(p, dtype=np.float64).T
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


@pytest.mark.parametrize("scene", ["wind-tunnel", "wind-tunnel-3d"])
def test_coefficients_from_the_stored_forces(scene):
    ov = {"inflow.speed": 1.3, "airfoil.angle_of_attack": 12.0, "airfoil.chord": 0.4,
          "run.end_time": 0.4, "measure.start": 0.25, "measure.block_time": 0.01}
    sim = Simulation.from_scene(load_scene(scene), backend="cpu", particles=1500, overrides=ov)
    sim.run(until=0.4, chunk=200)
    res = sim.result()
    sc = sim.scalars()
    nb = int(sc["nblocks"])
    assert nb >= 4 and res["blocks"] == nb
    lo, hi = np.asarray(sim.params["channel_lo"], np.float64), np.asarray(sim.params["channel_hi"], np.float64)
    free = (hi[0] - lo[0]) * (hi[1] - lo[1]) - _polygon_area(sim.info["airfoil"])
    span = 1.0
    if scene == "wind-tunnel-3d":
        span = hi[2] - lo[2]
        free *= span
    rho = sim.n_particles * float(sim.params["mass"]) / free
    U, c = 1.3, 0.4
    q = 0.5 * rho * U * U
    for force, coef, length in (("lift", "cl", c), ("drag", "cd", c), ("moment", "cm", c * c)):
        blocks = np.asarray(sc["blocks_" + force], np.float64)[:nb] / span  # per unit span
        assert np.any(blocks != 0.0), force
        mean = blocks.mean()
        se = blocks.std(ddof=1) / math.sqrt(nb)
        assert res[force] == pytest.approx(mean, rel=1e-9, abs=1e-12), force
        assert res[coef] == pytest.approx(mean / (q * length), rel=1e-9), coef
        assert res[coef + "_se"] == pytest.approx(se / (q * length), rel=1e-9), coef
