"""The fluid box (seed 002): a block of SPH fluid released in a closed box, for size sweeps
(``--particles`` from 128 to millions) and the three neighbour searches (``--neighbors grid``,
``compact``, ``allpairs``). See :mod:`corpuscle.kinds._sph_box` for the model and the walls.
"""

from __future__ import annotations

import numpy as np

from ..schema import KeySpec, SceneError
from ._sph_box import SphBox, common_keys, make_schema

KEYS = common_keys(3, end_time=0.5, record_every=100, smoothing=1.732, alpha=0.05)
KEYS.update({
    "box.size": KeySpec("vec3", [1.0, 1.0, 1.0], "m", 0.0, 1e4, "the box's inner size (x, y, z; gravity along -z)",
                        lo_open=True),
    "fluid.lo": KeySpec("vec3", [0.0, 0.0, 0.0], "m", 0.0, 1e4, "the fluid block's lower corner"),
    "fluid.hi": KeySpec("vec3", [0.5, 1.0, 0.5], "m", 0.0, 1e4, "the fluid block's upper corner"),
})


def _block_inside(values, arrays) -> None:
    lo, hi, size = (np.asarray(values[k], dtype=float) for k in ("fluid.lo", "fluid.hi", "box.size"))
    if np.any(hi <= lo) or np.any(hi > size):
        raise SceneError(f"fluid.lo = {values['fluid.lo']} .. fluid.hi = {values['fluid.hi']} must be a block "
                         f"inside box.size = {values['box.size']}")


class FluidBox(SphBox):
    name = "fluid-box"
    dim = 3
    schema = make_schema("fluid-box", "a block of SPH fluid released in a closed box (seed 002)", KEYS, 3,
                         [_block_inside], box=lambda v: v["box.size"])
    default_particles = {"cuda": 1_048_576, "cpu": 4096, "serial": 4096}

    def geometry(self, v):
        return (np.asarray(v["box.size"], dtype=np.float64), np.asarray(v["fluid.lo"], dtype=np.float64),
                np.asarray(v["fluid.hi"], dtype=np.float64))


KIND = FluidBox()
