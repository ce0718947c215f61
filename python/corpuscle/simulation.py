"""`corpuscle.Simulation`: a scene on one backend, stepped from Python.

The compiled core holds the whole state (on the GPU for the CUDA backend); this module turns a
validated scene into the core's parameters and initial state, and reads results back.
"""
from __future__ import annotations

import math
import numbers
import time as _time
from typing import Any

import numpy as np

__all__ = ["Simulation", "BackendError", "UnstableRunError", "MemoryNeedError", "BACKENDS"]

BACKENDS = ("auto", "serial", "cpu", "cuda")

# die faces: number -> outward normal in the body frame (opposite faces sum to 7)
DIE_FACES = {1: (1, 0, 0), 6: (-1, 0, 0), 2: (0, 1, 0), 5: (0, -1, 0), 3: (0, 0, 1), 4: (0, 0, -1)}


class BackendError(ValueError):
    """A backend was asked for that this build or machine cannot run."""


class UnstableRunError(RuntimeError):
    """The run went unstable (non-finite state); `step` names where."""

    def __init__(self, step: int, message: str):
        super().__init__(message)
        self.step = step


class MemoryNeedError(ValueError):
    """A scene needs more memory than the backend has; the message names the keys."""


# the reasons a run is stopped as unstable, by the core's code (kBad* in magic8ball.h)
UNSTABLE_REASONS = {1: "a particle position or velocity became non-finite (NaN/inf)",
                    2: "the die's state became non-finite (NaN/inf)",
                    3: "a particle moved faster than 100 times the sound speed",
                    4: "a particle had more neighbours than its list holds (the fluid collapsed)"}

# the scalars of a checkpoint (Simulation.checkpoint), as the core names them
CHECKPOINT_ARRAYS = ("position", "velocity", "id")


def _count(name: str, value, minimum: int = 0) -> int:
    """An integer argument (Python or NumPy integer, not bool or float) >= minimum."""
    if isinstance(value, bool) or type(value).__name__ == "bool_" or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    if int(value) < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {int(value)}")
    return int(value)


def _finite_vector(name: str, value, length: int = 3) -> list[float]:
    """`length` finite numbers."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be {length} numbers, got {value!r}") from None
    if arr.shape != (length,):
        raise ValueError(f"{name} must be {length} numbers, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return [float(x) for x in arr]


def _fmt_bytes(b: float) -> str:
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if b >= size:
            return f"{b / size:.3g} {unit}"
    return f"{b / 1e3:.3g} kB"


def _core():
    from . import _core as core  # the compiled extension
    return core


def cuda_status() -> tuple[bool, str]:
    """(usable, reason): whether the CUDA backend can run here, and why not."""
    info = _core().build_info()
    if not info["cuda_compiled"]:
        return False, "this build has no CUDA backend"
    if not info["gpus"]:
        return False, info.get("gpu_error") or "no CUDA device found"
    return True, ""


def resolve_backend(name: str) -> str:
    """Map 'auto' to cuda when a GPU is usable, else cpu; reject unusable choices."""
    if name not in BACKENDS:
        raise BackendError(f"--backend must be one of {', '.join(BACKENDS)}, got {name!r}")
    ok, why = cuda_status()
    if name == "auto":
        return "cuda" if ok else "cpu"
    if name == "cuda" and not ok:
        raise BackendError(f"--backend cuda: no usable GPU ({why})")
    return name


def _random_quaternion(rng: np.random.Generator) -> np.ndarray:
    # uniform on SO(3) (Shoemake 1992)
    u1, u2, u3 = rng.random(3)
    a, b = math.sqrt(1 - u1), math.sqrt(u1)
    return np.array([b * math.cos(2 * math.pi * u3), a * math.sin(2 * math.pi * u2),
                     a * math.cos(2 * math.pi * u2), b * math.sin(2 * math.pi * u3)], dtype=np.float32)


def _rotate_inv(q, v) -> list[float]:
    """v rotated by the inverse of unit quaternion q (w, x, y, z): container to body frame."""
    w, x, y, z = (float(c) for c in q)
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    return (r.T @ np.asarray(v, dtype=np.float64)).tolist()


class _Magic8BallCore:
    """The magic8ball kind over the scene-generic core class: its state as the dict the rest
    of the package reads, its die and particle setters and its control."""

    def __init__(self, core):
        self.core = core

    def __getattr__(self, name):  # step, evaluate, set_end_time, view, download, bench, profile
        return getattr(self.core, name)

    def state(self) -> dict:
        s = self.core.scalars()
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

    def set_control(self, acceleration, torque) -> None:
        self.core.set_control({"acceleration": list(acceleration), "torque": list(torque)})

    def set_die(self, die: dict) -> None:
        q = np.asarray(die["orientation"], dtype=np.float64)
        q = q / np.linalg.norm(q)
        self.core.set_scalar("die_position", list(die["position"]))
        self.core.set_scalar("die_velocity", list(die["velocity"]))
        self.core.set_scalar("die_orientation", q.tolist())
        self.core.set_scalar("die_angular_velocity_body", _rotate_inv(q, die["angular_velocity"]))

    def set_particles(self, pos, vel) -> None:
        self.core.upload("position", pos)  # ids restart at 0..n-1
        self.core.upload("velocity", vel)


class Simulation:
    """A scene running on one backend.

    Build with :meth:`from_scene`; advance with :meth:`step` or :meth:`run`; read particle
    arrays with :meth:`field` (zero-copy: NumPy on the CPU, DLPack on CUDA) and rigid poses
    with :meth:`rigid_poses`; push shaking input with :meth:`set_control`.
    """

    def __init__(self, scene, backend: str = "auto", checkpoint: dict | None = None,
                 neighbors: str | None = None, device: int = 0):
        self.scene = scene
        self.backend = resolve_backend(backend)
        kinds = dict(_core().kinds())
        if scene.kind not in kinds:
            raise BackendError(f"scene kind {scene.kind!r} is not supported by this version")
        self.neighbors = kinds[scene.kind][0] if neighbors is None else str(neighbors)
        if self.neighbors not in kinds[scene.kind]:
            raise ValueError(f"--neighbors must be one of {', '.join(kinds[scene.kind])}, got {self.neighbors!r}")
        self.device = _count("device", device)
        t0 = _time.perf_counter()
        self._build_magic8ball(checkpoint)
        if checkpoint is not None:
            self.restore(checkpoint)
        else:
            # densities, pressures and the dt of the initial state, so that fields and frame 0
            # hold them (the first step sorts exactly as it would have)
            self._sim.evaluate()
        #: seconds spent building the scene (placement, allocation, upload), excluded from steps/s
        self.init_seconds = _time.perf_counter() - t0

    # construction ---------------------------------------------------------------------
    @classmethod
    def from_scene(cls, scene, backend: str = "auto", overrides: dict[str, Any] | None = None,
                   neighbors: str | None = None, device: int = 0, **kwargs) -> "Simulation":
        """Load a scene (built-in name, TOML path or Scene) with overrides and build it.

        Overrides are dotted keys (``{"fluid.stiffness": 2e4}``) or keyword arguments with
        ``__`` for the dot (``fluid__stiffness=2e4``); ``particles``, ``seed`` and
        ``end_time`` are shorthands for ``fluid.particles``, ``run.seed`` and ``run.end_time``.
        ``neighbors`` picks the neighbour search (``lists``, ``grid``, ``allpairs``; the
        kind's first by default), ``device`` the CUDA device.
        """
        from .scene import Scene, load_scene

        aliases = {"particles": "fluid.particles", "seed": "run.seed", "end_time": "run.end_time"}
        ovr = dict(overrides or {})
        for k, v in kwargs.items():
            ovr[aliases.get(k, k.replace("__", "."))] = v
        if isinstance(scene, Scene):
            scene = scene.with_overrides(ovr) if ovr else scene
        else:
            scene = load_scene(scene, ovr)
        return cls(scene, backend, neighbors=neighbors, device=device)

    @staticmethod
    def cuda_available() -> bool:
        """Whether the CUDA backend is compiled and a device is usable."""
        return cuda_status()[0]

    def _build_magic8ball(self, checkpoint: dict | None = None) -> None:
        v = self.scene.values
        n = int(v["fluid.particles"])
        radius = float(v["container.radius"])
        h = float(v["sph.h"])
        if v["sph.scale_h"]:
            h *= (float(v["sph.reference_particles"]) / n) ** (1.0 / 3.0)
        side = float(v["die.side"])
        half = side / 2
        die_mass = float(v["die.density"]) * side ** 3
        rest = float(v["fluid.rest_density"])
        seed = int(v["run.seed"])
        rng = np.random.default_rng(seed)
        die_q = _random_quaternion(rng)
        die_pos = np.asarray(v["die.position"], dtype=np.float32)
        margin = float(v["die.contact_margin"]) * h
        fluid_volume = 4.0 / 3.0 * math.pi * radius ** 3 - side ** 3
        self.h = h
        self.mass = rest * fluid_volume / n
        params = {
            "n_fluid": n, "h": h, "mass": self.mass, "rest_density": rest,
            "stiffness": v["fluid.stiffness"], "gamma": v["fluid.gamma"], "viscosity": v["fluid.viscosity"],
            "xsph": v["fluid.xsph"], "density_floor": v["fluid.density_floor"] * rest,
            "radius": radius, "wall_restitution": v["container.restitution"],
            "wall_friction": v["container.friction"], "shell_inertia": v["container.shell_inertia"],
            "spin_damping": v["container.spin_damping"], "gravity": list(v["gravity.g"]),
            "die_half": [half] * 3, "die_mass": die_mass, "die_inertia": [die_mass * side ** 2 / 6.0] * 3,
            "contact_margin": margin, "contact_stiffness": v["die.contact_stiffness"],
            "contact_drag": v["die.drag"], "die_restitution": v["die.restitution"],
            "die_linear_damping": v["die.linear_damping"], "die_angular_damping": v["die.angular_damping"],
            "dt_min": v["timestep.dt_min"], "dt_max": v["timestep.dt_max"],
            "cfl_advective": v["timestep.cfl_advective"], "cfl_acoustic": v["timestep.cfl_acoustic"],
            "cfl_force": v["timestep.cfl_force"], "cfl_viscous": v["timestep.cfl_viscous"],
            "shakes": [dict(start=s["start"], end=s["end"], acceleration=list(s["acceleration"]),
                            torque=list(s["torque"])) for s in self.scene.shakes],
        }
        # neighbour lists reach h (1 + skin) and stand until a particle has moved skin h / 2
        # (less the stretch of the mirror map, under which a ghost moves up to
        # (2R - r) / r times as far as its particle at r >= R - h (1 + skin)); skin 0: every step
        # (grid and allpairs search every step: no skin)
        skin = float(v["sph.skin"]) if self.neighbors == "lists" else 0.0
        list_radius = h * (1.0 + skin)
        r_min = max(radius - list_radius, 0.25 * radius)
        stretch = (2.0 * radius - r_min) / r_min
        params["list_radius"] = list_radius
        params["rebuild_distance"] = skin * h / (1.0 + stretch)
        # list capacity: 2.5 times the mean count within the list radius (the fluid compresses
        # a few percent; a list that still overflows stops the run as unstable), in warp widths
        # and never more than every particle and ghost there is
        def capacity(reach):
            mean = 4.0 / 3.0 * math.pi * reach ** 3 * n / fluid_volume
            return min(int(math.ceil((2.5 * mean + 32) / 32.0)), int(math.ceil(2 * n / 32.0))) * 32

        params["max_neighbors"] = capacity(list_radius)
        params["max_near"] = capacity(h)
        self.params = params
        params["die_initial"] = {"position": die_pos.tolist(), "velocity": [0.0] * 3,
                                 "orientation": die_q.tolist(), "angular_velocity": [0.0] * 3}
        self._check_memory(params)  # before the (costly) placement and any allocation
        if checkpoint is None:
            self._check_room(radius, half, die_pos, die_q, margin, n)
        if checkpoint is None:
            # fluid fills the sphere outside the die's contact margin
            pos, spacing = _core().poisson_disk_sphere(radius, n, die_pos.tolist(), [half] * 3, die_q.tolist(),
                                                       margin, seed)
        else:
            # a resumed run starts from its checkpoint's particles (restored below)
            pos = np.ascontiguousarray(checkpoint["position"], dtype=np.float32)
            spacing = float(checkpoint.get("spacing", 0.0))
            if pos.shape != (n, 3):
                raise ValueError(f"checkpoint: {pos.shape[0] if pos.ndim else 0} particles, the scene has "
                                 f"fluid.particles = {n}")
        self.spacing = float(spacing)
        vel = np.zeros_like(pos)
        core = _core().Simulation("magic8ball", self.backend, self.neighbors, params,
                                  {"position": np.ascontiguousarray(pos), "velocity": vel}, self.device)
        self._sim = _Magic8BallCore(core)
        self.end_time = float(v["run.end_time"])
        self.answers = list(v["die.answers"])

    def _check_room(self, radius: float, half: float, center, q, margin: float, n: int) -> None:
        """Fail before placing particles when the container minus the die and its contact
        margin leaves (almost) no room: the share of the sphere that is free, estimated
        from 100,000 fixed-seed samples (one in a thousand is the resolution)."""
        rng = np.random.default_rng(12345)
        p = rng.uniform(-radius, radius, size=(100_000, 3))
        p = p[np.einsum("ij,ij->i", p, p) <= radius * radius] - np.asarray(center, dtype=np.float64)
        w, x, y, z = (float(c) for c in q)
        rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        d = np.abs(p @ rot) - half  # body frame (rot maps body to container)
        sdf = np.linalg.norm(np.maximum(d, 0.0), axis=1) + np.minimum(d.max(axis=1), 0.0)
        free = float(np.mean(sdf >= margin)) if len(p) else 0.0
        if free < 0.01:
            v = self.scene.values
            raise ValueError(f"die.contact_margin={v['die.contact_margin']} h with sph.h={self.h:.4g} m keeps fluid "
                             f"{margin:.3g} m from the die (side {2 * half:.3g} m): that leaves "
                             f"{100 * free:.1f}% of the container (radius {radius:g} m) for {n} particles")

    def _check_memory(self, params: dict) -> None:
        """Fail before allocating when the scene needs more memory than the backend has."""
        need = float(_core().bytes_needed("magic8ball", self.neighbors, params))
        have = float(_core().bytes_available(self.backend, self.device))
        if have > 0 and need > have:
            v = self.scene.values
            keys = ", ".join(f"{k}={v[k]!r}".replace("True", "true").replace("False", "false")
                             for k in ("fluid.particles", "sph.h", "sph.scale_h", "sph.skin"))
            where = "GPU memory free" if self.backend == "cuda" else "host memory available"
            raise MemoryNeedError(f"{keys} need {_fmt_bytes(need)} ({params['max_neighbors']} neighbour "
                                  f"slots per particle), more than the {_fmt_bytes(have)} of {where}")

    # stepping -------------------------------------------------------------------------
    def step(self, n: int = 1) -> int:
        """Advance up to n steps; returns how many were taken. Once the end time (set by
        :meth:`run` or :meth:`set_end_time`) is reached, or the run went unstable, steps are
        no-ops that cost (almost) nothing and are not counted. Ctrl-C stops it after a whole
        step (KeyboardInterrupt)."""
        n = _count("steps", n)
        return int(self._sim.step(n))

    def run(self, until: float | None = None, steps: int | None = None, chunk: int = 100,
            callback=None) -> None:
        """Run to simulated time `until` (exactly: the last dt is shortened) or for `steps` steps.

        `callback(sim)` is called after every `chunk` steps; it may return True to stop.
        """
        if until is not None:
            until = float(until)
            if not math.isfinite(until):
                raise ValueError(f"until must be a finite time, got {until!r}")
            self._sim.set_end_time(until)
        budget = _count("steps", steps) if steps is not None else (None if until is not None else 0)
        chunk = _count("chunk", chunk, minimum=1)
        while True:
            k = chunk if budget is None else min(chunk, budget)
            if k <= 0:
                break
            taken = self.step(k)
            if budget is not None:
                budget -= k
            st = self._sim.state()
            if st["bad"]:
                raise UnstableRunError(st["bad_step"], self.check_health() or "unstable")
            if callback is not None and callback(self):
                break
            if st["done"] or taken < k:
                break

    def set_end_time(self, t: float) -> None:
        """Steps that would pass simulated time t are shortened, then become no-ops
        (t = inf: no end)."""
        if not isinstance(t, numbers.Real) or isinstance(t, bool) or math.isnan(t):
            raise ValueError(f"end time must be a number of seconds, got {t!r}")
        self._sim.set_end_time(float(t))

    def set_control(self, acceleration=(0.0, 0.0, 0.0), torque=(0.0, 0.0, 0.0)) -> None:
        """Container linear acceleration (m/s²) and shell torque (N·m) for the next steps,
        added to the scene's shake schedule; every backend applies it identically."""
        self._sim.set_control(_finite_vector("acceleration", acceleration), _finite_vector("torque", torque))

    def evaluate(self) -> dict:
        """Compute densities, pressures, accelerations and this state's reductions without
        advancing; returns :meth:`state` (its ``chosen_dt`` is the dt a step would take)."""
        self._sim.evaluate()
        return self._sim.state()

    def set_particles(self, positions, velocities=None) -> None:
        """Replace the fluid state ((n, 3) arrays, n = n_particles, finite, positions inside
        the container); ids restart at 0..n-1."""
        n = self.n_particles
        pos = self._particle_array("positions", positions, n)
        vel = np.zeros_like(pos) if velocities is None else self._particle_array("velocities", velocities, n)
        r = np.sqrt(np.einsum("ij,ij->i", pos.astype(np.float64), pos.astype(np.float64)))
        radius = float(self.params["radius"])
        outside = np.flatnonzero(r > radius * (1 + 1e-6))
        if outside.size:
            i = int(outside[0])
            raise ValueError(f"positions[{i}] = {pos[i].tolist()} is outside the container (radius {radius} m, "
                             f"{outside.size} particles outside)")
        self._sim.set_particles(pos, vel)

    @staticmethod
    def _particle_array(name: str, value, n: int) -> np.ndarray:
        try:
            arr = np.asarray(value)
        except (TypeError, ValueError):
            raise TypeError(f"{name} must be an ({n}, 3) array of numbers") from None
        if arr.dtype.kind not in "iuf" or arr.shape != (n, 3):
            raise ValueError(f"{name} must be an ({n}, 3) array of numbers, got shape {arr.shape} "
                             f"dtype {arr.dtype}")
        bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
        if bad.size:
            i = int(bad[0])
            raise ValueError(f"{name}[{i}] = {arr[i].tolist()} is not finite ({bad.size} rows are not)")
        return np.ascontiguousarray(arr, dtype=np.float32)

    def set_die(self, position=None, orientation=None, velocity=None, angular_velocity=None) -> None:
        """Set the die's pose (orientation as w, x, y, z) and velocities (container frame)."""
        die = self._sim.state()["die"]
        for key, val in (("position", position), ("orientation", orientation), ("velocity", velocity),
                         ("angular_velocity", angular_velocity)):
            if val is not None:
                die[key] = _finite_vector(key, val, 4 if key == "orientation" else 3)
        if np.linalg.norm(die["orientation"]) < 1e-6:
            raise ValueError(f"orientation must be a non-zero quaternion, got {die['orientation']}")
        self._sim.set_die(die)

    # checkpoints ----------------------------------------------------------------------
    def checkpoint(self) -> dict:
        """The whole state the next step reads: ``position``, ``velocity``, ``id`` (fluid
        arrays in their current order) and the scalars (time, step, die and shell state,
        control, ...). Restoring it with :meth:`restore` (on this or a new simulation of the
        same scene) continues bit-identically on the CPU backends: the step after a
        checkpoint sorts and relists, as the first step after a restore does. The scene
        draws no random numbers after its start, so there is no generator state to keep."""
        c = dict(self._sim.core.checkpoint())
        c["spacing"] = self.spacing
        return c

    def restore(self, state: dict) -> None:
        """Replace the whole state by one :meth:`checkpoint` returned (the end time stays)."""
        missing = [k for k in CHECKPOINT_ARRAYS if k not in state]
        if missing:
            raise ValueError(f"checkpoint: missing {', '.join(missing)}")
        n = self.n_particles
        pos = self._particle_array("checkpoint position", state["position"], n)
        vel = self._particle_array("checkpoint velocity", state["velocity"], n)
        ids = np.ascontiguousarray(state["id"]).reshape(-1)
        if ids.shape != (n,) or ids.dtype.kind not in "iu" or np.any(np.sort(ids) != np.arange(n)):
            raise ValueError(f"checkpoint id must be a permutation of 0..{n - 1}")
        full = {k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in state.items()
                if k not in CHECKPOINT_ARRAYS and k != "spacing"}
        full.update(position=pos, velocity=vel, id=np.ascontiguousarray(ids, dtype=np.int32))
        self._sim.core.restore(full)

    # state ----------------------------------------------------------------------------
    def state(self) -> dict:
        """Scalars of the current state (time, dt, die pose, last step's reductions)."""
        return self._sim.state()

    @property
    def time(self) -> float:
        """Simulated time (s)."""
        return self._sim.state()["time"]

    @property
    def dt(self) -> float:
        """The last step's dt (s)."""
        return self._sim.state()["dt"]

    @property
    def steps(self) -> int:
        """Steps taken."""
        return self._sim.state()["step"]

    @property
    def n_particles(self) -> int:
        """Fluid particles placed."""
        return self._sim.core.n_particles

    @property
    def n_ghosts(self) -> int:
        """Ghost particles of the last step."""
        return self._sim.state()["n_ghost"]

    def field(self, name: str, copy: bool = False):
        """A particle field: position, velocity, density, pressure, id, acceleration,
        ghost_position, ghost_velocity. Without copy: a zero-copy view (NumPy on the CPU; on
        CUDA an array exposing ``__dlpack__`` for CuPy/PyTorch), valid until the next step.
        Particles are reordered every step; ``id`` gives each one's persistent index."""
        return self._sim.download(name) if copy else self._sim.view(name)

    @property
    def positions(self):
        return self.field("position")

    @property
    def velocities(self):
        return self.field("velocity")

    @property
    def density(self):
        return self.field("density")

    @property
    def pressure(self):
        return self.field("pressure")

    def rigid_poses(self) -> dict[str, dict[str, np.ndarray]]:
        """Rigid bodies: name -> position, orientation (w, x, y, z), velocity, angular_velocity."""
        die = self._sim.state()["die"]
        return {"die": {k: np.asarray(v, dtype=np.float32) for k, v in die.items()}}

    def diagnostics(self) -> dict[str, float]:
        """Scalars recorded with every frame."""
        st = self._sim.state()
        die = st["die"]
        return {
            "kinetic_energy": st["kinetic_energy"], "density_error": st["density_error"],
            "mean_density": st["mean_density"], "die_height": die["position"][2],
            "die_speed": float(np.linalg.norm(die["velocity"])), "n_particles": float(self.n_particles),
            "n_ghosts": float(st["n_ghost"]), "die_contacts": float(st["die_contacts"]),
        }

    def frame(self, ghosts: bool = False, velocity: bool = False) -> dict:
        """Keyword arguments for `FrameWriter.write_frame` (host copies of the fields)."""
        fields = {"position": self._sim.download("position"), "density": self._sim.download("density"),
                  "pressure": self._sim.download("pressure")}
        groups = {k: "fluid" for k in fields}
        if velocity:
            fields["velocity"] = self._sim.download("velocity")
            groups["velocity"] = "fluid"
        if ghosts:
            fields["ghost_position"] = self._sim.download("ghost_position")
            groups["ghost_position"] = "ghost"
        rigid = {name: {"position": p["position"], "orientation": p["orientation"]}
                 for name, p in self.rigid_poses().items()}
        return {"fields": fields, "groups": groups, "rigid": rigid, "diagnostics": self.diagnostics()}

    def header(self) -> dict:
        """The run header recorded at the start of a frame stream."""
        from . import __version__
        r = float(self.params["radius"])
        half = self.params["die_half"]
        return {
            "scene": self.scene.name, "kind": self.scene.kind, "dim": 3, "backend": self.backend,
            "corpuscle_version": __version__, "parameters": self.scene.to_dict(),
            "container": {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": r},
            "bodies": [{"name": "die", "shape": "box", "half_extents": list(half),
                        "faces": {str(k): list(v) for k, v in DIE_FACES.items()},
                        "answers": self.answers}],
            "particles": self.n_particles, "h": self.h, "particle_radius": self.spacing / 2,
            "mass": self.mass, "window": [0.0, 0.0, 1.0],
        }

    def result(self) -> dict:
        """The scene's result: for magic8ball the face toward the window (+z) and its answer."""
        st = self._sim.state()
        face = int(st["answer_face"])
        return {"answer_face": face, "answer": self.answers[face - 1],
                "die_position": list(st["die"]["position"]), "die_orientation": list(st["die"]["orientation"])}

    def check_health(self) -> str | None:
        """None while the run is sound, else a message naming the step where it went bad."""
        st = self._sim.state()
        if st["bad"]:
            return f"unstable at step {st['bad_step']}: {UNSTABLE_REASONS.get(st['bad'], 'unsound state')}"
        return None

    # measurement ----------------------------------------------------------------------
    def bench_steps(self, n: int) -> float:
        """Seconds for n steps, timed by the core (CUDA events on the GPU), init excluded."""
        self._sim.set_end_time(math.inf)
        return float(self._sim.bench(_count("steps", n, minimum=1)))

    def stage_times(self, n: int) -> dict[str, float]:
        """Milliseconds per step of each pipeline stage, averaged over n steps."""
        self._sim.set_end_time(math.inf)
        return dict(self._sim.profile(_count("steps", n, minimum=1)))
