"""The 2-D fluid box: a block of SPH fluid in a rectangle, the kind of the canonical flows
(``taylor-green``: periodic in x and y; ``poiseuille``: periodic in x between walls driven by
a body force; ``lid-driven-cavity``: a closed square whose top wall slides). See
:mod:`corpuscle.kinds._sph_box` for the model, the walls, periodic axes and moving walls.
"""

from __future__ import annotations

import numpy as np

from ..schema import KeySpec, SceneError
from ._sph_box import SphBox, common_keys, make_schema

KEYS = common_keys(2, end_time=0.5, record_every=100, smoothing=1.5, alpha=0.05)
KEYS.update({
    "box.size": KeySpec("vec2", [1.0, 1.0], "m", 0.0, 1e4, "the box's inner size (x, y; gravity along -y)",
                        lo_open=True),
    "fluid.lo": KeySpec("vec2", [0.0, 0.0], "m", 0.0, 1e4, "the fluid block's lower corner"),
    "fluid.hi": KeySpec("vec2", [0.5, 0.5], "m", 0.0, 1e4, "the fluid block's upper corner"),
})


def _block_inside(values, arrays) -> None:
    lo, hi, size = (np.asarray(values[k], dtype=float) for k in ("fluid.lo", "fluid.hi", "box.size"))
    if np.any(hi <= lo) or np.any(hi > size):
        raise SceneError(f"fluid.lo = {values['fluid.lo']} .. fluid.hi = {values['fluid.hi']} must be a block "
                         f"inside box.size = {values['box.size']}")


class FluidBox2D(SphBox):
    name = "fluid-box-2d"
    dim = 2
    schema = make_schema("fluid-box-2d", "a block of SPH fluid in a 2-D box (the canonical flows: periodic axes, "
                         "moving walls)", KEYS, 2, [_block_inside], box=lambda v: v["box.size"])
    default_particles = {"cuda": 65536, "cpu": 1024, "serial": 1024}

    def geometry(self, v):
        return (np.asarray(v["box.size"], dtype=np.float64), np.asarray(v["fluid.lo"], dtype=np.float64),
                np.asarray(v["fluid.hi"], dtype=np.float64))


KIND = FluidBox2D()
