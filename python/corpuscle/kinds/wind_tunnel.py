"""The wind tunnel (seed 000): a 2-D soft-sphere gas streaming past an airfoil in a channel
with walls top and bottom. Particles leaving on the right (or the left) re-enter at the
inflow with free-stream statistics, so the count is constant and the flow steady; the
reaction on the airfoil (lift, drag, moment about the quarter chord) is summed every step
on the backend and averaged in blocks (batch means) over the steady part of the run.

Everything the Python side knows about the kind (see :mod:`corpuscle.kinds`): the schema,
the builder (particle radius from the solid fraction, the airfoil polygon, a jittered
lattice start outside the airfoil, the free-stream velocity), the state, the result (mean
lift, drag, moment and C_L, C_D, C_M with standard errors), the run header and the summary.
The core is cpp/include/corpuscle/scenes/wind_tunnel/.

Units: SI, 2-D (a mass is per particle, a force per unit span). The seed's particles have
unit mass (its accelerations are its forces).

The class is written for both dimensions (``dim``): :mod:`corpuscle.kinds.wind_tunnel_3d` is
the same kind in 3-D (the channel with a periodic span along z, the section extruded across
it), built by the same code paths (the core's stages are one template on D).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any

import numpy as np

from .. import airfoils
from ..schema import INT64_MAX, KeySpec, SceneError, SceneKind, _fmt_value, check_le
from . import Build, Kind, Target, check_memory, core, key_values
from . import _wind_tunnel_body
from ._wind_tunnel_start import KMAX_ROWS, conveyor, place, signed_distance  # noqa: F401  (public here)

__all__ = ["KIND", "WindTunnel", "WIND_TUNNEL_KEYS", "DEFAULT_PARTICLES", "restitution", "damping",
           "airfoil_polygon", "coefficients"]

# the default particle counts: the seed's on CUDA, the original's CPU size elsewhere
# the largest pitch the control takes (degrees, either way)
MAX_PITCH = 45.0

DEFAULT_PARTICLES = {"cuda": 2_097_152, "cpu": 131_072, "serial": 131_072}

# the LBVH traversal stack (entries per thread; shared memory on CUDA): the default and the most
LBVH_STACK, LBVH_MAX_STACK = 32, 128

UNSTABLE_REASONS = {1: "a particle position or velocity became non-finite (NaN/inf)",
                    2: "an LBVH traversal needed more stack than lbvh.stack entries (--neighbors lbvh: raise "
                       f"lbvh.stack, at most {LBVH_MAX_STACK}; the step was not taken)"}

# the default colour range of render and the live viewer: number density 0 .. this x the free stream's
RENDER_DENSITY_SPAN = 4.0

INTEGRATORS = {"forward-euler": 0, "symplectic-euler": 1}
CONTACT_FORMS = {"gather": 0, "reflexive": 1, "reflexive-warp": 2}

_K = KeySpec
WIND_TUNNEL_KEYS: dict[str, KeySpec] = {
    "run.end_time": _K("float", 20.0, "s", 0.0, 1e7, "simulated time at which the run ends", lo_open=True),
    "run.seed": _K("int", 0, "", 0, INT64_MAX, "random seed: start lattice jitter and re-entry positions"),
    "run.record_every": _K("int", 200, "steps", 1, 10**9, "record a frame every this many steps"),
    # the gas
    "gas.particles": _K("int", 0, "", 0, 2**31 - 1,
                        "number of particles; 0: 2,097,152 on CUDA, 131,072 on the CPU backends"),
    "gas.radius": _K("float", 0.0, "m", 0.0, 1.0,
                     "particle radius; 0: from gas.solid_fraction (so --particles keeps the fraction)"),
    "gas.solid_fraction": _K("float", 0.1, "", 0.0, 0.5,
                             "area fraction N pi r^2 / free area that sets the radius when gas.radius = 0",
                             lo_open=True),
    "gas.mass": _K("float", 1.0, "kg", 0.0, 1e6, "particle mass (the seed's: 1)", lo_open=True),
    # contact laws: spring k on the overlap, damper c on the normal approach speed
    "contact.enabled": _K("bool", True, "", doc="particle-particle contacts; false: a collisionless gas "
                          "(only walls and airfoil act, as in free-molecular flow)"),
    "contact.form": _K("enum", "gather", "", doc="gather (each particle sums its own contacts: no atomics, "
                       "reproducible), reflexive (each pair once, the reaction added by atomics; the seed's) or "
                       "reflexive-warp (the same with warp-aggregated atomics, __match_any_sync, on CUDA)",
                       choices=tuple(CONTACT_FORMS)),
    "contact.k": _K("float", 10000.0, "N/m", 0.0, 1e12, "particle-particle spring stiffness", lo_open=True),
    "contact.c": _K("float", 50.0, "N·s/m", 0.0, 1e9, "particle-particle damping (unless contact.restitution)"),
    "contact.restitution": _K("float", 1.0, "", 0.0, 1.0,
                              "particle-particle restitution; > 0 sets contact.c from k and the masses (1: an "
                              "elastic gas, as molecules collide, whose shock stands off the airfoil; 0: "
                              "contact.c decides, the seed's c = 50 giving 0.30, a granular gas whose shock layer "
                              "collapses onto the surface)"),
    "wall.k": _K("float", 10000.0, "N/m", 0.0, 1e12, "particle-wall spring stiffness", lo_open=True),
    "wall.c": _K("float", 50.0, "N·s/m", 0.0, 1e9, "particle-wall damping (unless wall.restitution)"),
    "wall.restitution": _K("float", 0.0, "", 0.0, 1.0, "particle-wall restitution; > 0 sets wall.c"),
    "wall.recycle_scattered": _K("bool", False, "", doc="a particle that touched the airfoil re-enters at the "
                                 "inflow when it reaches a wall, so the walls send no scattered particle back "
                                 "(the free-molecular validation); false: the walls reflect every particle"),
    "wing.k": _K("float", 50000.0, "N/m", 0.0, 1e12, "particle-airfoil spring stiffness", lo_open=True),
    "wing.c": _K("float", 50.0, "N·s/m", 0.0, 1e9, "particle-airfoil damping (unless wing.restitution)"),
    "wing.restitution": _K("float", 0.0, "", 0.0, 1.0, "particle-airfoil restitution; > 0 sets wing.c"),
    # the channel and the free stream
    "channel.length": _K("float", 3.56, "m", 0.0, 1e4, "channel length (x from -length/2 to length/2)", lo_open=True),
    "channel.height": _K("float", 2.0, "m", 0.0, 1e4, "channel height (walls at y = -height/2, height/2)",
                         lo_open=True),
    "inflow.speed": _K("float", 0.05, "m/s", 0.0, 1e4, "free-stream speed U (along +x)", lo_open=True),
    "inflow.thermal": _K("float", 0.0, "", 0.0, 100.0,
                         "thermal speed sqrt(2 kT / m) over U (1 / the speed ratio); 0: the seed's cold beam"),
    "inflow.speed_ratio": _K("float", 0.0, "", 0.0, 1e6,
                             "speed ratio S = U / sqrt(2 kT / m) of the Maxwellian free stream; > 0 sets "
                             "inflow.thermal = 1 / S (0: inflow.thermal decides)"),
    "inflow.lattice": _K("bool", True, "", doc="a cold beam with contacts re-enters as the start's lattice "
                         "(slots moving in at U: no particle lands on another); false: at uniformly random "
                         "heights (overlaps heat the stream)"),
    # the airfoil
    "airfoil.shape": _K("str", "e398", "", doc="'e398' (shipped), a NACA 4-digit code ('naca2412'), "
                        "'flat-plate', or the path of a Selig/Lednicer .dat file (relative: to the scene "
                        "file's folder)", file_beside_scene=True),
    "airfoil.chord": _K("float", 0.5, "m", 0.0, 1e3, "chord length", lo_open=True),
    "airfoil.angle_of_attack": _K("float", 10.0, "deg", -90.0, 90.0, "angle of attack, nose up positive"),
    "airfoil.leading_edge": _K("vec2", [-1.2, 0.0], "m", -1e4, 1e4, "leading-edge position"),
    "airfoil.thickness": _K("float", 0.02, "chord", 0.0, 0.5, "flat-plate thickness", lo_open=True),
    # time stepping
    "timestep.fraction": _K("float", 1.0, "radius", 0.0, 10.0,
                            "the fastest particle moves at most this many radii per step", lo_open=True),
    "timestep.dt_max": _K("float", 0.001, "s", 0.0, 1.0, "largest time step", lo_open=True),
    "timestep.integrator": _K("enum", "symplectic-euler", "", doc="symplectic-euler (returns the contact laws' "
                              "restitution) or forward-euler (the seed's: at the default dt it returns 1.12 for a "
                              "restitution of 0.9 and 1.24 for 1, collisions that gain energy)", choices=tuple(INTEGRATORS)),
    # measurement
    "measure.start": _K("float", 0.5, "", 0.0, 1.0,
                        "the steady part starts at this fraction of run.end_time", hi_open=True),
    "grid.cell": _K("float", 0.0, "m", 0.0, 1e3,
                    "cell edge of the broad-phase grid, at least a contact diameter (0: about one cell per "
                    "particle, sqrt(free area / N))"),
    "lbvh.stack": _K("int", LBVH_STACK, "", 1, LBVH_MAX_STACK,
                     "traversal stack entries per thread of the LBVH (--neighbors lbvh; CUDA keeps them in shared "
                     "memory: 512 bytes a block per entry); a walk that needs more stops the run"),
    "measure.block_time": _K("float", 0.0, "s", 0.0, 1e6,
                             "initial averaging block length; 0: the steady part / 64 (blocks double as needed)"),
}
del _K


def keys_3d(defaults: dict[str, int], end_time: float, span: float) -> dict[str, KeySpec]:
    """The 3-D kind's keys: the 2-D ones (same names, same meaning), the solid fraction a
    volume fraction, the default cell from the volume per particle, and channel.span (the
    periodic extent along z) after channel.height."""
    out: dict[str, KeySpec] = {}
    for name, spec in WIND_TUNNEL_KEYS.items():
        if name == "run.end_time":
            spec = dataclasses.replace(spec, default=end_time)
        elif name == "gas.particles":
            spec = dataclasses.replace(spec, doc=f"number of particles; 0: {defaults['cuda']:,} on CUDA, "
                                                 f"{defaults['cpu']:,} on the CPU backends")
        elif name == "gas.solid_fraction":
            spec = dataclasses.replace(spec, doc="volume fraction N (4/3) pi r^3 / free volume that sets the radius "
                                                 "when gas.radius = 0")
        elif name == "grid.cell":
            spec = dataclasses.replace(spec, doc="cell edge of the broad-phase grid, at least a contact diameter (0: "
                                                 "about one cell per particle, (free volume / N)^(1/3))")
        elif name == "airfoil.leading_edge":
            spec = dataclasses.replace(spec, doc="leading-edge position (x, y; the section spans every z)")
        out[name] = spec
        if name == "channel.height":
            out["channel.span"] = KeySpec("float", span, "m", 0.0, 1e4,
                                          "channel span along z, periodic (z from -span/2 to span/2; the airfoil "
                                          "section is extruded across all of it); at least 4 particle radii",
                                          lo_open=True)
    return out


def _channel_room(values: dict[str, Any], arrays) -> None:
    """The placed airfoil (chord, angle of attack and leading edge applied: what the run
    builds) lies inside the channel; the 3-D kind's section spans z, so x and y decide. A
    3-D body replaces the airfoil (its own check: _wind_tunnel_body.check_body)."""
    if arrays and arrays.get("bodies"):
        return
    L, H = float(values["channel.length"]), float(values["channel.height"])
    poly = airfoil_polygon(values)
    lo, hi = poly.min(axis=0), poly.max(axis=0)
    if not (lo[0] > -L / 2 and hi[0] < L / 2 and lo[1] > -H / 2 and hi[1] < H / 2):
        placed = ", ".join(f"{k} = {_fmt_value(values[k])}" for k in
                           ("airfoil.leading_edge", "airfoil.chord", "airfoil.angle_of_attack"))
        raise SceneError(f"{placed}: the placed airfoil spans x {lo[0]:.4g} .. {hi[0]:.4g} m, y {lo[1]:.4g} .. "
                         f"{hi[1]:.4g} m, not inside the channel (channel.length = {_fmt_value(L)}, channel.height = "
                         f"{_fmt_value(H)}: x within +-{L / 2:.4g} m, y within +-{H / 2:.4g} m)")


def _one_thermal(values: dict[str, Any], arrays) -> None:
    S, th = values["inflow.speed_ratio"], values["inflow.thermal"]
    if S > 0 and th > 0 and abs(th * S - 1.0) > 1e-9:
        raise SceneError(f"inflow.speed_ratio = {_fmt_value(S)} and inflow.thermal = {_fmt_value(th)} disagree "
                         f"(thermal is 1 / speed_ratio): set one of them")


def thermal_ratio(values: dict[str, Any]) -> float:
    """sqrt(2 kT / m) / U of the free stream (0: the cold beam)."""
    S = float(values["inflow.speed_ratio"])
    return 1.0 / S if S > 0 else float(values["inflow.thermal"])


SCHEMA = SceneKind(
    name="wind-tunnel",
    description="2-D soft-sphere gas past an airfoil: lift, drag and moment (seed 000)",
    keys=WIND_TUNNEL_KEYS,
    checks=[_channel_room, _one_thermal],
)


# ---------------------------------------------------------------------------
# physics helpers (the contact law's closed forms are the core's, physics/dem.h)
# ---------------------------------------------------------------------------


def restitution(k: float, c: float, m_eff: float) -> float:
    """Normal restitution of the spring-dashpot law (0 when overdamped): the core's
    restitution_from_damping (physics/dem.h), in double."""
    return core().dem_restitution_for_damping(float(k), float(c), float(m_eff))


def damping(k: float, e: float, m_eff: float) -> float:
    """The damping c that gives restitution e: the core's damping_from_restitution
    (physics/dem.h), in double."""
    return core().dem_damping_for_restitution(float(k), float(e), float(m_eff))


def airfoil_polygon(values: dict[str, Any]) -> np.ndarray:
    """The airfoil in scene coordinates (counter-clockwise, float64 (n, 2))."""
    shape = str(values["airfoil.shape"]).strip()
    if shape.lower() in ("flat-plate", "flat_plate", "plate"):
        base = airfoils.flat_plate(float(values["airfoil.thickness"]))
    else:
        try:
            base = airfoils.load(shape)
        except ValueError as e:
            raise SceneError(f"airfoil.shape: {e}") from None
    return airfoils.place(base, float(values["airfoil.chord"]), float(values["airfoil.angle_of_attack"]),
                          tuple(values["airfoil.leading_edge"]))


def coefficients(values: dict[str, float], rho: float, U: float, chord: float,
                 area: float | None = None) -> dict[str, float]:
    """C_L, C_D, C_M from lift, drag, moment and the free stream: per span over the chord, or
    (a 3-D body) the whole body's over its reference ``area`` (and length ``chord``)."""
    q = 0.5 * rho * U * U
    area = chord if area is None else area
    return {"cl": values["lift"] / (q * area), "cd": values["drag"] / (q * area),
            "cm": values["moment"] / (q * area * chord)}


# ---------------------------------------------------------------------------
# the kind
# ---------------------------------------------------------------------------


class WindTunnel(Kind):
    name = "wind-tunnel"
    schema = SCHEMA
    dim = 2
    default_particles = DEFAULT_PARTICLES
    particle_key = "gas.particles"
    unstable_reasons = UNSTABLE_REASONS
    frame_fields = ()  # the core's table marks what frames record (position, pressure, number_density)
    units = {"position": "m", "velocity": "m/s", "pressure": "N/m", "number_density": "1/m^2", "force": "N/m",
             "lift": "N/m", "drag": "N/m", "moment": "N", "pitch": "deg", "kinetic_energy": "J", "vmax": "m/s",
             "airfoil_contacts": "count"}

    def summary(self, result: dict[str, Any]) -> tuple[list[str], dict[str, Any]]:
        lines = []
        rest = dict(result)
        if "cl" in result:
            def pm(k):
                v, e = result.get(k), result.get(k + "_se")
                return f"{v:.4g} ± {e:.2g}" if v is not None and e is not None and math.isfinite(e) else f"{v:.4g}"
            blocks = result.get("blocks", 0)
            if not result.get("not_measured"):
                lines.append(f"C_L = {pm('cl')}, C_D = {pm('cd')}, C_M = {pm('cm')} "
                             f"(over {blocks} block{'s' if blocks > 1 else ''} from t = {result['measure_start']:.4g} s"
                             + ("; no error estimate from one block)" if blocks == 1 else ")"))
            else:
                # nothing measured (null in --json): the means and their errors are not printed as nan rows
                lines.append(f"C_L, C_D, C_M: not measured ({result['not_measured']})")
                for k in ("lift", "drag", "moment", "lift_se", "drag_se", "moment_se", "not_measured"):
                    rest.pop(k, None)
            for k in ("cl", "cd", "cm", "cl_se", "cd_se", "cm_se"):
                rest.pop(k, None)
        if "particles_note" in result:
            lines.append(result["particles_note"])
            rest.pop("particles_note")
        return lines, rest

    # the span (m) of a 3-D channel; 1 in 2-D (forces per unit span are the totals there)
    def span(self, values) -> float:
        return float(values["channel.span"]) if self.dim == 3 else 1.0

    def build(self, scene, target: Target, checkpoint: dict | None = None) -> Build:
        v = scene.values
        d = self.dim
        n = int(v["gas.particles"]) or self.default_particles.get(target.backend, self.default_particles["cpu"])
        L, H = float(v["channel.length"]), float(v["channel.height"])
        lo, hi = np.array([-L / 2, -H / 2]), np.array([L / 2, H / 2])
        # a 3-D [[bodies]] entry replaces the airfoil (_wind_tunnel_body.py)
        body = _wind_tunnel_body.build_body(v, scene.arrays) if d == 3 else None
        poly = airfoil_polygon(v) if body is None else None
        free_area = L * H - (abs(airfoils.signed_area(poly)) if poly is not None else 0.0)
        if d == 2:
            radius = float(v["gas.radius"]) or math.sqrt(float(v["gas.solid_fraction"]) * free_area / (math.pi * n))
            free = free_area  # the free area (2-D) or volume (3-D)
        else:
            B = self.span(v)
            lo, hi = np.array([-L / 2, -H / 2, -B / 2]), np.array([L / 2, H / 2, B / 2])
            free = free_area * B - (body.volume if body is not None else 0.0)
            radius = float(v["gas.radius"]) or (3.0 * float(v["gas.solid_fraction"]) * free / (4.0 * math.pi * n)) ** (1 / 3)
            if not B >= 4 * radius * (1 + 2e-4):
                given = (f"gas.radius = {radius:g} m" if v["gas.radius"] else
                         f"gas.radius = {radius:.3g} m (from gas.solid_fraction = {v['gas.solid_fraction']:g} "
                         f"and gas.particles = {n})")
                raise SceneError(f"channel.span = {B:g} m is too narrow for {given}: the periodic span must be at "
                                 f"least 4 particle radii ({4 * radius:.3g} m)")
        if not H > 2 * radius:
            given = (f"gas.radius = {radius:g} m" if v["gas.radius"] else
                     f"gas.radius = {radius:.3g} m (from gas.solid_fraction = {v['gas.solid_fraction']:g} "
                     f"and gas.particles = {n})")
            raise SceneError(f"{given} does not fit in the channel: channel.height = {H:g} m must be more than "
                             f"a diameter")
        m = float(v["gas.mass"])
        laws = {}
        for key, m_eff in (("contact", m / 2), ("wall", m), ("wing", m)):
            k, c, e = float(v[f"{key}.k"]), float(v[f"{key}.c"]), float(v[f"{key}.restitution"])
            laws[key] = (k, damping(k, e, m_eff) if e > 0 else c)
        chord = float(v["airfoil.chord"]) if body is None else body.reference_length
        a = math.radians(float(v["airfoil.angle_of_attack"]))
        le = np.asarray(v["airfoil.leading_edge"], dtype=np.float64)
        quarter = le + 0.25 * chord * np.array([math.cos(a), -math.sin(a)]) if body is None else body.centroid[:2]
        end = float(v["run.end_time"])
        t0 = float(v["measure.start"]) * end
        block = float(v["measure.block_time"]) or max((end - t0) / 64.0, 1e-9)
        params = {
            "n": n, "integrator": INTEGRATORS[v["timestep.integrator"]], "radius": radius, "mass": m,
            "k": laws["contact"][0], "c": laws["contact"][1], "k_wall": laws["wall"][0], "c_wall": laws["wall"][1],
            "k_wing": laws["wing"][0], "c_wing": laws["wing"][1],
            "channel_lo": lo.tolist(), "channel_hi": hi.tolist(), "speed": float(v["inflow.speed"]),
            "thermal": thermal_ratio(v) / math.sqrt(2.0), "collide": int(bool(v["contact.enabled"])),
            "recycle_scattered": int(bool(v["wall.recycle_scattered"])),
            "reflexive": CONTACT_FORMS[v["contact.form"]], "dt_fraction": float(v["timestep.fraction"]),
            # about one cell per particle: at 2,097,152 particles on the H200 2,574 steps/s
            # against 1,846 with cells of one contact diameter (most of them empty, 2026-12-01)
            "cell": float(v["grid.cell"]) or (math.sqrt(free_area / n) if d == 2 else (free / n) ** (1 / 3)),
            "lbvh_stack": int(v["lbvh.stack"]),
            "dt_max": float(v["timestep.dt_max"]), "quarter_chord": quarter.tolist(), "measure_start": t0,
            "block_time": block, "seed": int(v["run.seed"]) & 0xFFFFFFFF,
        }
        if params["collide"] and params["thermal"] == 0.0 and v["inflow.lattice"]:
            params.update(conveyor(n, radius, lo, hi, poly, body))
        check_memory(self.name, target, params, key_values(scene, ("gas.particles", "gas.radius", "grid.cell")),
                     f"{n} particles")
        if poly is not None and len(poly) > 1024:
            raise SceneError(f"airfoil.shape: {len(poly)} vertices, at most 1024")
        if checkpoint is None:
            pos, vel = place(n, radius, lo, hi, poly, params, int(v["run.seed"]), body)
        else:
            pos = np.ascontiguousarray(checkpoint["position"], dtype=np.float32)
            vel = np.ascontiguousarray(checkpoint["velocity"], dtype=np.float32)
            if pos.shape != (n, d):
                raise ValueError(f"checkpoint: {pos.shape[0] if pos.ndim else 0} particles, the scene has {n}")
        rho = n * m / free  # per unit area (2-D) or volume (3-D)
        info = {"radius": radius, "mass": m, "density": rho, "chord": chord, "airfoil": poly, "free_area": free_area,
                "speed": float(v["inflow.speed"]), "measure_start": t0,
                "restitution_pp": restitution(laws["contact"][0], laws["contact"][1], m / 2),
                "restitution_wall": restitution(laws["wall"][0], laws["wall"][1], m),
                "restitution_wing": restitution(laws["wing"][0], laws["wing"][1], m)}
        if d == 3:
            info.update(span=self.span(v), free_volume=free)  # the free volume's section: free_area
        arrays = {"position": pos, "velocity": vel}
        if body is None:
            arrays["airfoil"] = np.ascontiguousarray(poly, dtype=np.float32)
        else:  # forces are the whole body's; C_L, C_D, C_M on its reference area and length
            arrays.update(_wind_tunnel_body.core_arrays(body))
            info.update(body=_wind_tunnel_body.header_obstacle(body), reference_area=body.reference_area,
                        body_volume=body.volume, torque_about=body.centroid.tolist())
        return Build(params, arrays, info)

    def state(self, sim, s: dict[str, Any]) -> dict[str, Any]:
        f = s["airfoil_force"]
        # lift, drag, moment per unit span (a 3-D body's: the whole body's)
        b = float(sim.info["span"]) if self.dim == 3 and not sim.info.get("body") else None
        per = (lambda x: float(x) / b) if b else float
        return {"time": s["time"], "end_time": s["end_time"], "step": s["step"], "dt": s["dt"],
                "done": bool(s["done"]), "bad": s["bad"], "bad_step": s["bad_step"],
                "lift": per(f[1]), "drag": per(f[0]), "moment": per(s["airfoil_moment"]),
                "airfoil_contacts": int(s["airfoil_contacts"]), "wall_force": list(s["wall_force"]),
                "total_force": list(s["total_force"]), "kinetic_energy": float(s["sums_ke"]),
                "vmax": float(s["vmax"]), "recycled": int(s["recycled"]), "pushouts": int(s["pushouts"]),
                "chosen_dt": float(s["chosen_dt"]),
                **({"side_force": float(f[2]), "torque": [float(x) for x in s["body_torque"]]}
                   if sim.info.get("body") else {})}

    def diagnostics(self, sim, s: dict[str, Any]) -> dict[str, float]:
        st = self.state(sim, s)
        out = {k: float(st[k]) for k in ("lift", "drag", "moment", "kinetic_energy", "vmax", "airfoil_contacts")}
        out["pitch"] = float(sim.control["pitch"][0])
        return out

    def averages(self, sim, s: dict[str, Any]) -> dict[str, Any]:
        """Mean lift, drag, moment and their standard errors from the block means (batch
        means: the blocks are long against the force's correlation time)."""
        nb = int(s["nblocks"])
        out: dict[str, Any] = {"blocks": nb, "block_time": float(s["block_len"])}
        # per unit span (3-D: the whole span's / span; a 3-D body: the whole body's)
        span = float(sim.info["span"]) if self.dim == 3 and not sim.info.get("body") else 1.0
        touched = False
        for name, key in (("lift", "blocks_lift"), ("drag", "blocks_drag"), ("moment", "blocks_moment")):
            b = np.asarray(s[key], dtype=np.float64)[:nb]
            if span != 1.0:
                b = b / span
            touched = touched or bool(np.any(b != 0.0))
            out[name] = float(b.mean()) if nb else float("nan")
            out[name + "_se"] = float(b.std(ddof=1) / math.sqrt(nb)) if nb > 1 else float("nan")
        # why nothing was measured (the means are then NaN: null in JSON), or None
        t0 = float(sim.info["measure_start"])
        out["not_measured"] = (f"the run ended before the measurement window at t = {t0:.4g} s" if not nb else
                               None if touched else
                               f"no particle touched the {'body' if sim.info.get('body') else 'airfoil'} in the measurement window from t = {t0:.4g} s: "
                               f"its force was exactly 0 in every block")
        if out["not_measured"]:
            for name in ("lift", "drag", "moment"):
                out[name] = out[name + "_se"] = float("nan")
        return out

    def result(self, sim, s: dict[str, Any]) -> dict[str, Any]:
        av = self.averages(sim, s)
        U, c, rho = sim.info["speed"], sim.info["chord"], sim.info["density"]
        # the reference area: the chord (per unit span) or a 3-D body's reference area
        area = float(sim.info.get("reference_area") or c)
        co = coefficients(av, rho, U, c, area)
        q = 0.5 * rho * U * U
        out = {"lift": av["lift"], "drag": av["drag"], "moment": av["moment"],
               "lift_se": av["lift_se"], "drag_se": av["drag_se"], "moment_se": av["moment_se"],
               "cl": co["cl"], "cd": co["cd"], "cm": co["cm"],
               "cl_se": av["lift_se"] / (q * area), "cd_se": av["drag_se"] / (q * area),
               "cm_se": av["moment_se"] / (q * area * c),
               "blocks": av["blocks"], "measure_start": sim.info["measure_start"],
               **({"not_measured": av["not_measured"]} if av["not_measured"] else {}),
               "recycled": int(s["recycled"]), "pushouts": int(s["pushouts"])}
        if not int(sim.scene.values["gas.particles"]):
            out["particles_note"] = (f"{sim.n_particles:,} particles (the {sim.backend} default; "
                                     f"radius {sim.info['radius']:.3g} m)")
        return out

    def header(self, sim) -> dict[str, Any]:
        p = sim.params
        if sim.info.get("body"):  # a 3-D body replaces the airfoil: its triangles
            airfoil = dict(sim.info["body"])
        else:
            airfoil = {"type": "polygon", "name": "airfoil", "points": sim.info["airfoil"].tolist(),
                       "chord": sim.info["chord"], "file": str(sim.scene.values["airfoil.shape"]),
                       "angle_of_attack": float(sim.scene.values["airfoil.angle_of_attack"]),
                       # the control's pitch turns it (nose up: clockwise) about the quarter chord
                       "turn": {"diagnostic": "pitch", "about": list(p["quarter_chord"]), "sign": -1.0}}
        if sim.info.get("body"):
            pass
        elif self.dim == 3:
            # the section (x, y points) extruded along z across the whole (periodic) span
            airfoil["extrude"] = [float(p["channel_lo"][2]), float(p["channel_hi"][2])]
            airfoil["periodic"] = [False, False, True]
        extra = {"up": "+y"} if self.dim == 3 else {}  # the walls are bottom and top (a view's up), z the span
        return {"container": {"type": "box", "min": list(p["channel_lo"]), "max": list(p["channel_hi"])},
                "obstacles": [airfoil], **extra,
                "bodies": [], "particles": sim.n_particles, "particle_radius": sim.info["radius"],
                "mass": sim.info["mass"], "free_stream": [p["speed"]] + [0.0] * (self.dim - 1),
                "units": self.units_of(sim), "render": self.render_defaults(sim)}

    def units_of(self, sim) -> dict[str, str]:
        """The units of the run's values: a 3-D body's forces are the whole body's (N, N m)."""
        u = dict(self.units)
        if sim.info.get("body"):
            u.update(lift="N", drag="N", moment="N·m", side_force="N", torque="N·m")
        return u

    def render_defaults(self, sim) -> dict[str, Any]:
        """How render and the live viewer colour this kind by default: the number density on a
        fixed range from the free stream's, 0 to RENDER_DENSITY_SPAN times N / free area (3-D:
        free volume). The seed's pressure (contact-force sums) is zero for nearly every
        particle of the stream, so it showed black on black; the density shows the compressed
        layer ahead of and under the airfoil (saturating), the stream (a quarter of the ramp)
        and the rarefied wake behind it (dark)."""
        free = float(sim.info["free_volume"] if self.dim == 3 else sim.info["free_area"])
        n0 = sim.n_particles / free
        return {"color": "number_density", "range": [0.0, RENDER_DENSITY_SPAN * n0], "log": False, "ramp": "heat",
                "free_stream_density": n0}

    def control(self, sim, speed_scale=0.0, pitch=0.0) -> dict[str, list[float]]:
        """The re-entering free stream's speed is U (1 + speed_scale); the airfoil turns nose
        up by ``pitch`` degrees about its quarter chord (the angle of attack is the scene's
        plus the pitch), from the next step on, with no rebuild."""
        values = {}
        for name, value in (("speed_scale", speed_scale), ("pitch", pitch)):
            if isinstance(value, (list, tuple, np.ndarray)) and np.shape(value) == (1,):
                value = value[0]  # as the core lists it: one number
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
                raise TypeError(f"{name} must be a number, got {value!r}")
            values[name] = float(value)
        x, p = values["speed_scale"], values["pitch"]
        if not math.isfinite(x) or x <= -1.0:
            raise ValueError(f"speed_scale must be finite and > -1, got {speed_scale!r}")
        # the stream within inflow.speed's own range: faster, dt (a fraction of a radius per
        # step at the fastest particle) shrinks until the run stands still in simulated time
        top, U = float(WIND_TUNNEL_KEYS["inflow.speed"].hi), float(sim.info["speed"])
        if U * (1.0 + x) > top:
            raise ValueError(f"speed_scale = {x:g} makes the stream U (1 + speed_scale) = {U * (1.0 + x):.4g} m/s, "
                             f"above inflow.speed's bound {top:g} m/s")
        if not math.isfinite(p) or abs(p) > MAX_PITCH:
            raise ValueError(f"pitch must be finite degrees in [-{MAX_PITCH:g}, {MAX_PITCH:g}], got {pitch!r}")
        return {"speed_scale": [x], "pitch": [p]}

    def angle_of_attack(self, sim) -> float:
        """Degrees: the scene's angle of attack plus the control's pitch."""
        return float(sim.scene.values["airfoil.angle_of_attack"]) + float(sim.control["pitch"][0])

    def live_controls(self, sim) -> list[dict[str, Any]]:
        """The live page's sliders: the inflow speed and the angle of attack."""
        U, a = float(sim.info["speed"]), float(sim.scene.values["airfoil.angle_of_attack"])
        speed = {"control": "speed_scale", "label": "inflow speed", "unit": "m/s", "min": 0.1 * U, "max": 3.0 * U,
                 "step": 0.01 * U, "value": U, "scale": 1.0 / U, "offset": -1.0}
        if sim.info.get("body"):  # a 3-D body does not pitch (the control turns the airfoil only)
            return [speed]
        return [speed,
                {"control": "pitch", "label": "angle of attack", "unit": "°", "min": max(a - MAX_PITCH, -90.0),
                 "max": min(a + MAX_PITCH, 90.0), "step": 0.5, "value": a, "scale": 1.0, "offset": -a}]

    def check_positions(self, sim, positions: np.ndarray) -> None:
        lo, hi = np.asarray(sim.params["channel_lo"]), np.asarray(sim.params["channel_hi"])
        out = np.flatnonzero(~np.all((positions >= lo) & (positions <= hi), axis=1))
        if out.size:
            raise ValueError(f"positions[{int(out[0])}] = {positions[int(out[0])].tolist()} is outside the channel")


KIND = WindTunnel()
