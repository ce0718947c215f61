"""`corpuscle.Simulation`: a scene on one backend, stepped from Python.

The compiled core holds the whole state (on the GPU for the CUDA backend). This class is
the same for every scene kind: what is particular to a kind (how a scene becomes the
core's parameters and initial state, what its state, diagnostics, result, run header and
frames hold, its setters) comes from the kind's module in :mod:`corpuscle.kinds`.

Kind-specific methods: a kind may offer methods of its own (``Kind.methods``), which the
simulation exposes as its attributes: ``sim.set_die(...)`` (the 8-ball's) calls
``kind.set_die(sim, ...)``. Likewise the values the kind derives when it builds the scene
(``Build.info``: ``sim.h``, ``sim.mass``, ``sim.spacing``, ...) read as attributes.

The core's scalars (``_core.Simulation.scalars()``) are read once per state: ``time``,
``dt``, ``steps``, ``state()``, ``check_health()``, ``diagnostics()`` ... after a step share
one snapshot, which every call that changes the state (step, evaluate, set_*, restore,
upload, bench) drops.
"""
from __future__ import annotations

import math
import numbers
import time as _time
from typing import Any, Mapping

import numpy as np

from . import kinds as _kinds
from ._errors import BackendError, MemoryNeedError, UnstableRunError
from .kinds import Target, count as _count, finite_vector as _finite_vector, fmt_bytes as _fmt_bytes  # noqa: F401
from .kinds import particle_array as _particle_array

__all__ = ["Simulation", "BackendError", "UnstableRunError", "MemoryNeedError", "BACKENDS"]

BACKENDS = ("auto", "serial", "cpu", "cuda")


def __getattr__(name):
    # the 8-ball's tables, where they were before the kinds had modules of their own
    if name in ("UNSTABLE_REASONS", "DIE_FACES"):
        from .kinds import magic8ball
        return getattr(magic8ball, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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


class CoreHandle:
    """The compiled ``_core.Simulation`` with a snapshot of its scalars.

    ``scalars()`` reads the core once per state and hands out copies; the methods that
    change the state (:data:`MUTATING`) drop the snapshot. Everything else passes through.
    """

    MUTATING = frozenset({"step", "evaluate", "set_end_time", "set_scalar", "set_control", "upload", "unpack",
                          "restore", "bench", "profile"})

    def __init__(self, raw):
        self.raw = raw
        self._snapshot: dict[str, Any] | None = None

    def snapshot(self) -> dict[str, Any]:
        """The cached scalars (not a copy: read, never change it)."""
        if self._snapshot is None:
            self._snapshot = dict(self.raw.scalars())
        return self._snapshot

    def scalars(self) -> dict[str, Any]:
        """A copy of the scalars (lists copied too)."""
        return {k: list(v) if isinstance(v, list) else v for k, v in self.snapshot().items()}

    def invalidate(self) -> None:
        self._snapshot = None

    def __getattr__(self, name):
        attr = getattr(self.raw, name)
        if name not in CoreHandle.MUTATING:
            return attr

        def mutating(*args, **kwargs):
            self._snapshot = None
            try:
                return attr(*args, **kwargs)
            finally:
                self._snapshot = None  # also when interrupted part way (Ctrl-C after some steps)

        return mutating


def _check_state(state) -> None:
    """A checkpoint is the mapping Simulation.checkpoint() returns."""
    if not isinstance(state, Mapping):
        raise TypeError(f"checkpoint must be the dict Simulation.checkpoint() returns, got {state!r}")



# the scalars a state's clock reads: a time in seconds and a step count start at 0
_NOT_NEGATIVE = ("time", "dt")


def _scalar_numbers(label: str, value, count: int) -> list:
    """``count`` numbers (one, or a list of them) of a restored state's scalar."""
    vals = list(value) if isinstance(value, (list, tuple, np.ndarray)) else [value]
    if len(vals) != count or any(isinstance(x, (bool, np.bool_)) or not isinstance(x, numbers.Real) for x in vals):
        what = "a number" if count == 1 else f"{count} numbers"
        raise ValueError(f"{label} must be {what}, got {value!r}")
    return vals


def _check_restored_scalar(label: str, name: str, value, dtype: np.dtype, count: int) -> None:
    """One scalar of a restored state, checked as the API checks its arguments: a float
    finite (and within float32 where the core keeps float32; a time or dt not negative), an
    integer whole and within the core's type, not negative (a step, a count, an index)."""
    vals = _scalar_numbers(label, value, count)
    if dtype.kind == "f":
        top = float(np.finfo(dtype).max)
        for x in vals:
            if not (math.isfinite(float(x)) and abs(float(x)) <= top):
                raise ValueError(f"{label} = {value!r} must be finite" + (" (float32)" if dtype.itemsize == 4 else ""))
            if name in _NOT_NEGATIVE and float(x) < 0:
                raise ValueError(f"{label} = {value!r} must not be negative")
    else:
        top = int(np.iinfo(dtype).max)
        for x in vals:
            if isinstance(x, float) and not x.is_integer() or not 0 <= x <= top:
                raise ValueError(f"{label} = {value!r} must be a whole number in [0, {top}]")


def _check_restored_scalars(sim, state: Mapping) -> None:
    """Every scalar of a checkpoint ``sim`` is about to take (the core's record values, the
    control input and the kind's extras) before any of it is restored."""
    fields = {f["name"] for f in sim._fields}
    for name in sim.kind.checkpoint_extra:
        if name in state:
            _check_restored_scalar(f"checkpoint {name}", name, state[name], np.dtype(np.float64), 1)
    controls = {}
    for key, value in state.items():
        if key in fields or key in sim.kind.checkpoint_extra or not isinstance(key, str):
            continue
        if key.startswith("control_") and key[len("control_"):] in sim._control:
            controls[key[len("control_"):]] = value
            continue
        try:
            ref = np.asarray(sim.core.scalar_of_scenes(key))  # (1,) or (1, count): the record's dtype
        except KeyError:
            continue  # not a scalar of this kind's record: the core does not read it
        _check_restored_scalar(f"checkpoint {key}", key, value, ref.dtype, int(ref.size))
    if controls:
        try:  # the control input as set_control takes it (its bounds included)
            sim.kind.control(sim, **{k: _scalar_numbers(f"checkpoint control_{k}", v, len(sim._control[k]))
                                     for k, v in controls.items()})
        except (TypeError, ValueError) as e:
            raise ValueError(f"checkpoint control: {e}") from None


def _bad_step(s: dict) -> int:
    """The step a snapshot went bad at; a flag raised outside a step (by ``evaluate``, which
    runs no finalize to note the step) is the current one."""
    return int(s["bad_step"]) if int(s["bad_step"]) >= 0 else int(s["step"])

class Simulation:
    """A scene running on one backend.

    Build with :meth:`from_scene`; advance with :meth:`step` or :meth:`run`; read particle
    arrays with :meth:`field` (zero-copy: NumPy on the CPU, DLPack on CUDA) and rigid poses
    with :meth:`rigid_poses`; push control input (the 8-ball's shaking) with
    :meth:`set_control`. ``kind`` is the scene's :class:`corpuscle.kinds.Kind`; its own
    methods (``set_die`` for the 8-ball) and derived values (``h``, ``mass``, ...) are
    attributes too. ``core`` is the compiled simulation (a :class:`CoreHandle`).
    """

    def __init__(self, scene, backend: str = "auto", checkpoint: dict | None = None,
                 neighbors: str | None = None, device: int = 0):
        if checkpoint is not None:
            _check_state(checkpoint)
        self.scene = scene
        self.backend = resolve_backend(backend)
        kinds = dict(_core().kinds(hidden=True))  # (and those built for tests, whose kind a test registers)
        kind = _kinds.find(scene.kind)
        if scene.kind not in kinds or kind is None:
            raise BackendError(f"scene kind {scene.kind!r} is not supported by this version")
        #: the scene's kind (corpuscle.kinds.Kind)
        self.kind = kind
        self.neighbors = kinds[scene.kind][0] if neighbors is None else str(neighbors)
        if self.neighbors not in kinds[scene.kind]:
            raise ValueError(f"--neighbors must be one of {', '.join(kinds[scene.kind])} (the indexes of {scene.kind}), "
                             f"got {self.neighbors!r}")
        self.device = _count("device", device)
        if self.device and self.backend != "cuda":
            raise ValueError(f"--device {self.device}: selects a CUDA device; the {self.backend} backend has none "
                             "(leave --device out, or use --backend cuda)")
        t0 = _time.perf_counter()
        built = kind.build(scene, Target(self.backend, self.neighbors, self.device), checkpoint)
        #: the core's parameters (as the kind built them)
        self.params = built.params
        #: the kind's derived values (also attributes: sim.h, ...)
        self.info = dict(built.info)
        self.end_time = float(scene.values["run.end_time"])
        self.core = CoreHandle(_core().Simulation(kind.name, self.backend, self.neighbors, built.params,
                                                  built.arrays, self.device))
        self._fields = [dict(f) for f in self.core.fields()]
        self._control = {str(k): [0.0] * int(v) for k, v in dict(self.core.controls()).items()}
        if checkpoint is not None:
            self.restore(checkpoint)
        else:
            # densities, pressures and the dt of the initial state, so that fields and frame 0
            # hold them (the first step sorts exactly as it would have)
            self.core.evaluate()
        #: seconds spent building the scene (placement, allocation, upload), excluded from steps/s
        self.init_seconds = _time.perf_counter() - t0

    def __getattr__(self, name):
        # only reached when normal lookup fails: the kind's methods, then its derived values
        d = self.__dict__
        kind = d.get("kind")
        if kind is not None and name in kind.methods:
            return _kinds.kind_method(kind, name, self)
        info = d.get("info")
        if info is not None and name in info:
            return info[name]
        what = f"of kind {kind.name!r} " if kind is not None else ""
        raise AttributeError(f"Simulation {what}has no attribute {name!r}")

    def __dir__(self):
        extra = list(self.kind.methods) + list(self.info) if "kind" in self.__dict__ else []
        return sorted(set(super().__dir__()) | set(extra))

    # construction ---------------------------------------------------------------------
    @classmethod
    def from_scene(cls, scene, backend: str = "auto", overrides: dict[str, Any] | None = None,
                   neighbors: str | None = None, device: int = 0, comm=None, **kwargs) -> "Simulation":
        """Load a scene (built-in name, TOML path or Scene) with overrides and build it.

        Overrides are dotted keys (``{"fluid.stiffness": 2e4}``) or keyword arguments with
        ``__`` for the dot (``fluid__stiffness=2e4``); ``particles``, ``seed`` and
        ``end_time`` are shorthands for the kind's particle key (``fluid.particles`` for the
        8-ball), ``run.seed`` and ``run.end_time``. ``neighbors`` picks the neighbour search
        (``lists``, ``grid``, ``allpairs``; the kind's first by default), ``device`` the CUDA
        device. ``comm`` (an mpi4py communicator): the ranks the scene is split over (the SPH
        box kinds, docs/distributed.md; collective: every rank calls it alike); one rank runs it
        as without.
        """
        from .scene import Scene, load_scene


        if not isinstance(scene, Scene):
            scene = load_scene(scene)
        kind = _kinds.find(scene.kind)
        particle_key = kind.particle_key if kind is not None else None
        aliases = {"seed": "run.seed", "end_time": "run.end_time"}
        if overrides is not None and not isinstance(overrides, Mapping):
            raise TypeError(f"overrides must be a mapping of dotted keys to values, got {overrides!r}")
        ovr = dict(overrides or {})
        for k, v in kwargs.items():
            if k == "particles":
                if particle_key is None:
                    raise ValueError(f"particles: scene kind {scene.kind!r} has no particle count")
                ovr[particle_key] = v
            else:
                ovr[aliases.get(k, k.replace("__", "."))] = v
        scene = scene.with_overrides(ovr) if ovr else scene
        if comm is not None and comm.Get_size() > 1:
            from ._ranks_sph import ranked_simulation
            return ranked_simulation(scene, backend, comm, neighbors=neighbors, device=device or None)
        return cls(scene, backend, neighbors=neighbors, device=device)

    @staticmethod
    def cuda_available() -> bool:
        """Whether the CUDA backend is compiled and a device is usable."""
        return cuda_status()[0]

    # stepping -------------------------------------------------------------------------
    def step(self, n: int = 1) -> int:
        """Advance up to n steps; returns how many were taken. Once the end time (set by
        :meth:`run` or :meth:`set_end_time`) is reached, or the run went unstable, steps are
        no-ops that cost (almost) nothing and are not counted. Ctrl-C stops it after a whole
        step (KeyboardInterrupt)."""
        n = _count("steps", n)
        # a kind whose core keeps series in fixed-capacity rings (the SPH box's probes) has
        # them drained at least every `cap` steps: one read of the record per call, never per step
        every = getattr(self.kind, "steps_between_drains", None)
        cap = every(self) if every is not None else None
        if not cap:
            return int(self.core.step(n))
        taken = 0
        while taken < n:
            k = min(cap, n - taken)
            t = int(self.core.step(k))
            self.kind.drain(self)
            taken += t
            if t < k:
                break
        return taken

    def probe_series(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """A probe's series (the SPH box kinds' [[probes]]): times (s) and pressures (Pa) of
        every sample it took (its `interval`; every step by default) of the states the steps
        started from; a gauge's (shape = "gauge"): times and water levels (m above its lower end)."""
        if not hasattr(self.kind, "probe_series"):
            raise ValueError(f"{self.kind.name} has no probes")
        return self.kind.probe_series(self, name)

    def probe_impulse(self, name: str, t0: float, t1: float) -> float:
        """The pressure impulse of a probe over [t0, t1] (Pa s): the trapezoid rule over its
        series, interpolated at the window's ends."""
        from .kinds._sph_box import pressure_impulse

        gauges = dict(zip(self.info.get("probe_names", []), self.info.get("probe_gauges", [])))
        if gauges.get(name):
            raise ValueError(f"probe {name!r} is a water-level gauge: it has no pressure impulse")
        t, p = self.probe_series(name)
        return pressure_impulse(t, p, float(t0), float(t1))

    def run(self, until: float | None = None, steps: int | None = None, chunk: int = 100,
            callback=None) -> None:
        """Run to simulated time `until` (exactly: the last dt is shortened) or for `steps` steps.

        `callback(sim)` is called after every `chunk` steps; it may return True to stop.
        """
        if until is not None:
            if not isinstance(until, numbers.Real) or isinstance(until, (bool, np.bool_)):
                raise TypeError(f"until must be a number of seconds, got {until!r}")
            until = float(until)
            if not math.isfinite(until):
                raise ValueError(f"until must be a finite time, got {until!r}")
            if until < self.time:
                raise ValueError(f"until = {until!r} s is before the current time {self.time!r} s")
            self.core.set_end_time(until)
        budget = _count("steps", steps) if steps is not None else (None if until is not None else 0)
        chunk = _count("chunk", chunk, minimum=1)
        while True:
            k = chunk if budget is None else min(chunk, budget)
            if k <= 0:
                break
            taken = self.step(k)
            if budget is not None:
                budget -= k
            s = self.core.snapshot()
            if s["bad"]:
                raise UnstableRunError(_bad_step(s), self.check_health() or "unstable")
            if callback is not None and callback(self):
                break
            if self.core.snapshot()["done"] or taken < k:
                break

    def set_end_time(self, t: float) -> None:
        """Steps that would pass simulated time t are shortened, then become no-ops
        (t = inf: no end)."""
        if not isinstance(t, numbers.Real) or isinstance(t, bool) or math.isnan(t):
            raise ValueError(f"end time must be a number of seconds, got {t!r}")
        if t < 0:
            raise ValueError(f"end time must not be negative (simulated time starts at 0 s), got {t!r}")
        self.core.set_end_time(float(t))

    def set_control(self, *args, **kwargs) -> None:
        """Control input for the next steps, as the kind takes it (the 8-ball:
        ``set_control(acceleration=(ax, ay, az), torque=(tx, ty, tz))``, the container's
        linear acceleration in m/s² and the shell torque in N·m, added to the scene's shake
        schedule; a control not given is zero); every backend applies it identically."""
        values = self.kind.control(self, *args, **kwargs)
        self.core.set_control(values)
        self._control.update({k: [float(x) for x in v] for k, v in values.items()})

    @property
    def control(self) -> dict[str, list[float]]:
        """The control input the next steps take, as the core holds it: name -> values
        (what :meth:`set_control` last set, or a restored checkpoint's; zeros at first)."""
        return {k: list(v) for k, v in self._control.items()}

    def evaluate(self) -> dict:
        """Compute densities, pressures, accelerations and this state's reductions without
        advancing; returns :meth:`state` (its ``chosen_dt`` is the dt a step would take)."""
        self.core.evaluate()
        return self.state()

    def set_particles(self, positions, velocities=None) -> None:
        """Replace the particle state ((n, dim) arrays, n = n_particles, finite, positions
        where the kind allows them: inside the 8-ball's container); ids restart at 0..n-1."""
        self.kind.set_particles(self, positions, velocities)

    # checkpoints ----------------------------------------------------------------------
    def checkpoint(self) -> dict:
        """The whole state the next step reads: the checkpointed fields (for the 8-ball
        ``position``, ``velocity``, ``id``, in their current order), the scalars (time,
        step, the kind's state, control, ...) and the kind's ``checkpoint_extra`` values.
        Restoring it with :meth:`restore` (on this or a new simulation of the same scene)
        continues bit-identically on the CPU backends: the step after a checkpoint sorts and
        relists, as the first step after a restore does. The scene draws no random numbers
        after its start, so there is no generator state to keep."""
        c = dict(self.core.checkpoint())
        for name in self.kind.checkpoint_extra:
            c[name] = self.info[name]
        return c

    def restore(self, state: dict) -> None:
        """Replace the whole state by one :meth:`checkpoint` returned (the end time stays)."""
        _check_state(state)
        fields = [f for f in self._fields if f["checkpointed"]]
        missing = [f["name"] for f in fields if f["name"] not in state]
        if missing:
            raise ValueError(f"checkpoint: missing {', '.join(missing)}")
        n = self.n_particles
        arrays = {}
        for f in fields:
            name, comps = f["name"], int(f["components"])
            # a field of another group (the SPH box's walls) has its own count
            n = self.n_particles if f.get("group", "fluid") == "fluid" else int(self.core.download(name).shape[0])
            if f["dtype"][1] == "f":
                arrays[name] = _particle_array(f"checkpoint {name}", state[name], n, comps,
                                               dtype=np.dtype(f["dtype"]))
            elif name == "id":
                ids = np.ascontiguousarray(state["id"]).reshape(-1)
                if ids.shape != (n,) or ids.dtype.kind not in "iu" or np.any(np.sort(ids) != np.arange(n)):
                    raise ValueError(f"checkpoint id must be a permutation of 0..{n - 1}")
                arrays[name] = np.ascontiguousarray(ids, dtype=np.dtype(f["dtype"]))
            else:
                arr = np.asarray(state[name])
                shape = (n, comps) if comps > 1 else (n,)
                if arr.dtype.kind not in "iu" or arr.shape != shape:
                    raise ValueError(f"checkpoint {name} must be an {shape} array of integers, got shape {arr.shape}")
                arrays[name] = np.ascontiguousarray(arr, dtype=np.dtype(f["dtype"]))
        _check_restored_scalars(self, state)
        skip = {f["name"] for f in self._fields} | set(self.kind.checkpoint_extra)
        full = {k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in state.items() if k not in skip}
        full.update(arrays)
        self.core.restore(full)
        for name, values in self._control.items():  # the core restored the checkpoint's control, or zeros
            given = state.get(f"control_{name}", [0.0] * len(values))
            self._control[name] = [float(x) for x in np.atleast_1d(np.asarray(given, dtype=np.float64))]

    @property
    def checkpoint_fields(self) -> dict[str, str]:
        """The particle fields a checkpoint holds -> their group."""
        return {f["name"]: f["group"] for f in self._fields if f["checkpointed"]}

    @property
    def checkpoint_float64(self) -> tuple[str, ...]:
        """The checkpoint's scalars that are float64 (the clock's time and the kind's
        extras); the others are the core's float32 and integer values."""
        return ("time", *self.kind.checkpoint_extra)

    # state ----------------------------------------------------------------------------
    def scalars(self) -> dict:
        """The core's scalars as of the last step: the kind's per-scene record by name and
        the values the core derives (a copy)."""
        return self.core.scalars()

    def state(self) -> dict:
        """Scalars of the current state, as the kind arranges them (the 8-ball: time, dt,
        die pose, last step's reductions)."""
        return self.kind.state(self, self.core.scalars())

    @property
    def time(self) -> float:
        """Simulated time (s)."""
        return self.core.snapshot()["time"]

    @property
    def dt(self) -> float:
        """The last step's dt (s)."""
        return self.core.snapshot()["dt"]

    @property
    def steps(self) -> int:
        """Steps taken."""
        return self.core.snapshot()["step"]

    @property
    def n_particles(self) -> int:
        """Particles placed."""
        return self.core.n_particles

    @property
    def n_ghosts(self) -> int | None:
        """Ghost particles of the last step (None for kinds without ghosts)."""
        return self.core.snapshot().get("n_ghost")

    def field_info(self) -> list[dict]:
        """The kind's particle fields: name, group, dtype, components, checkpointed, settable."""
        return [dict(f) for f in self._fields]

    def field(self, name: str, copy: bool = False):
        """A particle field (the 8-ball: position, velocity, density, pressure, id,
        acceleration, ghost_position, ghost_velocity; see :meth:`field_info`). Without copy:
        a zero-copy view (NumPy on the CPU; on CUDA an array exposing ``__dlpack__`` for
        CuPy/PyTorch), valid until the next step. Particles are reordered every step; ``id``
        gives each one's persistent index."""
        if not isinstance(name, str):
            raise TypeError(f"field name must be a string, got {name!r}")
        return self.core.download(name) if copy else self.core.view(name)

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
        return self.kind.rigid_poses(self, self.core.scalars())

    def diagnostics(self) -> dict[str, float]:
        """Scalars recorded with every frame."""
        return self.kind.diagnostics(self, self.core.scalars())

    def frame(self, ghosts: bool = False, velocity: bool = False) -> dict:
        """Keyword arguments for `FrameWriter.write_frame` (host copies of the fields)."""
        return self.kind.frame(self, ghosts=ghosts, velocity=velocity)

    def header(self) -> dict:
        """The run header recorded at the start of a frame stream (docs/frame_format.md,
        "Run header"): the scene and the build, then the kind's description of the run
        (container, obstacles, rigid bodies, ...)."""
        from . import __version__
        out = {
            "scene": self.scene.name, "kind": self.scene.kind, "dim": self.kind.dim, "backend": self.backend,
            "corpuscle_version": __version__, "parameters": self.scene.to_dict(),
            "container": None, "obstacles": [], "bodies": [],
        }
        out.update(self.kind.header(self))
        return out

    def result(self) -> dict:
        """The scene's result (the 8-ball: the face toward the window, +z, and its answer)."""
        return self.kind.result(self, self.core.scalars())

    def check_health(self) -> str | None:
        """None while the run is sound, else a message naming the step where it went bad."""
        s = self.core.snapshot()
        if s["bad"]:
            reason = self.kind.unstable_reasons.get(s["bad"], "unsound state")
            return f"unstable at step {_bad_step(s)}: {reason}"
        return None

    # measurement ----------------------------------------------------------------------
    def bench_steps(self, n: int) -> float:
        """Seconds for n steps, timed by the core (CUDA events on the GPU), init excluded."""
        self.core.set_end_time(math.inf)
        return float(self.core.bench(_count("steps", n, minimum=1)))

    def stage_times(self, n: int) -> dict[str, float]:
        """Milliseconds per step of each pipeline stage, averaged over n steps."""
        self.core.set_end_time(math.inf)
        return dict(self.core.profile(_count("steps", n, minimum=1)))
