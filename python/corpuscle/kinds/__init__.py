"""Scene kinds: everything the Python side knows about one kind of scene.

The engine is kind-agnostic: :class:`corpuscle.Simulation`, the scene loader
(:mod:`corpuscle.scene`), the command line and render/plot/export name no kind. Each kind is
one module in this package that defines ``KIND``, an instance of a :class:`Kind` subclass.
The first import of this package imports every module here (modules whose names start
with ``_`` excepted) and registers its ``KIND``: **adding a scene kind is adding one file
here**, plus its pipeline in the C++ core, registered there under the same name
(``_core.kinds()``). Nothing here needs the compiled core at import time: scenes are
validated, and the CLI checks its input, before the core is loaded.

What a kind provides (attributes and methods of :class:`Kind`; those marked * have a
default in :class:`Kind`). Methods get the :class:`~corpuscle.Simulation` as ``sim``, and
those that read the state get ``s``, a copy of the core's scalars (``sim.scalars()``: the
kind's per-scene record by name, plus the values the core derives) as of the last step.

Scene (used without the core)

``name``
    The kind's name: ``[scene] kind = "..."`` in a scene file and the core's kind.
``schema``
    A :class:`corpuscle.scene.SceneKind`: every key with type, default, unit, range and
    doc; the arrays of tables (``[[shake]]``) and their required keys; the cross-key
    checks. It is registered with :func:`corpuscle.scene.register_kind`. Every kind has
    ``run.end_time`` (s) and ``run.record_every`` (steps), which the CLI's ``--time`` and
    ``--every`` set; ``run.seed`` (``--seed``) is optional.
``particle_key`` *
    The key ``--particles`` (and ``Simulation.from_scene(particles=...)``) sets, or None:
    the kind has no particle count, and ``--particles`` is an error.
``summary(result)`` *
    ``(lines, rest)``: the lines ``corpuscle run`` prints for the run's ``result()``
    after its table (the 8-ball's "8-ball says: ..."), and the rest of the result, printed
    as rows. Default: no lines, every item a row.

Building (``Simulation.__init__``)

``build(scene, target, checkpoint)``
    Returns a :class:`Build`: the core's parameters and initial arrays
    (``_core.Simulation(name, backend, index, params, arrays, device)``) and ``info``, the
    kind's derived values (smoothing length, particle mass, ...), which become read-only
    attributes of the simulation (``sim.h``). ``target`` (:class:`Target`) names the
    backend, the neighbour index and the device. Room, memory (:func:`check_memory`) and
    capacity checks belong here, before anything costly is allocated. With a
    ``checkpoint`` (a dict as ``Simulation.checkpoint()`` returns), the initial arrays come
    from it (the simulation restores the rest).
``checkpoint_extra`` *
    Names in ``info`` that checkpoints carry as well (float64 scalars, e.g. the 8-ball's
    Poisson-disk ``spacing``), for ``build`` to read back.

Reading the state

``dim`` *
    2 or 3: the dimension of positions (default 3).
``state(sim, s)`` *
    ``Simulation.state()``: the state as a dict (default: the scalars as they are).
``diagnostics(sim, s)`` *
    The scalars recorded with every frame, name -> float (default: none).
``rigid_poses(sim, s)`` *
    Rigid bodies: name -> position, orientation, velocity, angular velocity arrays.
``result(sim, s)`` *
    The scene's result (the 8-ball's answer); default ``{}``.
``header(sim)`` *
    The kind's part of the run header (see docs/frame_format.md, "Run header"):
    ``container``, ``obstacles``, ``bodies`` and whatever else describes the run
    (``particles``, ``h``, ``particle_radius``, ``units`` ...; ``render``: the kind's default
    colouring for render and the live page, ``{"color": field, "range": [lo, hi], "log":
    bool, "ramp": name}``). The simulation adds ``scene``, ``kind``, ``dim``, ``backend``,
    ``corpuscle_version``, ``parameters``.
``frame(sim, ghosts, velocity)`` *
    Keyword arguments for ``FrameWriter.write_frame``. The default records the fields in
    ``frame_fields``, ``velocity`` when asked, the fields in ``ghost_fields`` when asked
    (each in its core group), ``rigid_poses`` and ``diagnostics``; and the particles'
    ``id`` first, whenever the kind's field table has one, and the fields its table marks
    ``recorded`` (sim/field_store.h).
``unstable_reasons`` *
    The core's instability codes (the ``bad`` scalar) -> text, for ``check_health()``.
``units`` *
    Units of the kind's fields and diagnostics, name -> unit, written to the run header
    for render and plot.

Changing the state

``control(sim, *args, **kwargs)`` *
    ``Simulation.set_control``'s arguments as the core's controls ``{name: values}``.
    Default: keyword (or positional, in the core's order) arguments named as the core's
    controls, each a finite vector of its length; a control not given is zero.
``set_particles(sim, positions, velocities)`` *
    ``Simulation.set_particles``. Default: (n, dim) finite arrays, ``check_positions``,
    then the ``position`` and ``velocity`` fields uploaded.
``check_positions(sim, positions)`` *
    Raise ValueError for positions the scene cannot hold (default: none).
``live_controls(sim)`` *
    Sliders for the live page (``corpuscle run --live``): a list of ``{"control", "index",
    "label", "unit", "min", "max", "step", "value", "scale", "offset"}``, the control's
    component ``index`` being ``scale * value + offset`` for a slider at ``value`` (the wind
    tunnel's inflow speed in m/s and angle of attack in degrees); messages outside a slider's
    range are rejected. Default: none.
``methods`` *
    Names of further methods of the kind that the simulation offers as its own:
    ``sim.set_die(...)`` calls ``kind.set_die(sim, ...)``. They must not shadow an
    attribute of :class:`~corpuscle.Simulation`.

Every kind's core record has the clock scalars ``time``, ``end_time``, ``step``, ``dt``,
``done``, ``bad`` and ``bad_step``, which the simulation reads itself (``sim.time``,
``run``, ``check_health``); ``n_ghost``, where a kind has it, is ``sim.n_ghosts``. A kind
changes the core only through ``sim.core``, which drops the simulation's scalar snapshot
whenever it changes the state.
"""

from __future__ import annotations

import functools
import importlib
import numbers
import pkgutil
from dataclasses import dataclass, field
from typing import Any

import math

import numpy as np

from .. import schema as _schema
from .._errors import MemoryNeedError
from ..schema import SceneError, SceneKind

__all__ = ["Kind", "Build", "Target", "register", "find", "get", "registry", "count", "finite_vector",
           "CONTROL_BOUNDS", "bounded_control", "particle_array", "fmt_bytes", "check_memory", "memory_available",
           "key_values", "kind_method", "core"]

# the run keys every kind declares (the CLI's --time and --every set them)
REQUIRED_KEYS = ("run.end_time", "run.record_every")

# the field every kind's frames carry first: a particle's index in the initial arrays (kept
# through every re-sort; a batch of scenes numbers them scene by scene, scene s holding ids
# s * n to (s + 1) * n - 1)
ID_FIELD = "id"


@dataclass(frozen=True)
class Target:
    """Where a simulation runs: backend (serial, cpu, cuda), neighbour index, CUDA device."""

    backend: str
    index: str
    device: int = 0


@dataclass
class Build:
    """What :meth:`Kind.build` returns: the core's parameters and initial arrays, and the
    kind's derived values (attributes of the simulation)."""

    params: dict[str, Any]
    arrays: dict[str, np.ndarray]
    info: dict[str, Any] = field(default_factory=dict)


class Kind:
    """A scene kind (see the module's documentation for what a subclass provides)."""

    name: str = ""
    schema: SceneKind
    dim: int = 3
    particle_key: str | None = None
    methods: tuple[str, ...] = ()
    checkpoint_extra: tuple[str, ...] = ()
    unstable_reasons: dict[int, str] = {}
    units: dict[str, str] = {}
    frame_fields: tuple[str, ...] = ("position",)
    ghost_fields: tuple[str, ...] = ()
    # a liquid with a free surface (SPH): `corpuscle export --format surface` reconstructs it
    fluid: bool = False

    @property
    def description(self) -> str:
        return self.schema.description

    def __repr__(self) -> str:
        return f"<scene kind {self.name!r}>"

    # scene -------------------------------------------------------------------------------
    def summary(self, result: dict[str, Any]) -> tuple[list[str], dict[str, Any]]:
        """Lines for the CLI's run summary, and the rest of the result (printed as rows)."""
        return [], dict(result)

    # building ----------------------------------------------------------------------------
    def build(self, scene, target: Target, checkpoint: dict | None = None) -> Build:
        raise NotImplementedError(f"scene kind {self.name!r} does not build simulations")

    # reading -----------------------------------------------------------------------------
    def state(self, sim, s: dict[str, Any]) -> dict[str, Any]:
        return s

    def diagnostics(self, sim, s: dict[str, Any]) -> dict[str, float]:
        return {}

    def rigid_poses(self, sim, s: dict[str, Any]) -> dict[str, dict[str, np.ndarray]]:
        return {}

    def result(self, sim, s: dict[str, Any]) -> dict[str, Any]:
        return {}

    def header(self, sim) -> dict[str, Any]:
        return {"container": None, "obstacles": [], "bodies": []}

    def frame(self, sim, ghosts: bool = False, velocity: bool = False) -> dict[str, Any]:
        info = sim.field_info()
        group = {f["name"]: f["group"] for f in info}
        # every frame carries each particle's id (the engine writes its particles in sorted
        # order, which changes when they are re-sorted: the id follows a particle)
        names = [ID_FIELD] if ID_FIELD in group and ID_FIELD not in self.frame_fields else []
        names += list(self.frame_fields)
        # and the fields the core's table marks recorded
        names += [f["name"] for f in info if f.get("recorded") and f["name"] not in names]
        if velocity:
            names.append("velocity")
        if ghosts:
            names += list(self.ghost_fields)
        fields = dict(sim.core.download_many(names))  # one transfer for the frame
        groups = {name: group.get(name, "fluid") for name in names}
        rigid = {name: {"position": p["position"], "orientation": p["orientation"]}
                 for name, p in sim.rigid_poses().items()}
        return {"fields": fields, "groups": groups, "rigid": rigid, "diagnostics": sim.diagnostics()}

    # changing the state ------------------------------------------------------------------
    def control(self, sim, *args, **kwargs) -> dict[str, list[float]]:
        counts = dict(sim.core.controls())
        names = list(counts)
        if len(args) > len(names):
            raise TypeError(f"set_control takes at most {len(names)} controls ({', '.join(names)}), "
                            f"got {len(args)}")
        given = dict(zip(names, args))
        for name, value in kwargs.items():
            if name not in counts:
                raise TypeError(f"unknown control {name!r} (controls: {', '.join(names)})")
            if name in given:
                raise TypeError(f"control {name!r} given twice")
            given[name] = value
        return {name: finite_vector(name, given.get(name, [0.0] * counts[name]), counts[name]) for name in names}

    def set_particles(self, sim, positions, velocities=None) -> None:
        n = sim.n_particles
        pos = particle_array("positions", positions, n, self.dim)
        vel = np.zeros_like(pos) if velocities is None else particle_array("velocities", velocities, n, self.dim)
        self.check_positions(sim, pos)
        sim.core.upload("position", pos)  # ids restart at 0..n-1
        sim.core.upload("velocity", vel)

    def check_positions(self, sim, positions: np.ndarray) -> None:
        return None

    def live_controls(self, sim) -> list[dict[str, Any]]:
        return []


# ---- the registry ------------------------------------------------------------------------

_REGISTRY: dict[str, Kind] = {}


def register(kind: Kind) -> Kind:
    """Add a kind (and its schema to :mod:`corpuscle.schema`); a later one of the same name
    replaces it."""
    if not isinstance(kind, Kind):
        raise TypeError(f"a scene kind must be a corpuscle.kinds.Kind, got {type(kind).__name__}")
    schema = getattr(kind, "schema", None)
    if not isinstance(schema, SceneKind) or schema.name != kind.name or not kind.name:
        raise TypeError(f"scene kind {kind.name!r}: schema must be a SceneKind named {kind.name!r}")
    missing = [k for k in REQUIRED_KEYS if k not in schema.keys]
    if missing:
        raise TypeError(f"scene kind {kind.name!r}: its schema lacks {', '.join(missing)}")
    if kind.particle_key is not None and kind.particle_key not in schema.keys:
        raise TypeError(f"scene kind {kind.name!r}: particle_key {kind.particle_key!r} is not one of its keys")
    absent = [m for m in kind.methods if not callable(getattr(kind, m, None))]
    if absent:
        raise TypeError(f"scene kind {kind.name!r}: methods {', '.join(absent)} are not defined")
    _schema.register_kind(schema)
    _REGISTRY[kind.name] = kind
    return kind


def find(name: str) -> Kind | None:
    """The kind of this name, or None."""
    return _REGISTRY.get(name)


def get(name: str) -> Kind:
    """The kind of this name (KeyError naming the known ones)."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise KeyError(f"unknown scene kind {name!r} (kinds: {', '.join(_REGISTRY) or 'none'})") from None


def registry() -> dict[str, Kind]:
    """Every registered kind, name -> kind, in registration order."""
    return dict(_REGISTRY)


def _discover() -> None:
    for module in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if module.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{__name__}.{module.name}")
        kind = getattr(mod, "KIND", None)
        if kind is None:
            raise TypeError(f"{mod.__name__} defines no KIND")
        register(kind)


# ---- helpers for kinds ---------------------------------------------------------------------


def core():
    """The compiled extension (imported on first use)."""
    from .. import _core as c
    return c


def count(name: str, value, minimum: int = 0, maximum: int = 2**63 - 1) -> int:
    """An integer argument (Python or NumPy integer, not bool or float) in [minimum,
    maximum] (by default what the core's 64-bit integers hold)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    if int(value) < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {int(value)}")
    if int(value) > maximum:
        raise ValueError(f"{name} must be <= {maximum}, got {int(value)}")
    return int(value)


#: the largest control input, per component, that any kind takes from any entry point
#: (Simulation.set_control, Batch.set_control, the Gymnasium env, a restored checkpoint), and
#: the bounds of the 8-ball's [[shake]] window keys: name -> (bound, unit)
CONTROL_BOUNDS: dict[str, tuple[float, str]] = {"acceleration": (1e4, "m/s²"), "torque": (1e6, "N·m")}


def bounded_control(name: str, value, length: int = 3) -> list[float]:
    """`length` finite numbers each within ``CONTROL_BOUNDS[name]``."""
    out = finite_vector(name, value, length)
    bound, unit = CONTROL_BOUNDS[name]
    if any(not -bound <= x <= bound for x in out):
        raise ValueError(f"{name} must be {length} numbers each in [{-bound:g}, {bound:g}] {unit}, got {out}")
    return out


def finite_vector(name: str, value, length: int = 3) -> list[float]:
    """`length` finite numbers."""
    # the common case, a tuple or list of Python numbers, without NumPy (set every step)
    if type(value) in (tuple, list) and len(value) == length and all(type(x) in (float, int) for x in value):
        out = [float(x) for x in value]
        if all(math.isfinite(x) for x in out):
            return out
        raise ValueError(f"{name} must be finite, got {out}")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be {length} numbers, got {value!r}") from None
    if arr.shape != (length,):
        raise ValueError(f"{name} must be {length} numbers, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return [float(x) for x in arr]


def particle_array(name: str, value, n: int, components: int = 3, dtype=np.float32) -> np.ndarray:
    """An (n, components) array of finite numbers ((n,) for one component), as ``dtype``."""
    shape = (n, components) if components > 1 else (n,)
    text = f"({n}, {components})" if components > 1 else f"({n},)"
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be an {text} array of numbers") from None
    if arr.dtype.kind not in "iuf" or arr.shape != shape:
        raise ValueError(f"{name} must be an {text} array of numbers, got shape {arr.shape} dtype {arr.dtype}")
    rows = np.isfinite(arr) if arr.ndim == 1 else np.isfinite(arr).all(axis=1)
    bad = np.flatnonzero(~rows)
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"{name}[{i}] = {arr[i].tolist()} is not finite ({bad.size} rows are not)")
    with np.errstate(over="ignore", invalid="ignore"):
        out = np.ascontiguousarray(arr, dtype=dtype)
    # finite in float64 but not in the core's dtype (1e300 as float32 is inf): the step would
    # start from a non-finite state
    rows = np.isfinite(out) if out.ndim == 1 else np.isfinite(out).all(axis=1)
    bad = np.flatnonzero(~rows)
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"{name}[{i}] = {arr[i].tolist()} does not fit in {np.dtype(dtype).name} "
                         f"({bad.size} rows do not)")
    return out


def fmt_bytes(b: float) -> str:
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if b >= size:
            return f"{b / size:.3g} {unit}"
    return f"{b / 1e3:.3g} kB"


def key_values(scene, keys) -> str:
    """``key=value, ...`` of scene keys, values as TOML writes them (true/false)."""
    v = scene.values
    return ", ".join(f"{k}={v[k]!r}".replace("True", "true").replace("False", "false") for k in keys)


def memory_available(target: Target) -> tuple[float | None, str]:
    """(bytes the backend can allocate now, what they are), None where unknown: the GPU's free
    memory, or the host's available memory within the process's own limits (a ulimit, a
    cgroup: :mod:`corpuscle._memory_limits`)."""
    have = float(core().bytes_available(target.backend, target.device))
    where = "GPU memory free" if target.backend == "cuda" else "host memory available"
    if target.backend != "cuda":  # a ulimit or a cgroup may allow less than the host has
        from .._memory_limits import process_limit

        limit = process_limit()
        if limit is not None and (have <= 0 or limit[0] < have):
            have, where = limit[0], f"memory this process may still use ({limit[1]})"
            return have, where
    return (have if have > 0 else None), where


def check_memory(kind: str, target: Target, params: dict, keys: str, detail: str) -> None:
    """Fail (:class:`MemoryNeedError`, naming ``keys`` and ``detail``) before allocating
    when a simulation with these parameters needs more memory than the backend has."""
    try:
        need = float(core().bytes_needed(kind, target.index, params))
    except ValueError as exc:  # a size the core cannot index (a grid of more than 2^31 cells, ...)
        raise SceneError(f"{keys}: {exc}") from None
    have, where = memory_available(target)
    if have is not None and need > have:
        raise MemoryNeedError(f"{keys} need {fmt_bytes(need)} ({detail}), more than the {fmt_bytes(have)} of {where}")


def kind_method(kind: Kind, name: str, sim):
    """``kind.<name>`` bound to ``sim`` (what ``sim.<name>`` is for a kind's method)."""
    fn = getattr(kind, name)

    @functools.wraps(fn)
    def method(*args, **kwargs):
        return fn(sim, *args, **kwargs)

    return method


_discover()
