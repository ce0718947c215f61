"""The 3-D wind tunnel (``wind-tunnel-3d``): the wind tunnel's soft-sphere gas in a channel
with walls top and bottom (y) and a periodic span along z, past the airfoil section extruded
across the whole span. The same kind as :mod:`corpuscle.kinds.wind_tunnel`, built by the same
code (its class, with ``dim = 3``; the core's stages are one template on the dimension,
cpp/include/corpuscle/scenes/wind_tunnel/).

Why a periodic span: a 2-D section test wants the flow of an infinitely long wing, which a
periodic span gives with no end walls (walls at the span's ends would add their own boundary
layers and corner flows, and the measured force would depend on the span). Particle-particle
contacts reach across the periodic boundary (the core searches the index around each particle's
image near the ends); the airfoil's contact is the 2-D polygon's in x-y (its surface has no z
normal), so the z velocity of a particle is untouched by it.

Forces are reported per unit span (lift, drag: N/m; moment about the quarter-chord line: N),
and C_L, C_D, C_M use the free stream's mass density per volume, rho = N m / free volume:
C_L = L' / (rho U^2 c / 2), L' the lift per unit span (the whole span's lift / span).

A ``[[bodies]]`` entry (a closed mesh from an STL/OBJ/PLY file, or a primitive) replaces the
airfoil (:mod:`corpuscle.kinds._wind_tunnel_body`): its triangles are held in the engine's LBVH
and touched by signed distance; its forces are the whole body's (N), its moment about the z
axis through its centroid (N m), and C_L, C_D, C_M use its reference area and length.
"""

from __future__ import annotations

from ..geometry import body_keys
from ..schema import SceneKind
from ._wind_tunnel_body import BODY_KEYS, MAX_BODIES, check_body
from .wind_tunnel import WindTunnel, _channel_room, _one_thermal, keys_3d

__all__ = ["KIND", "WindTunnel3D", "DEFAULT_PARTICLES", "WIND_TUNNEL_3D_KEYS"]

# CUDA: the 2-D kind's GPU size (2,097,152, radius 0.0027 m at the 0.25 m span); the CPU
# backends: a size whose default run (10 s, about 10,000 steps) takes under a minute on 2 cores
DEFAULT_PARTICLES = {"cuda": 2_097_152, "cpu": 8_192, "serial": 8_192}
END_TIME = 10.0  # s: the default run (about 10,000 steps at dt_max)
SPAN = 0.25  # m: half a chord (the span only needs to exceed the flow's correlation lengths)

WIND_TUNNEL_3D_KEYS = {**keys_3d(DEFAULT_PARTICLES, END_TIME, SPAN), **BODY_KEYS}

SCHEMA = SceneKind(
    name="wind-tunnel-3d",
    description="3-D soft-sphere gas past an airfoil spanning a periodic channel: lift, drag and moment per span",
    keys=WIND_TUNNEL_3D_KEYS,
    # [[bodies]]: one closed, fixed body (a mesh or a primitive) in place of the airfoil
    arrays={"bodies": body_keys(3)},
    required_in_arrays={"bodies": ("shape",)},
    max_in_arrays={"bodies": MAX_BODIES},
    checks=[_channel_room, _one_thermal, check_body],
)


class WindTunnel3D(WindTunnel):
    name = "wind-tunnel-3d"
    schema = SCHEMA
    dim = 3
    default_particles = DEFAULT_PARTICLES
    units = {"position": "m", "velocity": "m/s", "pressure": "N", "number_density": "1/m^3", "force": "N",
             "lift": "N/m", "drag": "N/m", "moment": "N", "pitch": "deg", "kinetic_energy": "J", "vmax": "m/s",
             "airfoil_contacts": "count"}


KIND = WindTunnel3D()
