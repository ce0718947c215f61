"""The 3-D dam break (see :mod:`corpuscle.kinds._dam_break`)."""

from ._dam_break import DamBreakBase, _fits, dam_keys, tank_size
from ._sph_box import make_schema


class DamBreak(DamBreakBase):
    name = "dam-break"
    dim = 3
    schema = make_schema("dam-break", "3-D dam break: a column of width a and height 2a released against a wall "
                         "(Martin & Moyce 1952)", dam_keys(3, 1.732), 3, [_fits], box=tank_size)
    default_particles = {"cuda": 8000, "cpu": 8000, "serial": 8000}


KIND = DamBreak()
