"""Bodies in the SPH box kinds (``[[bodies]]``, :mod:`corpuscle.geometry`): each body's
surface becomes dynamic boundary particles (DBC, as the tank's walls) on the fluid's lattice
(i + 1/2) dp, inside the body and as many layers deep as the kernel support; fluid is never
placed inside a body or within half a spacing of it. The body particles join the walls
(slots [n_fluid, n)).

A moving body (``motion = "velocity"`` or ``"table"``) is rigid: the core sets its particles
from its pose each step (cpp/include/corpuscle/scenes/sph/bodies.h), each particle keeping its
offset in the body's frame; its pose at t = 0 is where it is built (for a table, the table's
pose at t = 0, not ``position`` and ``rotation``).

A free body (``motion = "free"``, DualSPHysics's floating body) moves with the force and torque
of the fluid on its particles, gravity and the tank's contact (bodies.h): its reference point is
its centre of mass, its mass and inertia those of its shape at its ``density`` (or ``mass``:
geometry.mass_properties), its initial velocity and angular velocity the entry's ``velocity``
and ``angular_velocity``."""

from __future__ import annotations

from typing import Any, Callable

import math

import numpy as np

from .. import geometry
from . import core
from ..schema import CrossCheck, SceneError, _fmt_value

#: the most [[bodies]] entries of an SPH box scene
MAX_BODIES = 64
#: the motions the SPH box kinds support
MOTIONS = ("fixed", "velocity", "table", "free")
#: the most moving bodies of a scene (kMaxMovingBodies of scenes/sph/bodies.h)
MAX_MOVING = 16
#: body_motion's kind codes (bodies.h)
MOTION_CODES = {"velocity": 1, "table": 2, "free": 3}
#: the times a moving body is checked to stay in the tank at (besides its table's rows)
CHECK_SAMPLES = 401


def body_keys(dim: int):
    return geometry.body_keys(dim)


class Motion:
    """A moving body's prescribed motion as the core takes it (bodies.h): its kind code, the
    velocity motion's start, velocity and angular velocity (rad/s), or its table (float32 rows
    t, x, y, z, rx, ry, rz; degrees)."""

    def __init__(self, entry: dict[str, Any], dim: int, label: str):
        self.kind = MOTION_CODES[entry["motion"]]
        pad = [0.0] * (3 - dim)
        self.c0 = [float(x) for x in entry["position"]] + pad
        if dim == 3:
            self.a0 = [float(x) for x in entry["rotation"]]
            self.omega = [math.radians(float(x)) for x in entry["angular_velocity"]]
        else:
            self.a0 = [0.0, 0.0, float(entry["rotation"])]
            self.omega = [0.0, 0.0, math.radians(float(entry["angular_velocity"]))]
        self.velocity = [float(x) for x in entry["velocity"]] + pad
        if self.kind == MOTION_CODES["table"]:
            t = geometry.read_motion_table(entry["motion_file"], dim, f"{label}.motion_file")
            rows = np.zeros((len(t), 7))
            rows[:, 0] = t[:, 0]
            rows[:, 1:1 + dim] = t[:, 1:1 + dim]
            if dim == 3:
                rows[:, 4:7] = t[:, 4:7]
            else:
                rows[:, 6] = t[:, 3]
            self.table = np.ascontiguousarray(rows, dtype=np.float32)
            if np.any(np.diff(self.table[:, 0].astype(np.float64)) <= 0.0):
                raise SceneError(f"{label}.motion_file: {entry['motion_file']}: times closer than float32 "
                                 f"resolves (they must increase strictly)")
        else:
            self.table = np.zeros((0, 7), dtype=np.float32)

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(c, R, velocity, angular velocity) at time t (the core's, bodies.h, in double)."""
        p = np.asarray(core().sph_body_pose(self.kind, self.c0, self.a0, self.velocity, self.omega, self.table,
                                            float(t)), dtype=np.float64)
        return p[0:3], p[3:12].reshape(3, 3), p[12:15], p[15:18]

    def params(self, row0: int) -> list[float]:
        """This body's numbers of the core's body_motion (its table's rows from row0)."""
        return [float(self.kind), float(row0), float(len(self.table)), *self.c0, *self.a0, *self.velocity, *self.omega]

    def times(self, end_time: float) -> np.ndarray:
        """The times it is checked at in [0, end_time]: a regular sampling and its table's rows."""
        t = np.linspace(0.0, end_time, CHECK_SAMPLES)
        rows = self.table[:, 0].astype(np.float64)
        return np.union1d(t, rows[(rows > 0.0) & (rows < end_time)])


class FreeMotion(Motion):
    """A free body's start as the core takes it (bodies.h's free_body_start): its centre of
    mass, rotation (degrees), velocity and angular velocity (rad/s), and its mass and inertia
    tensor about the centre of mass in its own frame (2-D: Izz times the identity)."""

    def __init__(self, entry: dict[str, Any], dim: int, label: str, body):
        super().__init__({**entry, "motion": "velocity"}, dim, label)
        self.kind = MOTION_CODES["free"]
        volume = geometry.mass_properties(body, 1.0)["volume"]
        density = float(entry["density"]) if entry["density"] > 0.0 else float(entry["mass"]) / volume
        props = geometry.mass_properties(body, density)
        self.mass = float(props["mass"])
        self.c0 = [float(x) for x in props["center"]] + [0.0] * (3 - dim)
        if dim == 2:
            self.inertia = float(props["inertia"]) * np.eye(3)
        else:
            R0 = geometry.rotation_matrix(entry["rotation"])
            self.inertia = R0.T @ np.asarray(props["inertia"], dtype=np.float64) @ R0
        self.density = density

    def pose(self, t: float):
        """(c, R, velocity, angular velocity) at t = 0 (later poses are the run's: its record)."""
        p = np.asarray(core().sph_body_pose(MOTION_CODES["velocity"], self.c0, self.a0, self.velocity, self.omega,
                                            self.table, 0.0), dtype=np.float64)
        return p[0:3], p[3:12].reshape(3, 3), p[12:15], p[15:18]

    def free_params(self) -> list[float]:
        return [self.mass, *np.asarray(self.inertia, dtype=np.float64).ravel().tolist()]

    def times(self, end_time: float) -> np.ndarray:
        return np.zeros(1)


def _pose_body(b, c: np.ndarray, R: np.ndarray) -> None:
    """Place body b with its reference point at c and rotation R (3-D; 2-D: their first axes)."""
    D = b.dim
    if b.vertices is not None:  # a mesh: its file's vertices moved (make_body's placement)
        mesh = b.extra["mesh"]
        b.vertices = np.asarray(mesh.vertices, dtype=np.float64) @ R[:D, :D].T + c[:D]
    b.position = np.asarray(c[:D], dtype=np.float64)
    b.rotation = np.asarray(R[:D, :D], dtype=np.float64)


def posed_bodies(arrays: dict[str, list], dim: int) -> tuple[list, list]:
    """The bodies at their pose of t = 0 and their motions (None for a fixed body)."""
    bodies = geometry.make_bodies(arrays, dim)
    motions = []
    for k, (b, entry) in enumerate(zip(bodies, arrays.get("bodies", [])), start=1):
        if entry["motion"] == "fixed":
            motions.append(None)
            continue
        if entry["motion"] == "free":  # (placed where its entry puts it; its reference: the centre of mass)
            motions.append(FreeMotion(entry, dim, f"bodies[{k}]", b))
            continue
        m = Motion(entry, dim, f"bodies[{k}]")
        c, R, _, _ = m.pose(0.0)
        _pose_body(b, c, R)
        motions.append(m)
    return bodies, motions


def check_bodies(box: Callable[[dict[str, Any]], Any], dim: int) -> CrossCheck:
    """The [[bodies]] checks: each entry's keys (geometry.check_bodies), its mesh readable and
    closed, the body inside the tank (box(values): its inner size from the origin), a moving
    body there at every time of the run (its table's rows and CHECK_SAMPLES times), at most
    MAX_MOVING moving bodies, and no sliding lid beside them."""
    def check(values, arrays) -> None:
        entries = arrays.get("bodies", [])
        if not entries:
            return
        geometry.check_bodies(arrays, dim, motions=MOTIONS, open_allowed=True)
        size = np.asarray(box(values), dtype=np.float64)
        tol = 1e-9 * max(float(size.max()), 1.0)
        bodies, motions = posed_bodies(arrays, dim)
        moving = sum(m is not None for m in motions)
        if moving > MAX_MOVING:
            raise SceneError(f"bodies: {moving} moving bodies, at most {MAX_MOVING}")
        if moving and values.get("walls.moving"):
            raise SceneError(f"walls.moving = {_fmt_value(list(values['walls.moving']))} with moving bodies: a "
                             f"sliding lid and moving bodies in one scene are not supported")
        end = float(values["run.end_time"])
        for k, (b, m) in enumerate(zip(bodies, motions), start=1):
            lo, hi = b.bounds()
            if np.any(lo < -tol) or np.any(hi > size + tol):
                raise SceneError(f"bodies[{k}] ({b.name!r}) reaches outside the tank: its bounds "
                                 f"{_fmt_value(np.round(lo, 6).tolist())} .. {_fmt_value(np.round(hi, 6).tolist())} m, "
                                 f"the tank 0 .. {_fmt_value(size.tolist())} m (check bodies[{k}].position, size, "
                                 f"scale and units)")
            if m is None:
                continue
            c0, R0, _, _ = m.pose(0.0)
            local = (geometry.surface_mesh(b)[0] - c0[:dim]) @ R0[:dim, :dim]
            for t in m.times(end):
                c, R, _, _ = m.pose(t)
                w = local @ R[:dim, :dim].T + c[:dim]
                lo, hi = w.min(axis=0), w.max(axis=0)
                if np.any(lo < -tol) or np.any(hi > size + tol):
                    raise SceneError(f"bodies[{k}] ({b.name!r}) leaves the tank at t = {t:.6g} s (its bounds "
                                     f"{_fmt_value(np.round(lo, 6).tolist())} .. "
                                     f"{_fmt_value(np.round(hi, 6).tolist())} m, the tank 0 .. "
                                     f"{_fmt_value(size.tolist())} m): check bodies[{k}]'s motion")
    return check


def build_bodies(arrays: dict[str, list], dim: int, dp: float, layers: int,
                 fluid: np.ndarray) -> tuple[list, np.ndarray, np.ndarray, np.ndarray, list]:
    """(bodies, their boundary particles (n, dim), each particle's body index, the mask of
    the fluid points no body excludes, the bodies' motions (None: fixed)), the bodies at their
    pose of t = 0. Particles two bodies share (overlapping bodies) are kept once."""
    bodies, motions = posed_bodies(arrays, dim)
    if not bodies:
        return [], np.zeros((0, dim)), np.zeros(0, np.int32), np.ones(len(fluid), bool), []
    pts, owner = [], []
    for k, b in enumerate(bodies):
        p = geometry.sample_boundary(b, dp, layers)
        pts.append(p)
        owner.append(np.full(len(p), k, np.int32))
    pts = np.concatenate(pts)
    owner = np.concatenate(owner)
    # one particle per lattice cell: the first body's
    cells = np.rint(pts / dp - 0.5).astype(np.int64)
    _, first = np.unique(cells, axis=0, return_index=True)
    first = np.sort(first)
    keep = geometry.fluid_clear(bodies, fluid, dp, layers)
    return bodies, pts[first], owner[first], keep, motions


def moving_arrays(motions: list, owner: np.ndarray, body_pts: np.ndarray, n_wall: int,
                  dim: int) -> tuple[dict[str, Any], dict[str, np.ndarray], list[int]]:
    """The core's moving-body parameters (n_moving, body_motion) and arrays (wall_body: each
    wall particle's moving body or -1, wall_local: its offset in the body's frame at t = 0,
    body_table: the tables' rows), given the body particles (the last len(body_pts) of the
    n_wall walls) and their owners; and the moving bodies' body indices. Empty without any."""
    index = [k for k, m in enumerate(motions) if m is not None]
    if not index:
        return {}, {}, []
    wall_body = np.full(n_wall, -1.0, dtype=np.float32)
    local = np.zeros((n_wall, 3))
    first = n_wall - len(body_pts)
    numbers, tables, row0 = [], [], 0
    for j, k in enumerate(index):
        m = motions[k]
        sel = np.flatnonzero(owner == k)
        c, R, _, _ = m.pose(0.0)
        wall_body[first + sel] = float(j)
        p3 = np.zeros((len(sel), 3))
        p3[:, :dim] = body_pts[sel]
        local[first + sel] = (p3 - c) @ R  # R^T (x - c)
        numbers += m.params(row0)
        row0 += len(m.table)
        tables.append(m.table)
    arrays = {"wall_body": wall_body.reshape(-1, 1), "wall_local": np.ascontiguousarray(local, dtype=np.float32)}
    if row0:
        arrays["body_table"] = np.ascontiguousarray(np.concatenate(tables), dtype=np.float32)
    params = {"n_moving": len(index), "body_motion": numbers}
    if any(isinstance(motions[k], FreeMotion) for k in index):
        params["body_free"] = [x for k in index for x in
                               (motions[k].free_params() if isinstance(motions[k], FreeMotion) else [0.0] * 10)]
    return params, arrays, index


def contact_params(spacing: float, h: float, c0: float) -> list[float]:
    """The tank's contact on the free bodies' particles (bodies.h's tank_contact): from half a
    spacing off a wall's face (the body's surface at the face), an acceleration k pen - c v_n per
    particle with omega = c0 / h (k = omega^2, c = omega): the stiffness of the fluid's own
    pressure response over a support radius, resolved by the CFL step (omega dt <= 0.1 at
    timestep.cfl = 0.2), damped at half the critical rate of one particle."""
    w = c0 / h
    return [0.5 * spacing, w * w, w]


def header_obstacles(bodies: list, motions: list | None = None) -> list[dict[str, Any]]:
    """The bodies as the run header's obstacles (render, live and export draw them): an
    unrotated 3-D box as a box, a 2-D body as its outline polygon, any other 3-D body as its
    triangles (``type = "mesh"``: ``vertices``, ``faces``). A moving body (a 2-D polygon, a
    3-D body always as its triangles) adds ``pose``: the diagnostics of its pose in each frame
    (body_<name>_x, ...), its reference point and rotation at t = 0 (what its points are
    given at)."""
    out = []
    motions = motions or [None] * len(bodies)
    for b, m in zip(bodies, motions):
        v, f = geometry.surface_mesh(b)
        if b.dim == 2:
            ob = {"name": b.name, "type": "polygon", "points": np.round(v, 9).tolist()}
            if m is not None:
                c, R, _, _ = m.pose(0.0)
                ob["pose"] = {"diagnostic": f"body_{b.name}", "origin": c[:2].tolist(),
                              "rotation": R[:2, :2].tolist()}
            out.append(ob)
        elif m is not None:  # a moving 3-D body: its triangles at t = 0 and its pose
            c, R, _, _ = m.pose(0.0)
            out.append({"name": b.name, "type": "mesh", "vertices": np.round(v, 9).tolist(),
                        "faces": np.asarray(f, np.int64).tolist(),
                        "pose": {"diagnostic": f"body_{b.name}", "origin": c.tolist(), "rotation": R.tolist()}})
        elif b.shape == "box" and np.allclose(b.rotation, np.eye(3)):
            lo, hi = b.bounds()
            out.append({"name": b.name, "type": "box", "min": lo.tolist(), "max": hi.tolist()})
        else:
            out.append({"name": b.name, "type": "mesh", "vertices": np.round(v, 9).tolist(),
                        "faces": np.asarray(f, np.int64).tolist()})
    return out
