"""The Magic 8-Ball (seed 001): SPH fluid in a sphere with a rigid cube die, shaken by a
schedule; the face toward the window (+z) gives the answer.

Everything the Python side knows about the kind (see :mod:`corpuscle.kinds` for the
contract): its scene schema (``MAGIC8BALL_KEYS``, ``[[shake]]``, cross-checks), the
builder (h scaling, Poisson-disk placement, the core's parameters, room, memory and list
capacity checks), the state, die and particle setters, diagnostics, result, run header,
CLI summary and frames. Key names are read by the core (cpp/include/corpuscle/scenes/
magic8ball/): keep them.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..schema import INT32_MAX, INT64_MAX, KeySpec, SceneError, SceneKind, _fmt_value, check_le, check_windows
from . import CONTROL_BOUNDS, Build, Kind, Target, bounded_control, check_memory, core, finite_vector, key_values

__all__ = ["KIND", "Magic8Ball", "MAGIC8BALL_KEYS", "SHAKE_KEYS", "DEFAULT_ANSWERS", "DIE_FACES", "UNSTABLE_REASONS"]

# die faces: number -> outward normal in the body frame (opposite faces sum to 7)
DIE_FACES = {1: (1, 0, 0), 6: (-1, 0, 0), 2: (0, 1, 0), 5: (0, -1, 0), 3: (0, 0, 1), 4: (0, 0, -1)}

# the reasons a run is stopped as unstable, by the core's code (kBad* in scenes/magic8ball/model.h)
UNSTABLE_REASONS = {1: "a particle position or velocity became non-finite (NaN/inf)",
                    2: "the die's state became non-finite (NaN/inf)",
                    3: "a particle moved faster than 100 times the sound speed",
                    4: "a particle had more neighbours than its list holds and the lists could not grow "
                       "(not enough memory)"}

# ---------------------------------------------------------------------------
# the scene schema
# ---------------------------------------------------------------------------

DEFAULT_ANSWERS = [
    "It is certain",
    "Ask again later",
    "Outlook good",
    "Don't count on it",
    "Signs point to yes",
    "Very doubtful",
]

_K = KeySpec
MAGIC8BALL_KEYS: dict[str, KeySpec] = {
    # run control
    "run.end_time": _K("float", 5.0, "s", 0.0, 1e6, "simulated time at which the run ends", lo_open=True),
    "run.seed": _K("int", 1, "", 0, INT64_MAX, "random seed for the Poisson-disk start"),
    "run.record_every": _K("int", 100, "steps", 1, 10**9, "record a frame every this many steps"),
    # spherical container
    "container.radius": _K("float", 0.15, "m", 0.0, 100.0, "radius of the spherical container", lo_open=True),
    "container.restitution": _K("float", 0.3, "", 0.0, 1.0, "fraction of normal wall velocity kept on contact"),
    "container.friction": _K("float", 0.1, "", 0.0, 1.0, "fraction of tangential wall velocity removed on contact"),
    "container.shell_inertia": _K(
        "float", 0.02, "kg·m²", 0.0, 1e6, "moment of inertia of the ball shell that a shake torque acts on", lo_open=True
    ),
    "container.spin_damping": _K("float", 2.0, "1/s", 0.0, 1e4, "decay rate of the shell's spin"),
    # fluid
    "fluid.particles": _K("int", 3500, "", 200, 2_000_000, "number of fluid particles"),
    "fluid.rest_density": _K("float", 1000.0, "kg/m³", 0.0, 1e5, "rest density of the fluid", lo_open=True),
    "fluid.stiffness": _K("float", 12000.0, "Pa", 0.0, 1e10, "Tait equation-of-state stiffness B", lo_open=True),
    "fluid.gamma": _K("float", 7.0, "", 1.0, 10.0, "Tait equation-of-state exponent"),
    "fluid.viscosity": _K("float", 10.0, "Pa·s", 0.0, 1e5, "dynamic viscosity (viscosity-kernel Laplacian)"),
    "fluid.xsph": _K("float", 0.1, "", 0.0, 1.0, "XSPH velocity smoothing factor"),
    "fluid.density_floor": _K(
        "float", 0.01, "", 0.0, 1.0, "lowest density allowed, as a fraction of rest density", lo_open=True
    ),
    # smoothing length
    "sph.h": _K("float", 0.05, "m", 0.0, 10.0, "SPH smoothing length (kernel support radius)", lo_open=True),
    "sph.scale_h": _K("bool", True, "", doc="scale h with particle count so neighbour counts stay fixed"),
    "sph.reference_particles": _K("int", 3500, "", 1, INT32_MAX, "particle count at which sph.h applies"),
    "sph.skin": _K("float", 0.2, "h", 0.0, 1.0,
                   "neighbour-list skin: lists reach h (1 + skin) and are reused until a particle moved too far; 0 rebuilds every step"),
    "sph.lanes": _K("int", 0, "", 0, 32, "CUDA threads per particle in the density and force passes: a warp (32) "
                    "or groups of 16, 8 or 4 of one; 0: chosen by the state's size (32 below 262,144 particles in all, "
                    "8 from there; the CPU runs one)"),
    "sph.list_build": _K("enum", "auto", "", doc="how the neighbour lists are rebuilt: cells (the 27 cells around "
                         "each particle) or scan (every particle and ghost of its scene: cheaper for small scenes); "
                         "auto: scan up to 500 particles a scene", choices=("auto", "cells", "scan")),
    "sph.path": _K("enum", "auto", "", doc="how the cuda backend steps the scenes: chip (a thread block per scene, "
                   "the scene in the multiprocessor's shared memory, many steps a launch), general (the engine's "
                   "stages over global memory); auto: chip for a batch whose scenes fit (docs/magic8ball.md)",
                   choices=("auto", "general", "chip")),
    "sph.max_list_memory": _K("float", 0.0, "MB", 0.0, 1e9,
                              "most memory the neighbour lists may grow to when they overflow; 0: what the backend has free"),
    # gravity
    "gravity.g": _K("vec3", [0.0, 0.0, -9.81], "m/s²", -1e4, 1e4, "gravitational acceleration"),
    # rigid cube die
    "die.side": _K("float", 0.064, "m", 0.0, 10.0, "edge length of the cube die", lo_open=True),
    "die.density": _K(
        "float", 1000.0, "kg/m³", 0.0, 1e5, "die density (equal to fluid.rest_density = neutrally buoyant)", lo_open=True
    ),
    "die.contact_stiffness": _K(
        "float", 2.0e4, "1/s²", 0.0, 1e9, "spring acceleration per metre of penetration into the contact margin"
    ),
    "die.contact_margin": _K("float", 0.16, "h", 0.0, 5.0, "contact margin around the die, in units of h", lo_open=True),
    "die.drag": _K("float", 20.0, "1/s", 0.0, 1e6, "relative-velocity drag rate on particles in the margin"),
    "die.restitution": _K("float", 0.3, "", 0.0, 1.0, "fraction of normal velocity kept when the die hits the wall"),
    "die.linear_damping": _K("float", 0.0, "1/s", 0.0, 1e4, "linear velocity damping rate of the die"),
    "die.angular_damping": _K("float", 0.0, "1/s", 0.0, 1e4, "angular velocity damping rate of the die"),
    "die.position": _K("vec3", [0.0, 0.0, 0.0], "m", None, None, "initial centre of the die (inside the container)"),
    "die.answers": _K("list[str]", list(DEFAULT_ANSWERS), "", doc="answers printed on faces 1..6", length=6),
    # adaptive time step
    "timestep.dt_min": _K("float", 2e-5, "s", 0.0, 1.0, "smallest time step", lo_open=True),
    "timestep.dt_max": _K("float", 1.5e-3, "s", 0.0, 1.0, "largest time step", lo_open=True),
    "timestep.cfl_advective": _K("float", 0.4, "", 0.0, 1.0, "advective CFL number (h / max speed)", lo_open=True),
    "timestep.cfl_acoustic": _K("float", 0.4, "", 0.0, 1.0, "acoustic CFL number (h / sound speed)", lo_open=True),
    "timestep.cfl_force": _K("float", 0.25, "", 0.0, 1.0, "force limit factor (sqrt(h / max acceleration))", lo_open=True),
    "timestep.cfl_viscous": _K("float", 0.125, "", 0.0, 1.0, "viscous limit factor (h² rho / mu)", lo_open=True),
}
del _K

SHAKE_KEYS: dict[str, KeySpec] = {
    "start": KeySpec("float", 0.0, "s", 0.0, 1e6, "time the shake starts (required)"),
    "end": KeySpec("float", 0.0, "s", 0.0, 1e6, "time the shake ends (required)", lo_open=True),
    # the bounds of every control input (CONTROL_BOUNDS)
    "acceleration": KeySpec("vec3", [0.0, 0.0, 0.0], CONTROL_BOUNDS["acceleration"][1],
                            -CONTROL_BOUNDS["acceleration"][0], CONTROL_BOUNDS["acceleration"][0],
                            "container linear acceleration"),
    "torque": KeySpec("vec3", [0.0, 0.0, 0.0], CONTROL_BOUNDS["torque"][1], -CONTROL_BOUNDS["torque"][0],
                      CONTROL_BOUNDS["torque"][0], "torque applied to the container shell"),
}


def _die_inside_container(values: dict[str, Any], arrays: dict[str, list[dict[str, Any]]]) -> None:
    """The die's bounding sphere must lie inside the container."""
    p = values["die.position"]
    side = values["die.side"]
    radius = values["container.radius"]
    reach = math.sqrt(sum(x * x for x in p)) + side * math.sqrt(3.0) / 2.0
    if not reach < radius:
        raise SceneError(
            f"die.position must keep the die inside the container (|position| + die.side*sqrt(3)/2 < "
            f"container.radius), got die.position = {_fmt_value(p)}, die.side = {_fmt_value(side)}, "
            f"container.radius = {_fmt_value(radius)}"
        )

def _lanes_width(values: dict[str, Any], arrays: dict[str, list[dict[str, Any]]]) -> None:
    """sph.lanes is a width the CUDA pair passes have (or 0: automatic)."""
    if values["sph.lanes"] not in (0, 4, 8, 16, 32):
        raise SceneError(f"sph.lanes must be 0 (automatic), 4, 8, 16 or 32, got {_fmt_value(values['sph.lanes'])}")


SCHEMA = SceneKind(
    name="magic8ball",
    description="3-D SPH fluid in a sphere with a rigid cube die (seed 001)",
    keys=MAGIC8BALL_KEYS,
    arrays={"shake": SHAKE_KEYS},
    required_in_arrays={"shake": ("start", "end")},
    max_in_arrays={"shake": 32},  # kMaxShakes of scenes/magic8ball/model.h
    checks=[check_le("timestep.dt_min", "timestep.dt_max"), check_windows("shake"), _die_inside_container,
            _lanes_width],
)


# ---------------------------------------------------------------------------
# geometry helpers
# ---------------------------------------------------------------------------


def fluid_volume(radius, side):
    """The fluid's volume: the sphere of the container less the die (scalars or arrays)."""
    return 4.0 / 3.0 * math.pi * radius ** 3 - side ** 3


def particle_mass(rest_density, radius, side, n):
    """The mass of one of n fluid particles filling the container at rest density (the single
    scene's and, per scene as arrays, the batch's)."""
    return rest_density * fluid_volume(radius, side) / n


def die_mass_inertia(density, side):
    """The die's mass and its moment of inertia about each axis, m side^2 / 6 (a solid cube;
    scalars or arrays)."""
    mass = density * side ** 3
    return mass, mass * side ** 2 / 6.0


def _random_quaternion(rng: np.random.Generator) -> np.ndarray:
    # uniform on SO(3) (Shoemake 1992)
    u1, u2, u3 = rng.random(3)
    a, b = math.sqrt(1 - u1), math.sqrt(u1)
    return np.array([b * math.cos(2 * math.pi * u3), a * math.sin(2 * math.pi * u2),
                     a * math.cos(2 * math.pi * u2), b * math.sin(2 * math.pi * u3)], dtype=np.float32)


def _rotation(q) -> np.ndarray:
    """The rotation matrix (body to container frame) of unit quaternion q (w, x, y, z)."""
    w, x, y, z = (float(c) for c in q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _rotate_inv(q, v) -> list[float]:
    """v rotated by the inverse of unit quaternion q (w, x, y, z): container to body frame."""
    return (_rotation(q).T @ np.asarray(v, dtype=np.float64)).tolist()


# ---------------------------------------------------------------------------
# the kind
# ---------------------------------------------------------------------------


class Magic8Ball(Kind):
    """The magic8ball kind (see the module's documentation)."""
    fluid = True

    name = "magic8ball"
    schema = SCHEMA
    dim = 3
    particle_key = "fluid.particles"
    methods = ("set_die",)
    checkpoint_extra = ("spacing",)
    unstable_reasons = UNSTABLE_REASONS
    frame_fields = ()  # the core's table marks what frames record (position, density, pressure)
    ghost_fields = ("ghost_position",)
    units = {"position": "m", "velocity": "m/s", "density": "kg/m³", "pressure": "Pa", "ghost_position": "m",
             "kinetic_energy": "J", "density_error": "-", "mean_density": "kg/m³", "die_height": "m",
             "die_speed": "m/s", "n_particles": "count", "n_ghosts": "count", "die_contacts": "count"}

    # scene ---------------------------------------------------------------------------
    def summary(self, result: dict[str, Any]) -> tuple[list[str], dict[str, Any]]:
        """The answer first ("8-ball says: ... (face N)"), then anything else it reports."""
        lines = []
        if "answer" in result:
            face = result.get("answer_face")
            lines.append(f"8-ball says: {result['answer']}" + (f" (face {face})" if face is not None else ""))
        return lines, {k: v for k, v in result.items() if k not in ("answer", "answer_face")}

    # building ------------------------------------------------------------------------
    def build(self, scene, target: Target, checkpoint: dict | None = None) -> Build:
        v = scene.values
        n = int(v["fluid.particles"])
        radius = float(v["container.radius"])
        h = float(v["sph.h"])
        if v["sph.scale_h"]:
            h *= (float(v["sph.reference_particles"]) / n) ** (1.0 / 3.0)
        side = float(v["die.side"])
        half = side / 2
        die_mass, die_inertia = die_mass_inertia(float(v["die.density"]), side)
        rest = float(v["fluid.rest_density"])
        seed = int(v["run.seed"])
        rng = np.random.default_rng(seed)
        die_q = _random_quaternion(rng)
        die_pos = np.asarray(v["die.position"], dtype=np.float32)
        margin = float(v["die.contact_margin"]) * h
        mass = particle_mass(rest, radius, side, n)
        params = {
            "n_fluid": n, "h": h, "mass": mass, "rest_density": rest,
            "stiffness": v["fluid.stiffness"], "gamma": v["fluid.gamma"], "viscosity": v["fluid.viscosity"],
            "xsph": v["fluid.xsph"], "density_floor": v["fluid.density_floor"] * rest,
            "radius": radius, "wall_restitution": v["container.restitution"],
            "wall_friction": v["container.friction"], "shell_inertia": v["container.shell_inertia"],
            "spin_damping": v["container.spin_damping"], "gravity": list(v["gravity.g"]),
            "die_half": [half] * 3, "die_mass": die_mass, "die_inertia": [die_inertia] * 3,
            "contact_margin": margin, "contact_stiffness": v["die.contact_stiffness"],
            "contact_drag": v["die.drag"], "die_restitution": v["die.restitution"],
            "die_linear_damping": v["die.linear_damping"], "die_angular_damping": v["die.angular_damping"],
            "dt_min": v["timestep.dt_min"], "dt_max": v["timestep.dt_max"],
            "cfl_advective": v["timestep.cfl_advective"], "cfl_acoustic": v["timestep.cfl_acoustic"],
            "cfl_force": v["timestep.cfl_force"], "cfl_viscous": v["timestep.cfl_viscous"],
            "shakes": [dict(start=s["start"], end=s["end"], acceleration=list(s["acceleration"]),
                            torque=list(s["torque"])) for s in scene.shakes],
        }
        # neighbour lists reach h (1 + skin) and stand while no pair can have closed in by the
        # skin: the core relists a scene once its largest fluid displacement a and ghost
        # displacement b since the last rebuild reach a + max(a, b) > skin h (moved_too_far in
        # scenes/magic8ball/stages.h); skin 0: every step (grid and allpairs search every
        # step: no skin)
        skin = float(v["sph.skin"]) if target.index == "lists" else 0.0
        list_radius = h * (1.0 + skin)
        params["list_radius"] = list_radius
        params["skin_distance"] = list_radius - h
        params["lanes"] = int(v["sph.lanes"])
        params["list_scan"] = {"auto": -1, "cells": 0, "scan": 1}[v["sph.list_build"]]
        from ..batch import core_path  # (batch imports this module)

        params["path"] = core_path(v["sph.path"], target.backend, "sph.path")

        # list capacity: 2.5 times the mean count within the list radius (the fluid compresses
        # a few percent; a list that still overflows stops the run as unstable), in warp widths
        # and never more than every particle and ghost there is
        def capacity(reach):
            mean = 4.0 / 3.0 * math.pi * reach ** 3 * n / fluid_volume(radius, side)
            return min(int(math.ceil((2.5 * mean + 32) / 32.0)), int(math.ceil(2 * n / 32.0))) * 32

        params["max_neighbors"] = capacity(list_radius)
        params["max_near"] = capacity(h)
        params["max_list_bytes"] = float(v["sph.max_list_memory"]) * 1e6
        params["die_initial"] = {"position": die_pos.tolist(), "velocity": [0.0] * 3,
                                 "orientation": die_q.tolist(), "angular_velocity": [0.0] * 3}
        # before the (costly) placement and any allocation
        check_memory(self.name, target, params,
                     key_values(scene, ("fluid.particles", "sph.h", "sph.scale_h", "sph.skin")),
                     f"{params['max_neighbors']} neighbour slots per particle")
        if checkpoint is None:
            self._check_room(scene, h, radius, half, die_pos, die_q, margin, n)
            # fluid fills the sphere outside the die's contact margin
            pos, spacing = core().poisson_disk_sphere(radius, n, die_pos.tolist(), [half] * 3, die_q.tolist(),
                                                      margin, seed)
        else:
            # a resumed run starts from its checkpoint's particles (the simulation restores the rest)
            if "position" not in checkpoint:
                raise ValueError("checkpoint: missing position")
            pos = np.ascontiguousarray(checkpoint["position"], dtype=np.float32)
            spacing = float(checkpoint.get("spacing", 0.0))
            if pos.shape != (n, 3):
                raise ValueError(f"checkpoint: {pos.shape[0] if pos.ndim else 0} particles, the scene has "
                                 f"fluid.particles = {n}")
        vel = np.zeros_like(pos)
        info = {"h": h, "mass": mass, "spacing": float(spacing), "answers": list(v["die.answers"])}
        return Build(params, {"position": np.ascontiguousarray(pos), "velocity": vel}, info)

    @staticmethod
    def _check_room(scene, h: float, radius: float, half: float, center, q, margin: float, n: int) -> None:
        """Fail before placing particles when the container minus the die and its contact
        margin leaves (almost) no room: the share of the sphere that is free, estimated
        from 100,000 fixed-seed samples (one in a thousand is the resolution)."""
        rng = np.random.default_rng(12345)
        p = rng.uniform(-radius, radius, size=(100_000, 3))
        p = p[np.einsum("ij,ij->i", p, p) <= radius * radius] - np.asarray(center, dtype=np.float64)
        d = np.abs(p @ _rotation(q)) - half  # body frame (the rotation maps body to container)
        sdf = np.linalg.norm(np.maximum(d, 0.0), axis=1) + np.minimum(d.max(axis=1), 0.0)
        free = float(np.mean(sdf >= margin)) if len(p) else 0.0
        if free < 0.01:
            v = scene.values
            raise ValueError(f"die.contact_margin={v['die.contact_margin']} h with sph.h={h:.4g} m keeps fluid "
                             f"{margin:.3g} m from the die (side {2 * half:.3g} m): that leaves "
                             f"{100 * free:.1f}% of the container (radius {radius:g} m) for {n} particles")

    # reading -------------------------------------------------------------------------
    def state(self, sim, s: dict[str, Any]) -> dict[str, Any]:
        return {
            "time": s["time"], "end_time": s["end_time"], "step": s["step"], "dt": s["dt"],
            "n_ghost": s["n_ghost"], "rebuilds": s["rebuilds"], "done": bool(s["done"]), "bad": s["bad"],
            "bad_step": s["bad_step"],
            "die": {"position": s["die_position"], "velocity": s["die_velocity"],
                    "orientation": s["die_orientation"],
                    "angular_velocity": [s["die_angular_velocity_x"], s["die_angular_velocity_y"],
                                         s["die_angular_velocity_z"]]},
            "shell_orientation": s["shell_orientation"], "shell_angular_velocity": s["shell_angular_velocity"],
            "vmax": s["vmax"], "amax": s["amax"], "density_error": s["sums_rho_err"],
            "mean_density": s["mean_density"], "kinetic_energy": s["sums_ke"], "die_force": s["sums_force"],
            "die_torque": s["sums_torque"], "die_contacts": s["sums_contacts"],
            "answer_face": int(s["answer_face"]), "chosen_dt": s["chosen_dt"],
        }

    def rigid_poses(self, sim, s: dict[str, Any]) -> dict[str, dict[str, np.ndarray]]:
        die = self.state(sim, s)["die"]
        return {"die": {k: np.asarray(x, dtype=np.float32) for k, x in die.items()}}

    def diagnostics(self, sim, s: dict[str, Any]) -> dict[str, float]:
        st = self.state(sim, s)
        die = st["die"]
        return {
            "kinetic_energy": st["kinetic_energy"], "density_error": st["density_error"],
            "mean_density": st["mean_density"], "die_height": die["position"][2],
            "die_speed": float(np.linalg.norm(die["velocity"])), "n_particles": float(sim.n_particles),
            "n_ghosts": float(st["n_ghost"]), "die_contacts": float(st["die_contacts"]),
        }

    def result(self, sim, s: dict[str, Any]) -> dict[str, Any]:
        """The face toward the window (+z) and its answer."""
        st = self.state(sim, s)
        face = int(st["answer_face"])
        return {"answer_face": face, "answer": sim.answers[face - 1],
                "die_position": list(st["die"]["position"]), "die_orientation": list(st["die"]["orientation"])}

    def header(self, sim) -> dict[str, Any]:
        r = float(sim.params["radius"])
        half = sim.params["die_half"]
        return {
            "container": {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": r},
            "obstacles": [],
            "bodies": [{"name": "die", "shape": "box", "half_extents": list(half),
                        "faces": {str(k): list(x) for k, x in DIE_FACES.items()},
                        "answers": sim.answers}],
            "particles": sim.n_particles, "h": sim.h, "particle_radius": sim.spacing / 2,
            "mass": sim.mass, "window": [0.0, 0.0, 1.0], "gravity": list(sim.params["gravity"]),
            "units": dict(self.units),
        }

    # changing the state --------------------------------------------------------------
    def control(self, sim, acceleration=(0.0, 0.0, 0.0), torque=(0.0, 0.0, 0.0)) -> dict[str, list[float]]:
        """Container linear acceleration (m/s²) and shell torque (N·m) for the next steps,
        added to the scene's shake schedule; every backend applies it identically."""
        return {"acceleration": bounded_control("acceleration", acceleration),
                "torque": bounded_control("torque", torque)}

    def check_positions(self, sim, positions: np.ndarray) -> None:
        """Every position inside the container."""
        pos = positions.astype(np.float64)
        r = np.sqrt(np.einsum("ij,ij->i", pos, pos))
        radius = float(sim.params["radius"])
        outside = np.flatnonzero(r > radius * (1 + 1e-6))
        if outside.size:
            i = int(outside[0])
            raise ValueError(f"positions[{i}] = {positions[i].tolist()} is outside the container (radius {radius} m, "
                             f"{outside.size} particles outside)")

    def set_die(self, sim, position=None, orientation=None, velocity=None, angular_velocity=None) -> None:
        """Set the die's pose (orientation as w, x, y, z) and velocities (container frame)."""
        die = sim.state()["die"]
        for key, val in (("position", position), ("orientation", orientation), ("velocity", velocity),
                         ("angular_velocity", angular_velocity)):
            if val is not None:
                die[key] = finite_vector(key, val, 4 if key == "orientation" else 3)
        if np.linalg.norm(die["orientation"]) < 1e-6:
            raise ValueError(f"orientation must be a non-zero quaternion, got {die['orientation']}")
        q = np.asarray(die["orientation"], dtype=np.float64)
        q = q / np.linalg.norm(q)
        sim.core.set_scalar("die_position", list(die["position"]))
        sim.core.set_scalar("die_velocity", list(die["velocity"]))
        sim.core.set_scalar("die_orientation", q.tolist())
        sim.core.set_scalar("die_angular_velocity_body", _rotate_inv(q, die["angular_velocity"]))


KIND = Magic8Ball()
