"""`corpuscle.Batch`: many independent Magic 8-Balls in one state on one backend.

One compiled simulation holds B scenes (their particles in fixed slot ranges, a record,
a control and a clock each); a step advances all of them at once and they never interact.
What a study varies per scene (particle count, fluid stiffness and viscosity, die size and
density, seed) is given as arrays; everything else is shared.

A batch starts settled: the scenes are placed, stepped for ``settle`` seconds without
control input, and that state is kept on the device as the **reset cache**. Every scene
then starts from it with its clock at zero, and :meth:`Batch.reset` restores chosen scenes
from it — one small upload and two kernels (their slots, their records), so resetting a tenth
of a batch costs far less than one batched step. With ``randomize`` the restored scene is turned by two symmetries
that keep it settled: the whole scene about the direction of gravity (the container is a
sphere at rest) and the die by one of the rotations that map its cube onto itself (24), so
every face is equally likely to be up when an episode starts. Without it the cached state
comes back bit for bit.
"""
from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

from . import kinds as _kinds
from ._errors import UnstableRunError
from .kinds import Target, count as _count, magic8ball
from .simulation import _core, resolve_backend

__all__ = ["Batch", "PER_SCENE_KEYS", "CONTROL_COLUMNS", "cube_rotations"]

#: scene keys that may be given as one value per scene (an array of length n)
#: particle slots of a batch (scenes x the most particles of one): the core indexes them with int32
MAX_SLOTS = 2**31 - 1
#: a lower bound of the memory one particle slot needs (positions, velocities, densities,
#: neighbour slots...: about 4 kB at the default scene): checked before anything is built
MIN_SLOT_BYTES = 256
PER_SCENE_KEYS = ("fluid.particles", "fluid.stiffness", "fluid.viscosity", "die.side", "die.density", "run.seed")
#: the columns of a batch's actions: container linear acceleration (m/s²), shell torque (N·m)
CONTROL_COLUMNS = ("acceleration_x", "acceleration_y", "acceleration_z", "torque_x", "torque_y", "torque_z")

_ALIASES = {"particles": "fluid.particles", "seed": "run.seed", "end_time": "run.end_time"}


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products of quaternion arrays (..., 4), (w, x, y, z)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v (..., 3) rotated by unit quaternions q (..., 4)."""
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + q[..., :1] * t + np.cross(u, t)


def cube_rotations() -> np.ndarray:
    """The 24 rotations that map a cube (centred, axis-aligned) onto itself, as unit
    quaternions (24, 4): the identity, quarter, half and three-quarter turns about the 3 face
    axes, half turns about the 6 edge axes, and third turns about the 4 body diagonals."""
    q = [(1.0, 0.0, 0.0, 0.0)]
    for e in np.eye(3):
        for angle in (0.5 * np.pi, np.pi, 1.5 * np.pi):
            q.append((math.cos(angle / 2), *(math.sin(angle / 2) * e)))
    for axis in ((1, 1, 0), (1, -1, 0), (1, 0, 1), (1, 0, -1), (0, 1, 1), (0, 1, -1)):
        q.append((0.0, *(np.asarray(axis, dtype=np.float64) / math.sqrt(2.0))))
    for sx, sy, sz in np.ndindex(2, 2, 2):
        q.append((0.5, 0.5 * (-1) ** sx, 0.5 * (-1) ** sy, 0.5 * (-1) ** sz))
    return np.asarray(q, dtype=np.float64)


def _random_quaternions(rng: np.random.Generator, k: int) -> np.ndarray:
    # uniform on SO(3) (Shoemake 1992)
    u1, u2, u3 = rng.random((3, k))
    a, b = np.sqrt(1 - u1), np.sqrt(u1)
    return np.stack([b * np.cos(2 * np.pi * u3), a * np.sin(2 * np.pi * u2), a * np.cos(2 * np.pi * u2),
                     b * np.sin(2 * np.pi * u3)], axis=1)


#: the core's codes of the step's paths (``path`` of Batch.from_scene, ``bench --path``);
#: ``"chip-emulated"`` runs the chip path's code on the CPU's emulated tiles (the tests')
PATHS = {"auto": -1, "general": 0, "chip": 1, "chip-emulated": 2}


def core_path(path: str, backend: str, key: str = "path") -> int:
    """The core's code of a step path, checked against the backend (a one-line ValueError)."""
    if path not in PATHS:
        raise ValueError(f"{key} must be one of auto, general, chip, got {path!r}")
    if path == "chip" and backend != "cuda":
        raise ValueError(f"{key} = chip runs on the cuda backend, got backend {backend!r} (use general or auto)")
    return PATHS[path]


def _split_overrides(n: int, overrides: dict[str, Any]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Shared overrides and per-scene arrays (keys of PER_SCENE_KEYS given n values)."""
    shared, per = {}, {}
    for key, value in overrides.items():
        is_seq = isinstance(value, (list, tuple, np.ndarray))
        if key in PER_SCENE_KEYS and is_seq:
            arr = np.asarray(value)
            if arr.ndim != 1 or arr.shape[0] != n:
                raise ValueError(f"{key} must be one value or one per scene ({n}), got shape {arr.shape}")
            if arr.dtype.kind not in "iuf" or not np.all(np.isfinite(arr)):
                raise ValueError(f"{key} must be {n} finite numbers, got {value!r}")
            per[key] = arr
        elif isinstance(value, np.ndarray) and value.ndim >= 1 and value.shape[0] == n and value.size != 3:
            raise ValueError(f"{key} cannot vary per scene (keys that can: {', '.join(PER_SCENE_KEYS)})")
        else:
            shared[key] = value.tolist() if isinstance(value, np.ndarray) else value
    return shared, per


class Batch:
    """B independent Magic 8-Balls stepped together on one backend.

    Build with :meth:`from_scene`. :meth:`step` advances every scene (each with its own
    adaptive dt), :meth:`advance` advances each by the same simulated time,
    :meth:`set_control` takes a (B, 6) array of container accelerations and shell torques
    (one upload at the next step, no rebuild), :meth:`reset` restores chosen scenes to the
    settled start, :meth:`observations` returns per-scene arrays without copies (NumPy on
    the CPU; on CUDA arrays exposing ``__dlpack__`` for PyTorch, JAX or CuPy).
    """

    def __init__(self, *args, **kwargs):
        raise TypeError("build a Batch with Batch.from_scene(scene, n=..., ...)")

    # construction ---------------------------------------------------------------------
    @classmethod
    def from_scene(cls, scene="magic8ball", n: int = 1, backend: str = "auto",
                   overrides: dict[str, Any] | None = None, neighbors: str | None = None, device: int | None = None,
                   settle: float = 1.0, randomize: bool = True, placement: str = "rotated",
                   comm=None, path: str | None = None, **kwargs) -> "Batch":
        """n scenes of one scene file (a built-in name, a TOML path or a Scene), with
        overrides as :meth:`corpuscle.Simulation.from_scene` takes them (dotted keys or
        ``__`` for the dot; ``particles``, ``seed``, ``end_time``). The keys of
        :data:`PER_SCENE_KEYS` may be given one value per scene (a length-n array); a seed
        given once gives scene s the seed ``seed + s``.

        ``placement``: ``"rotated"`` places the fluid once for each distinct particle count
        and die size and gives each scene a random rotation of it (drawn from its seed: the
        container is a sphere, so this is another valid start; fast for thousands of
        scenes); ``"each"`` places every scene as ``Simulation.from_scene`` with its seed
        would (the same start bit for bit, about 0.3 s a scene). The smoothing length is
        shared: the one the smallest particle count gives (``sph.scale_h``), so every scene
        has at least its usual neighbour count.

        ``settle``: seconds stepped without control before the state is cached (0: none).
        ``randomize``: whether :meth:`reset`, and the start, turn each scene by a random
        symmetry (about gravity, and the die by a rotation of its cube).

        ``path``: how the device steps the scenes: ``"chip"`` (a block per scene, the scene in
        the multiprocessor's shared memory, many steps a launch: docs/magic8ball.md),
        ``"general"`` (the engine's stages over global memory), or ``"auto"`` (general: the chip
        path measured slower, docs/magic8ball.md); None: the scene's ``sph.path``.
        ``"chip"`` on a CPU backend, or where a scene does not fit, is a ``ValueError``.
        :attr:`path` says which runs.

        ``comm`` (an mpi4py communicator, e.g. ``MPI.COMM_WORLD``; docs/distributed.md): the n
        scenes are spread over its ranks in contiguous blocks, rank r holding scenes
        ``[scene_offset, scene_offset + n_scenes)`` on its own backend and device (``device``
        None: the node-local rank's GPU). Every per-scene array of the API is then the rank's
        (B = its ``n_scenes``); :meth:`gather_observations` brings every rank's to one. Each
        scene is built and stepped exactly as in a one-process batch of all n (bit for bit on
        the CPU); randomized resets draw their turns per rank. The construction is checked on
        every rank and fails on all (``ValueError``) when it fails on any.
        """
        if comm is None:
            return cls._build(scene, n, backend, overrides, neighbors, 0 if device is None else device, settle,
                              randomize, placement, None, path, **kwargs)
        from . import _mpi

        if device is None and resolve_backend(backend) == "cuda":
            local, _ = _mpi.node_local_rank(comm)
            device = local % max(1, len(_core().build_info().get("gpus") or [None]))
        return _mpi.agree(comm, lambda: cls._build(scene, n, backend, overrides, neighbors, device or 0, settle,
                                                   randomize, placement, comm, path, **kwargs))

    @classmethod
    def _build(cls, scene, n, backend, overrides, neighbors, device, settle, randomize, placement, comm, path=None,
               **kwargs) -> "Batch":
        from .scene import Scene, load_scene

        self = cls.__new__(cls)
        n = _count("n", n, minimum=1)
        rank, size = (0, 1) if comm is None else (comm.Get_rank(), comm.Get_size())
        if n < size:
            raise ValueError(f"n = {n} scenes over {size} ranks: give every rank at least one scene")
        lo, hi = rank * n // size, (rank + 1) * n // size  # this rank's scenes
        n_loc = hi - lo
        self.comm, self.scene_offset, self.n_total = comm, lo, n
        if placement not in ("rotated", "each"):
            raise ValueError(f"placement must be 'rotated' or 'each', got {placement!r}")
        if not isinstance(settle, numbers.Real) or isinstance(settle, bool) or not (0.0 <= settle < 1e6):
            raise ValueError(f"settle must be a time in seconds (>= 0), got {settle!r}")
        if not isinstance(scene, Scene):
            scene = load_scene(scene)
        if scene.kind != "magic8ball":
            raise ValueError(f"a Batch runs magic8ball scenes, got kind {scene.kind!r}")
        kind = _kinds.get(scene.kind)
        ovr = dict(overrides or {})
        for k, v in kwargs.items():
            ovr[_ALIASES.get(k, k.replace("__", "."))] = v
        shared, per = _split_overrides(n, ovr)
        base = scene.with_overrides(shared) if shared else scene
        v = base.values
        # the cheap limits first: nothing of size n is made before they hold
        n_most = int(np.max(per["fluid.particles"])) if "fluid.particles" in per else int(v["fluid.particles"])
        if n_loc * n_most > MAX_SLOTS:
            raise ValueError(f"n = {n_loc} scenes{' on a rank' if comm is not None else ''} of fluid.particles = {n_most}: {n_loc * n_most:,} particle slots, "
                             f"at most {MAX_SLOTS:,}")
        self.backend = resolve_backend(backend)
        path_code = None if path is None else core_path(path, self.backend)
        self.device = _count("device", device)
        have, where = _kinds.memory_available(Target(self.backend, "lists", self.device))
        if have is not None and n_loc * n_most * MIN_SLOT_BYTES > have:
            raise _kinds.MemoryNeedError(
                f"n = {n_loc}, fluid.particles = {n_most} need more than {_kinds.fmt_bytes(n_loc * n_most * MIN_SLOT_BYTES)} "
                f"({n_loc * n_most:,} particle slots of at least {MIN_SLOT_BYTES} bytes), more than the "
                f"{_kinds.fmt_bytes(have)} of {where}")
        seeds = per.pop("run.seed", None)
        if seeds is None:
            seeds = int(v["run.seed"]) + np.arange(n, dtype=np.int64)
        if seeds.dtype.kind not in "iu" or np.any(seeds < 0):
            raise ValueError(f"run.seed must be non-negative integers, got {seeds.tolist()!r}")
        cols = {key: (per[key] if key in per else np.full(n, v[key])) for key in PER_SCENE_KEYS if key != "run.seed"}
        counts = cols["fluid.particles"]
        if counts.dtype.kind not in "iu" and not np.all(counts == np.round(counts)):
            raise ValueError(f"fluid.particles must be whole numbers, got {counts.tolist()!r}")
        counts = cols["fluid.particles"] = counts.astype(np.int64)
        # every distinct combination is validated once (ranges and cross-checks)
        combos = {}
        for s in range(n):
            key = tuple(cols[k][s].item() for k in cols)
            if key not in combos:
                combos[key] = base.with_overrides(dict(zip(cols, key)))
        kinds = dict(_core().kinds())
        self.neighbors = kinds["magic8ball"][0] if neighbors is None else str(neighbors)
        if self.neighbors not in kinds["magic8ball"]:
            raise ValueError(f"--neighbors must be one of {', '.join(kinds['magic8ball'])} (the indexes of magic8ball), "
                             f"got {self.neighbors!r}")
        if self.device and self.backend != "cuda":
            raise ValueError(f"--device {self.device}: selects a CUDA device; the {self.backend} backend has none "
                             "(leave --device out, or use --backend cuda)")
        target = Target(self.backend, self.neighbors, self.device)
        # the shared smoothing length: that of the smallest particle count
        n_min, n_max = int(counts.min()), int(counts.max())
        h = float(v["sph.h"])
        if v["sph.scale_h"]:
            h *= (float(v["sph.reference_particles"]) / n_min) ** (1.0 / 3.0)
        fixed_h = {"sph.h": h, "sph.scale_h": False}

        def build(scene_values: dict, seed: int):
            sc = base.with_overrides({**scene_values, **fixed_h, "run.seed": int(seed)})
            return kind.build(sc, target, None)

        # the batch-wide parameters: those of a scene of the most particles
        top = next(k for k in combos if int(k[0]) == n_max)
        ref = build(dict(zip(cols, top)), int(seeds[0]))
        placed = {(n_max, float(top[list(cols).index("die.side")])): ref}
        params = dict(ref.params)
        params["n_fluid"] = n_max
        params["n_scenes"] = n_loc
        if path_code is not None:
            params["path"] = path_code
        # per-scene parameters
        side = cols["die.side"].astype(np.float64)
        radius = float(v["container.radius"])
        die_mass, die_inertia = magic8ball.die_mass_inertia(cols["die.density"].astype(np.float64), side)
        mass = magic8ball.particle_mass(float(v["fluid.rest_density"]), radius, side, counts)
        scenes = []
        for s in range(lo, hi):
            scenes.append({"n_fluid": int(counts[s]), "mass": float(mass[s]),
                           "stiffness": float(cols["fluid.stiffness"][s]), "viscosity": float(cols["fluid.viscosity"][s]),
                           "die_half": [float(side[s]) / 2] * 3, "die_mass": float(die_mass[s]),
                           "die_inertia": [float(die_inertia[s])] * 3})
        params["scenes"] = scenes
        _kinds.check_memory("magic8ball", target, params,
                            f"n = {n_loc}, fluid.particles = {n_max}", f"{params['max_neighbors']} neighbour slots per particle")
        # initial particles: each scene's in its slot range, inactive slots at the centre
        pos = np.zeros((n_loc * n_max, 3), dtype=np.float32)
        dies = []
        for s in range(lo, hi):
            key = tuple(cols[k][s].item() for k in cols)
            if placement == "each":
                b = build(dict(zip(cols, key)), int(seeds[s]))
                p, die = b.arrays["position"], dict(b.params["die_initial"])
            else:
                geo = (int(counts[s]), float(side[s]))
                if geo not in placed:
                    placed[geo] = build(dict(zip(cols, key)), int(seeds[0]))
                b = placed[geo]
                q = _random_quaternions(np.random.default_rng(int(seeds[s])), 1)[0]
                p = _rotate(q[None, :], b.arrays["position"].astype(np.float64)).astype(np.float32)
                die = dict(b.params["die_initial"])
                die["position"] = _rotate(q, np.asarray(die["position"], dtype=np.float64)).tolist()
                qd = _qmul(q, np.asarray(die["orientation"], dtype=np.float64))
                die["orientation"] = (qd / np.linalg.norm(qd)).tolist()
            pos[(s - lo) * n_max: (s - lo) * n_max + int(counts[s])] = p
            dies.append(die)
        params["die_initial_scenes"] = dies
        params.pop("die_initial", None)
        self.scene = base
        self.params = params
        self.n_scenes = n_loc
        self.slots = n_max
        self.h = h
        self.answers = list(v["die.answers"])
        #: per-scene parameters as given (arrays of length n)
        self.scene_params = {**{k: np.asarray(c)[lo:hi].copy() for k, c in cols.items()}, "run.seed": seeds[lo:hi].copy()}
        self.n_active = counts[lo:hi].copy()
        self._rng = np.random.default_rng(int(seeds[lo]) + 0x8BA11)
        self._sym = cube_rotations()
        try:
            self.core = _core().Simulation("magic8ball", self.backend, self.neighbors, params,
                                           {"position": pos, "velocity": np.zeros_like(pos)}, self.device)
        except Exception as exc:  # the core's refusal of path = chip: one line, a ValueError
            if "path = chip" in str(exc):
                raise ValueError(str(exc).removeprefix("magic8ball: ")) from None
            raise
        self._controls = sum(int(c) for c in dict(self.core.controls()).values())
        self.core.evaluate()
        # settle, keep the reset cache, start every scene from it
        if settle > 0:
            self.core.set_end_time(float(settle))
            self.core.step(10**9)  # until every scene reached it
            bad = self.core.scalar_of_scenes("bad")
            if np.any(bad):
                s = int(np.flatnonzero(bad)[0])
                step = int(self.core.scalar_of_scenes("bad_step")[s])
                reason = kind.unstable_reasons.get(int(bad[s]), "unsound state")
                raise UnstableRunError(step, f"scene {s} went unstable while settling: {reason}")
        self.core.set_end_time(math.inf)
        self.core.cache_scenes()
        self._gravity_axis = self._gravity_axes()
        self.randomize = bool(randomize)
        self.reset()
        return self

    def _gravity_axes(self) -> np.ndarray:
        # gravity in the container frame of each cached scene (the axis of its turn)
        g = np.asarray(self.params["gravity"], dtype=np.float64)
        if np.linalg.norm(g) == 0.0:
            return np.zeros((self.n_scenes, 3))
        q = self.core.scalar_of_scenes("shell_orientation").astype(np.float64)
        qi = q * np.array([1.0, -1.0, -1.0, -1.0])
        axes = _rotate(qi, np.broadcast_to(g, (self.n_scenes, 3)))
        return axes / np.linalg.norm(axes, axis=1, keepdims=True)

    @property
    def path(self) -> str:
        """The path the scenes are stepped on: ``"chip"`` or ``"general"`` (see from_scene)."""
        return "chip" if dict(self.core.scalars(0)).get("chip_path", 0.0) else "general"

    # stepping -------------------------------------------------------------------------
    def step(self, k: int = 1) -> int:
        """Advance every scene up to k steps (each with its own dt); returns the steps taken
        by the scene that took the most (a scene past its end time or unsound takes none)."""
        return int(self.core.step(_count("steps", k)))

    def advance(self, duration, max_steps: int = 10**7) -> int:
        """Advance every scene by `duration` seconds of simulated time (one number, or one
        per scene; 0 holds a scene still): each lands exactly on its time + duration, then
        waits for the others. Returns the steps run (of the scene that took the most in each
        chunk)."""
        if isinstance(duration, numbers.Real) and not isinstance(duration, bool):
            if not (0 < duration < 1e6):
                raise ValueError(f"duration must be a positive number of seconds, got {duration!r}")
            d = np.full(self.n_scenes, float(duration))
        else:
            d = np.asarray(duration, dtype=np.float64) if not isinstance(duration, bool) else np.zeros(0)
            if d.shape != (self.n_scenes,) or not np.all((d >= 0) & (d < 1e6)):
                raise ValueError(f"duration must be a positive number of seconds or {self.n_scenes} numbers >= 0, "
                                 f"got {duration!r}")
        budget = _count("max_steps", max_steps, minimum=1)
        self.core.set_end_times(np.ascontiguousarray(d), True)
        # in chunks of the steps the scenes still need at their last dt: a device checks the
        # scenes only every 32 steps, and steps launched after the last scene is done are waste
        taken = 0
        dt_max = float(self.params["dt_max"])
        while taken < budget:
            c = self.core
            live = (c.scalar_of_scenes("done") == 0) & (c.scalar_of_scenes("bad") == 0)
            if not live.any():
                break
            left = (c.scalar_of_scenes("end_time") - c.scalar_of_scenes("time"))[live]
            dt = c.scalar_of_scenes("dt")[live].astype(np.float64)
            need = int(np.ceil(np.max(left / np.where(dt > 0, dt, dt_max)) * (1 + 1e-6)))
            k = int(c.step(min(max(need, 1), budget - taken)))
            if k == 0:
                break
            taken += k
        self.core.set_end_time(math.inf)
        return taken

    def set_control(self, actions) -> None:
        """Control input of every scene for the next steps: a (B, 6) array, per scene the
        container's linear acceleration (m/s², 3) and the torque on its shell (N·m, 3),
        added to the scene's shake schedule. Staged on the host, uploaded once by the next
        step; nothing is rebuilt."""
        a = self._actions(actions)
        self.core.set_controls(a)

    def _actions(self, actions) -> np.ndarray:
        if hasattr(actions, "__dlpack__") and not isinstance(actions, np.ndarray) and hasattr(actions, "cpu"):
            actions = actions.detach().cpu().numpy() if hasattr(actions, "detach") else actions.cpu()
        try:
            a = np.asarray(actions)
        except Exception:  # noqa: BLE001 - anything that is not an array
            raise ValueError(f"actions must be a ({self.n_scenes}, {self._controls}) array of numbers, "
                             f"got {type(actions).__name__}") from None
        if a.shape != (self.n_scenes, self._controls):
            raise ValueError(f"actions must be a ({self.n_scenes}, {self._controls}) array, got shape {a.shape}")
        if a.dtype.kind not in "iuf":
            raise ValueError(f"actions must be numbers, got dtype {a.dtype}")
        a = np.asarray(a, dtype=np.float64)
        bad = ~np.isfinite(a)
        if bad.any():
            s, c = (int(x) for x in np.argwhere(bad)[0])
            raise ValueError(f"actions[{s}, {c}] ({CONTROL_COLUMNS[c]}) must be finite, got {actions[s][c]!r}")
        # the bounds Simulation.set_control takes (one table for every entry point)
        bounds = np.array([_kinds.CONTROL_BOUNDS[c.rsplit("_", 1)[0]][0] for c in CONTROL_COLUMNS])
        out = np.abs(a) > bounds
        if out.any():
            s, c = (int(x) for x in np.argwhere(out)[0])
            name = CONTROL_COLUMNS[c].rsplit("_", 1)[0]
            raise ValueError(f"actions[{s}, {c}] ({CONTROL_COLUMNS[c]}) must be in [{-bounds[c]:g}, {bounds[c]:g}] "
                             f"{_kinds.CONTROL_BOUNDS[name][1]}, got {a[s, c]:g}")
        return np.ascontiguousarray(a, dtype=np.float32)

    def reset(self, mask=None, randomize: bool | None = None) -> np.ndarray:
        """Restore the chosen scenes (a boolean mask of length B, or scene indices; None:
        every scene) to the settled start, clock at zero; the others go on untouched.
        ``randomize`` (default: the batch's) turns each restored scene by a random
        symmetry (see the module). Returns the indices restored."""
        ids = self._mask(mask)
        rand = self.randomize if randomize is None else bool(randomize)
        k = ids.shape[0]
        turn = np.tile(np.array([1.0, 0.0, 0.0, 0.0]), (k, 1))
        sym = turn.copy()
        if rand and k:
            angle = self._rng.uniform(0.0, 2.0 * np.pi, k)
            axis = self._gravity_axis[ids]
            turn = np.concatenate([np.cos(angle / 2)[:, None], np.sin(angle / 2)[:, None] * axis], axis=1)
            no_axis = np.linalg.norm(axis, axis=1) == 0.0  # no gravity: any rotation is a symmetry
            if no_axis.any():
                turn[no_axis] = _random_quaternions(self._rng, int(no_axis.sum()))
            sym = self._sym[self._rng.integers(0, len(self._sym), k)]
        self.core.restore_scenes(np.ascontiguousarray(ids, dtype=np.int32), np.ascontiguousarray(turn, np.float32),
                                 np.ascontiguousarray(sym, np.float32))
        return ids

    def _mask(self, mask) -> np.ndarray:
        if mask is None:
            return np.arange(self.n_scenes, dtype=np.int32)
        if hasattr(mask, "__dlpack__") and not isinstance(mask, np.ndarray) and hasattr(mask, "cpu"):
            mask = mask.cpu().numpy() if hasattr(mask, "numpy") else mask.cpu()
        m = np.asarray(mask)
        if m.dtype == bool:
            if m.shape != (self.n_scenes,):
                raise ValueError(f"mask must be {self.n_scenes} booleans (one per scene), got shape {m.shape}")
            return np.flatnonzero(m).astype(np.int32)
        if m.dtype.kind in "iu" and m.ndim == 1:
            if m.size and (m.min() < 0 or m.max() >= self.n_scenes):
                raise ValueError(f"mask: scene indices must be in 0..{self.n_scenes - 1}")
            if np.unique(m).size != m.size:
                raise ValueError("mask: scene indices must be distinct")
            return m.astype(np.int32)
        raise ValueError(f"mask must be {self.n_scenes} booleans or scene indices, got dtype {m.dtype} shape {m.shape}")

    # reading --------------------------------------------------------------------------
    def observations(self, like: str | None = None) -> dict[str, Any]:
        """Per-scene arrays: ``die_position`` (B, 3), ``die_orientation`` (B, 4; w, x, y, z),
        ``die_velocity`` (B, 3), ``die_angular_velocity`` (B, 3; container frame, rad/s),
        ``answer_face`` (B,; 1..6, the face toward the window +z), ``time`` (B,; float64),
        ``done`` and ``bad`` (B,; the clock's flags). One small kernel writes them into
        buffers of their own, handed out without copies (valid until the next call):
        NumPy on the CPU; on CUDA, arrays exposing ``__dlpack__``. ``like`` converts:
        ``"torch"``, ``"cupy"``, ``"jax"`` (zero-copy through DLPack) or ``"numpy"`` (host
        copies of their own, on every backend)."""
        if like == "numpy":
            return dict(self.core.observe(True))
        obs = dict(self.core.observe())
        if like is None:
            return obs
        if like == "torch":
            import torch
            return {k: torch.from_dlpack(v) for k, v in obs.items()}
        if like == "cupy":
            import cupy
            return {k: cupy.from_dlpack(v) for k, v in obs.items()}
        if like == "jax":
            import jax.dlpack
            return {k: jax.dlpack.from_dlpack(v) for k, v in obs.items()}
        raise ValueError(f"like must be None, 'numpy', 'torch', 'cupy' or 'jax', got {like!r}")

    def gather_observations(self, root: int | None = 0) -> dict[str, Any] | None:
        """Every rank's :meth:`observations` as host arrays of all ``n_total`` scenes in scene
        order: on ``root`` (None: on every rank; the others get None). Without a communicator:
        this batch's, as host copies."""
        obs = dict(self.core.observe(True))
        if self.comm is None:
            return obs
        parts = self.comm.allgather(obs) if root is None else self.comm.gather(obs, root=root)
        if parts is None:
            return None
        return {k: np.concatenate([p[k] for p in parts]) for k in obs}

    def scalars(self, scene: int) -> dict:
        """The core's scalars of one scene (its record and the derived values)."""
        return dict(self.core.scalars(int(scene)))

    def field(self, name: str, copy: bool = False):
        """A particle field of every scene, (B * slots, ...) in scene order (see
        :attr:`n_active`: scene s's particles are its first n_active[s] slots)."""
        return self.core.download(name) if copy else self.core.view(name)

    @property
    def n_particles(self) -> int:
        """Particles of all scenes (active slots)."""
        return int(self.n_active.sum())

    def bench_steps(self, k: int) -> float:
        """Seconds for k batched steps (the core's clock: CUDA events on the GPU)."""
        self.core.set_end_time(math.inf)
        return float(self.core.bench(_count("steps", k, minimum=1)))
