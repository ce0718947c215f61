"""The 2-D dam break (see :mod:`corpuscle.kinds._dam_break`)."""

from ._dam_break import DamBreakBase, _fits, dam_keys, tank_size
from ._sph_box import make_schema


class DamBreak2D(DamBreakBase):
    name = "dam-break-2d"
    dim = 2
    schema = make_schema("dam-break-2d", "2-D dam break: a column of width a and height 2a released against a wall "
                         "(Martin & Moyce 1952)", dam_keys(2, 1.5), 2, [_fits], box=tank_size)
    default_particles = {"cuda": 3200, "cpu": 3200, "serial": 3200}


KIND = DamBreak2D()
