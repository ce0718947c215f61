"""Geometry for scenes: bodies from triangle meshes (STL, OBJ, PLY, read with trimesh) and
primitives (box, sphere, cylinder, plane; in 2-D box and circle), placed by units, scale,
position and rotation; the checks of a closed mesh; the ``[[bodies]]`` table's schema that
any kind reuses; mass, centre of mass and inertia from a density; signed distances, and the
lattice sampling of a body's surface as boundary particles. (It is longer than 600 lines: the
loader, its checks, the mass properties and the sampling all work on the one placed mesh type,
and a ``[[bodies]]`` entry's life from its keys to its particles reads in one place.)

Conventions (docs/geometry.md):

- **Placement.** A body's vertices are ``x_world = R (scale * units * x_file) + position``:
  the file's (or primitive's) own origin goes to ``position``. Primitives are centred on
  their origin; a cylinder's axis and a plane's normal are the local +z.
- **Rotation.** ``rotation = [rx, ry, rz]`` in degrees, turns about the fixed (world) x, y
  and z axes in that order: ``R = Rz(rz) Ry(ry) Rx(rx)`` (DualSPHysics's and ParaView's
  order). In 2-D it is one angle, counter-clockwise.
- **Signed distance** is positive outside a body, negative inside. An open mesh (a thin
  wall, ``open = true``) has an inside only behind its faces: the side their normals do not
  point to.

trimesh is an optional dependency (the ``mesh`` extra: ``pip install corpuscle[mesh]``);
primitives need only NumPy. Every error is a :class:`~corpuscle.schema.SceneError` with one
line naming the key (``bodies[1].file``) or the file and the fault.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .schema import KeySpec, SceneError, _fmt_value

__all__ = ["UNITS", "SHAPES", "MOTIONS", "MESH_FILE_BYTES", "body_keys", "check_bodies", "Body", "make_body",
           "make_bodies", "load_mesh", "check_closed_mesh", "rotation_matrix", "signed_distance",
           "sample_boundary", "mass_properties", "surface_mesh"]

#: length units a body's file or primitive may be given in, and their size in metres
UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "in": 0.0254}
#: the shapes a body may have, per dimension
SHAPES = {3: ("mesh", "box", "sphere", "cylinder", "plane"), 2: ("box", "circle", "cylinder")}
#: how a body moves: fixed; a constant velocity and angular velocity; a table of poses over
#: time (``motion_file``); free (a rigid body moved by the fluid and gravity)
MOTIONS = ("fixed", "velocity", "table", "free")
#: a mesh file holds at most this many bytes (a binary STL of 10 M triangles is ~500 MB)
MESH_FILE_BYTES = 512 << 20
#: a mesh holds at most this many triangles (the distance queries are brute force)
MESH_MAX_FACES = 200_000
#: a motion table holds at most this many rows
MOTION_MAX_ROWS = 100_000

_K = KeySpec


def body_keys(dim: int) -> dict[str, KeySpec]:
    """The keys of one ``[[bodies]]`` entry (any kind with bodies registers these as its
    ``bodies`` array; a kind refuses the shapes or motions it does not support in a check)."""
    vec = f"vec{dim}"
    keys = {
        "name": _K("str", "", "", doc="the body's name (letters, digits, _ and -); default body<i>"),
        "shape": _K("enum", "box", "", doc="mesh (3-D: file), box, sphere, cylinder, plane (3-D: a thin wall); "
                    "2-D: box, circle (or cylinder: its cross-section)", choices=SHAPES[dim] if dim == 2 else SHAPES[3]),
        "file": _K("path", "", "", doc="shape = mesh: an STL, OBJ or PLY file (relative to the scene file)"),
        "units": _K("enum", "m", "", doc="the length unit of the file and of size, radius, height: m, cm, mm or in",
                    choices=tuple(UNITS)),
        "scale": _K("float", 1.0, "", 0.0, 1e6, "a factor on the file's or primitive's size", lo_open=True),
        "size": _K(vec, [0.0] * dim, "units", 0.0, 1e6,
                   "box: its edge lengths; plane: its lengths along local x and y (the third is unused)"),
        "radius": _K("float", 0.0, "units", 0.0, 1e6, "sphere, cylinder, circle: the radius"),
        "height": _K("float", 0.0, "units", 0.0, 1e6, "cylinder (3-D): its length along its local z axis"),
        "position": _K(vec, [0.0] * dim, "m", -1e6, 1e6, "where the shape's own origin goes (a primitive's centre)"),
        "rotation": (_K("vec3", [0.0, 0.0, 0.0], "deg", -1e6, 1e6,
                        "turns about the fixed x, y, z axes, in that order (R = Rz Ry Rx)") if dim == 3 else
                     _K("float", 0.0, "deg", -1e6, 1e6, "a counter-clockwise turn about the shape's origin")),
        "open": _K("bool", False, "", doc="shape = mesh: accept an open mesh as a thin wall (its inside is behind "
                   "its faces)"),
        "density": _K("float", 0.0, "kg/m^3", 0.0, 1e7,
                      "the body's density (its mass and inertia; motion = free needs it or mass)"),
        "mass": _K("float", 0.0, "kg", 0.0, 1e12,
                   "motion = free: the body's mass instead of density (2-D: per metre of depth)"),
        "motion": _K("enum", "fixed", "", doc="fixed, velocity (velocity and angular_velocity), table (motion_file) "
                     "or free (moved by the fluid and gravity)", choices=MOTIONS),
        "velocity": _K(vec, [0.0] * dim, "m/s", -1e4, 1e4, "motion = velocity: the constant velocity (free: the initial one)"),
        "angular_velocity": (_K("vec3", [0.0, 0.0, 0.0], "deg/s", -1e6, 1e6,
                                "motion = velocity: turns per second about the fixed axes, through position "
                                "(free: the initial rate)")
                             if dim == 3 else
                             _K("float", 0.0, "deg/s", -1e6, 1e6,
                                "motion = velocity: counter-clockwise turn rate (free: the initial one)")),
        "motion_file": _K("path", "", "", doc="motion = table: a CSV of rows t, x, y[, z], angle(s) in degrees "
                          "(the body's position and rotation at time t), interpolated linearly"),
    }
    return keys


def _check_name(k: int, b: dict, seen: set, array: str) -> None:
    name = b["name"]
    if name and not all(c.isalnum() or c in "_-" for c in name):
        raise SceneError(f"{array}[{k}].name must be letters, digits, _ and -, got {_fmt_value(name)}")
    name = name or f"body{k}"
    if name in seen:
        raise SceneError(f"{array}[{k}].name = {_fmt_value(name)} is used twice")
    seen.add(name)


def check_bodies(arrays: dict[str, list[dict[str, Any]]], dim: int, *, array: str = "bodies",
                 motions: Sequence[str] = MOTIONS, open_allowed: bool = True) -> None:
    """The checks of each ``[[bodies]]`` entry that a key alone cannot make: the keys its
    shape needs, the motion's. ``motions`` are those the kind supports; ``open_allowed``:
    whether the kind takes thin walls. Entries are numbered from 1 (as the scene's errors)."""
    seen: set = set()
    for k, b in enumerate(arrays.get(array, []), start=1):
        where = f"{array}[{k}]"
        _check_name(k, b, seen, array)
        shape = b["shape"]
        if shape == "mesh" and not b["file"]:
            raise SceneError(f"{where}.file is missing (shape = \"mesh\" reads its triangles from a file)")
        if shape != "mesh" and b["file"]:
            raise SceneError(f"{where}.file = {_fmt_value(b['file'])} is only read for shape = \"mesh\", "
                             f"got shape = {_fmt_value(shape)}")
        if shape == "box" and min(b["size"]) <= 0.0:
            raise SceneError(f"{where}.size must be {dim} positive lengths for a box, got {_fmt_value(b['size'])}")
        if shape == "plane" and min(b["size"][:2]) <= 0.0:
            raise SceneError(f"{where}.size must have positive x and y lengths for a plane, "
                             f"got {_fmt_value(b['size'])}")
        if shape in ("sphere", "cylinder", "circle") and b["radius"] <= 0.0:
            raise SceneError(f"{where}.radius must be > 0 for a {shape}, got {_fmt_value(b['radius'])}")
        if shape == "cylinder" and dim == 3 and b["height"] <= 0.0:
            raise SceneError(f"{where}.height must be > 0 for a cylinder, got {_fmt_value(b['height'])}")
        if b["open"] and shape != "mesh":
            raise SceneError(f"{where}.open = true is for shape = \"mesh\" (a plane is a thin wall already), "
                             f"got shape = {_fmt_value(shape)}")
        if b["open"] and not open_allowed:
            raise SceneError(f"{where}.open = true: this kind takes closed bodies only (an open mesh has no inside)")
        if shape == "plane" and not open_allowed:
            raise SceneError(f"{where}.shape = \"plane\": this kind takes closed bodies only (a plane has no inside)")
        motion = b["motion"]
        if motion not in motions:
            raise SceneError(f"{where}.motion = {_fmt_value(motion)} is not supported by this kind "
                             f"(it takes {', '.join(json_str(m) for m in motions)})")
        if motion == "table" and not b["motion_file"]:
            raise SceneError(f"{where}.motion_file is missing (motion = \"table\" reads its poses from a CSV file)")
        if motion != "table" and b["motion_file"]:
            raise SceneError(f"{where}.motion_file is only read for motion = \"table\", got motion = "
                             f"{_fmt_value(motion)}")
        if b["mass"] > 0.0 and motion != "free":
            raise SceneError(f"{where}.mass = {_fmt_value(b['mass'])} is only read for motion = \"free\", got "
                             f"motion = {_fmt_value(motion)}")
        if motion == "free":
            if b["mass"] > 0.0 and b["density"] > 0.0:
                raise SceneError(f"{where}.mass = {_fmt_value(b['mass'])} and density = {_fmt_value(b['density'])}: "
                                 f"give one of them for motion = \"free\"")
            if b["density"] <= 0.0 and b["mass"] <= 0.0:
                raise SceneError(f"{where}.density must be > 0 for motion = \"free\" (its mass and inertia; or give "
                                 f"mass), got {_fmt_value(b['density'])}")
            if shape == "plane" or b["open"]:
                raise SceneError(f"{where}.motion = \"free\" needs a closed body (an open one has no mass), "
                                 f"got shape = {_fmt_value(shape)}{', open = true' if b['open'] else ''}")


def json_str(s: str) -> str:
    return '"' + s + '"'


# ---------------------------------------------------------------------------------------------
# rotations and placement
# ---------------------------------------------------------------------------------------------


def rotation_matrix(rotation) -> np.ndarray:
    """The rotation matrix of ``rotation``: three angles in degrees about the fixed x, y, z
    axes in that order (R = Rz Ry Rx; 3x3), or one counter-clockwise angle in 2-D (2x2)."""
    r = np.atleast_1d(np.asarray(rotation, dtype=np.float64))
    if r.size == 1:
        a = math.radians(float(r[0]))
        return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    ax, ay, az = (math.radians(float(x)) for x in r)
    cx, sx, cy, sy, cz, sz = math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay), math.cos(az), math.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


# ---------------------------------------------------------------------------------------------
# meshes
# ---------------------------------------------------------------------------------------------


def _trimesh(label: str):
    try:
        import trimesh
    except ImportError:
        raise SceneError(f"{label}: reading a mesh needs trimesh (pip install 'corpuscle[mesh]')") from None
    return trimesh


def load_mesh(path: str | os.PathLike, *, units: str = "m", scale: float = 1.0, closed: bool = True,
              label: str | None = None):
    """The mesh of an STL, OBJ or PLY file as a ``trimesh.Trimesh``, its vertices in metres
    (times ``scale``); checked closed (:func:`check_closed_mesh`) unless ``closed`` is false
    (a thin wall, which must still be non-degenerate). ``label`` prefixes errors (default:
    the file)."""
    from ._files import FileTooLarge, read_bounded
    path = os.fspath(path)
    label = label or path
    ext = os.path.splitext(path)[1].lower().lstrip(".")
    if ext not in ("stl", "obj", "ply"):
        raise SceneError(f"{label}: {path} is not an STL, OBJ or PLY file (by its extension {ext!r})")
    trimesh = _trimesh(label)
    try:
        data = read_bounded(path, MESH_FILE_BYTES, "a mesh file")
    except FileTooLarge as e:
        raise SceneError(f"{label}: {e}") from None
    except OSError as e:
        raise SceneError(f"{label}: cannot read {path}: {e.strerror or e}") from None
    import io
    import logging
    logging.getLogger("trimesh").setLevel(logging.ERROR)
    try:
        loaded = trimesh.load(io.BytesIO(data), file_type=ext, process=False, force="mesh")
    except Exception as e:  # trimesh's parsers raise many kinds on a bad file
        raise SceneError(f"{label}: {path} is not a readable {ext.upper()} mesh ({type(e).__name__}: "
                         f"{str(e).splitlines()[0] if str(e) else 'no detail'})") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise SceneError(f"{label}: {path} holds no triangles")
    if len(loaded.faces) > MESH_MAX_FACES:
        raise SceneError(f"{label}: {path} has {len(loaded.faces):,} triangles, at most {MESH_MAX_FACES:,} "
                         f"(decimate it)")
    v = np.asarray(loaded.vertices, dtype=np.float64)
    if not np.all(np.isfinite(v)):
        raise SceneError(f"{label}: {path} has vertices that are not finite numbers")
    # merge duplicated vertices (an STL repeats them per triangle) before checking the topology
    mesh = trimesh.Trimesh(vertices=v * (UNITS[units] * float(scale)), faces=np.asarray(loaded.faces), process=True,
                           validate=False)
    check_closed_mesh(mesh, label=f"{label}: {path}", closed=closed)
    return mesh


def check_closed_mesh(mesh, *, label: str, closed: bool = True) -> None:
    """A mesh a body can be made of: no degenerate (zero-area) triangles; if ``closed``,
    watertight, consistently wound and with its normals outward (a positive volume). Raises
    SceneError naming ``label`` and the first fault."""
    faces = np.asarray(mesh.faces)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    tri = v[faces]
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    edge = max(float(np.ptp(v, axis=0).max()), 1e-300)
    bad = np.flatnonzero(area2 <= 1e-12 * edge * edge)
    if bad.size:
        raise SceneError(f"{label}: triangle {int(bad[0])} (of {len(faces)}) is degenerate (zero area; "
                         f"{bad.size} such)")
    if not closed:
        return
    if not mesh.is_watertight:
        # an edge that belongs to other than two triangles: a hole or a non-manifold edge
        edges = np.sort(np.asarray(mesh.edges), axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        holes, extra = int(np.sum(counts == 1)), int(np.sum(counts > 2))
        what = (f"{holes} edges belong to one triangle only (a hole)" if holes else
                f"{extra} edges belong to more than two triangles (not a manifold)")
        raise SceneError(f"{label}: the mesh is not watertight: {what}; set open = true for a thin wall")
    if not mesh.is_winding_consistent:
        raise SceneError(f"{label}: the triangles' windings are inconsistent (some normals point in, some out)")
    vol = float(mesh.volume)
    if not vol > 0.0:
        raise SceneError(f"{label}: the normals point inward (the enclosed volume is {vol:.3g} m^3, negative); "
                         f"flip the triangles' winding")


# ---------------------------------------------------------------------------------------------
# bodies
# ---------------------------------------------------------------------------------------------


@dataclass
class Body:
    """A placed body: its entry's values, its rotation and position, and (3-D) its
    triangles in world coordinates. ``closed``: it has an inside (a thin wall has not)."""

    name: str
    shape: str
    dim: int
    position: np.ndarray
    rotation: np.ndarray  # the matrix
    entry: dict[str, Any]
    closed: bool = True
    length: float = 1.0  # units * scale: metres per unit of size, radius, height
    vertices: np.ndarray | None = None  # (3-D) world vertices of the surface mesh
    faces: np.ndarray | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def half(self) -> np.ndarray:
        """A box's (a plane's) half edge lengths in metres."""
        return 0.5 * np.asarray(self.entry["size"], dtype=np.float64) * self.length

    @property
    def radius(self) -> float:
        return float(self.entry["radius"]) * self.length

    @property
    def height(self) -> float:
        return float(self.entry["height"]) * self.length

    def to_local(self, points) -> np.ndarray:
        """World points in the body's own frame (its origin at 0, unrotated)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, self.dim)
        return (p - self.position) @ self.rotation

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The world-axis-aligned bounds of the body's surface (lo, hi)."""
        v = surface_mesh(self)[0]
        return v.min(axis=0), v.max(axis=0)


def make_body(entry: dict[str, Any], k: int, dim: int, *, array: str = "bodies") -> Body:
    """The body of a checked ``[[bodies]]`` entry (``k``: its number from 1)."""
    length = UNITS[entry["units"]] * float(entry["scale"])
    rot = rotation_matrix(entry["rotation"])
    body = Body(name=entry["name"] or f"body{k}", shape=entry["shape"], dim=dim,
                position=np.asarray(entry["position"], dtype=np.float64), rotation=rot, entry=entry,
                closed=not (entry["open"] or entry["shape"] == "plane"), length=length)
    if entry["shape"] == "mesh":
        mesh = load_mesh(entry["file"], units=entry["units"], scale=float(entry["scale"]), closed=body.closed,
                         label=f"{array}[{k}].file")
        body.extra["mesh"] = mesh  # in the file's frame, metres
        body.vertices = np.asarray(mesh.vertices, dtype=np.float64) @ rot.T + body.position
        body.faces = np.asarray(mesh.faces, dtype=np.int64)
    return body


def make_bodies(arrays: dict[str, list[dict[str, Any]]], dim: int, *, array: str = "bodies") -> list[Body]:
    return [make_body(b, k, dim, array=array) for k, b in enumerate(arrays.get(array, []), start=1)]


def surface_mesh(body: Body, segments: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """The body's surface as world vertices and faces: triangles (3-D; a sphere or cylinder
    with ``segments`` around) or, in 2-D, the outline polygon's vertices and its edges."""
    if body.vertices is not None:
        return body.vertices, body.faces
    shape = body.shape
    if body.dim == 2:
        if shape == "box":
            h = body.half
            local = np.array([[-h[0], -h[1]], [h[0], -h[1]], [h[0], h[1]], [-h[0], h[1]]])
        else:
            a = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
            local = body.radius * np.column_stack([np.cos(a), np.sin(a)])
        n = len(local)
        edges = np.column_stack([np.arange(n), (np.arange(n) + 1) % n])
        return local @ body.rotation.T + body.position, edges
    if shape == "box":
        h = body.half
        local = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float) * h
        faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                          [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    elif shape == "plane":
        h = body.half
        local = np.array([[-h[0], -h[1], 0], [h[0], -h[1], 0], [h[0], h[1], 0], [-h[0], h[1], 0]], float)
        faces = np.array([[0, 1, 2], [0, 2, 3]])
    elif shape == "sphere":
        nlat, nlon = max(segments // 2, 4), segments
        th = np.linspace(0.0, math.pi, nlat + 1)[1:-1]
        ph = np.linspace(0.0, 2 * math.pi, nlon, endpoint=False)
        ring = np.stack([np.outer(np.sin(th), np.cos(ph)), np.outer(np.sin(th), np.sin(ph)),
                         np.repeat(np.cos(th)[:, None], nlon, axis=1)], axis=-1).reshape(-1, 3)
        local = np.vstack([[0, 0, 1], ring, [0, 0, -1]]) * body.radius
        f = []
        for j in range(nlon):
            j1 = (j + 1) % nlon
            f.append([0, 1 + j, 1 + j1])
            for i in range(nlat - 2):
                a, b = 1 + i * nlon + j, 1 + i * nlon + j1
                f += [[a, a + nlon, b], [b, a + nlon, b + nlon]]
            last = 1 + (nlat - 2) * nlon
            f.append([last + j, len(local) - 1, last + j1])
        faces = np.array(f)
    else:  # cylinder along local z
        a = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
        r, hz = body.radius, 0.5 * body.height
        ring = np.column_stack([r * np.cos(a), r * np.sin(a)])
        local = np.vstack([np.column_stack([ring, -hz * np.ones(segments)]),
                           np.column_stack([ring, hz * np.ones(segments)]), [[0, 0, -hz], [0, 0, hz]]])
        f = []
        for j in range(segments):
            j1 = (j + 1) % segments
            f += [[j, j1, segments + j1], [j, segments + j1, segments + j],
                  [2 * segments, j1, j], [2 * segments + 1, segments + j, segments + j1]]
        faces = np.array(f)
    return local @ body.rotation.T + body.position, faces.astype(np.int64)


def mass_properties(body: Body, density: float | None = None) -> dict[str, Any]:
    """Mass (kg; per metre of depth in 2-D), centre of mass (world, m) and inertia tensor
    about the centre of mass in world axes (kg m^2; 2-D: the scalar about the out-of-plane
    axis) of a closed body of ``density`` (default its entry's). Primitives in closed form, a
    mesh by trimesh's mass properties."""
    rho = float(body.entry["density"] if density is None else density)
    if not body.closed:
        raise SceneError(f"body {body.name!r}: an open body (a thin wall) has no volume, hence no mass")
    if body.dim == 2:
        if body.shape == "box":
            w, h = 2 * body.half
            area = w * h
            inertia = rho * area * (w * w + h * h) / 12.0
        else:
            area = math.pi * body.radius ** 2
            inertia = 0.5 * rho * area * body.radius ** 2
        return {"mass": rho * area, "volume": area, "center": body.position.copy(), "inertia": float(inertia)}
    if body.shape == "mesh":
        mesh = body.extra["mesh"]
        vol = float(mesh.volume)
        com_local = np.asarray(mesh.center_mass, dtype=np.float64)
        # trimesh's inertia about the centre of mass for unit density, in the file's axes
        i_local = np.asarray(mesh.moment_inertia, dtype=np.float64) * (rho / float(mesh.density))
    else:
        if body.shape == "box":
            a, b, c = 2 * body.half
            vol = a * b * c
            i_local = rho * vol / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
        elif body.shape == "sphere":
            r = body.radius
            vol = 4.0 / 3.0 * math.pi * r ** 3
            i_local = 0.4 * rho * vol * r * r * np.eye(3)
        else:  # cylinder along z
            r, h = body.radius, body.height
            vol = math.pi * r * r * h
            m = rho * vol
            i_local = np.diag([m * (3 * r * r + h * h) / 12.0, m * (3 * r * r + h * h) / 12.0, 0.5 * m * r * r])
        com_local = np.zeros(3)
    R = body.rotation
    return {"mass": rho * vol, "volume": vol, "center": R @ com_local + body.position, "inertia": R @ i_local @ R.T}


# ---------------------------------------------------------------------------------------------
# signed distance
# ---------------------------------------------------------------------------------------------


def _sd_box(q: np.ndarray, h: np.ndarray) -> np.ndarray:
    d = np.abs(q) - h
    outside = np.linalg.norm(np.maximum(d, 0.0), axis=1)
    inside = np.minimum(d.max(axis=1), 0.0)
    return outside + inside


def _closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Closest points on triangles (a, b, c) to points p, all broadcast to (..., 3)
    (Ericson, Real-Time Collision Detection, 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("...i,...i", ab, ap), np.einsum("...i,...i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("...i,...i", ab, bp), np.einsum("...i,...i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("...i,...i", ab, cp), np.einsum("...i,...i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_in, w_in = vb / denom, vc / denom
        res = a + v_in[..., None] * ab + w_in[..., None] * ac
        # edges
        t_ab = d1 / (d1 - d3)
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        res = np.where(m[..., None], a + t_ab[..., None] * ab, res)
        t_ac = d2 / (d2 - d6)
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        res = np.where(m[..., None], a + t_ac[..., None] * ac, res)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        res = np.where(m[..., None], b + t_bc[..., None] * (c - b), res)
    # vertices
    res = np.where(((d6 >= 0) & (d5 <= d6))[..., None], c, res)
    res = np.where(((d3 >= 0) & (d4 <= d3))[..., None], b, res)
    res = np.where(((d1 <= 0) & (d2 <= 0))[..., None], a, res)
    return res


def _sd_mesh(p: np.ndarray, v: np.ndarray, f: np.ndarray, closed: bool) -> np.ndarray:
    """Signed distance to a triangle mesh (brute force, in chunks): the distance to the
    nearest triangle; the sign from the generalised winding number (closed; Jacobson et al.
    2013) or, open, from the side of the nearest triangle's plane: behind it is inside unless
    the nearest point lies on the mesh's open boundary (a thin wall's layers do not wrap
    round its edges)."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    normal = np.cross(b - a, c - a)
    if not closed:
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        ue, cnt = np.unique(e, axis=0, return_counts=True)
        rim = ue[cnt == 1]  # the edges of one triangle only
        r0, r1 = v[rim[:, 0]], v[rim[:, 1]]
    out = np.empty(len(p))
    chunk = max(1, 2_000_000 // max(len(f), 1))
    for s in range(0, len(p), chunk):
        q = p[s:s + chunk, None, :]
        cp = _closest_on_triangles(q, a[None], b[None], c[None])
        d2 = np.einsum("...i,...i", q - cp, q - cp)
        near = np.argmin(d2, axis=1)
        dist = np.sqrt(d2[np.arange(len(near)), near])
        if closed:
            # solid angle of each triangle seen from q (Van Oosterom & Strackee 1983)
            ra, rb, rc = a[None] - q, b[None] - q, c[None] - q
            la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (ra, rb, rc))
            num = np.einsum("...i,...i", ra, np.cross(rb, rc))
            den = (la * lb * lc + np.einsum("...i,...i", ra, rb) * lc + np.einsum("...i,...i", rb, rc) * la
                   + np.einsum("...i,...i", rc, ra) * lb)
            wind = np.arctan2(num, den).sum(axis=1) / (2 * math.pi)
            inside = wind > 0.5
        else:
            qn = q[:, 0, :] - cp[np.arange(len(near)), near]
            inside = np.einsum("ij,ij->i", qn, normal[near]) < 0.0
            if len(rim):
                # the distance to the open boundary's edges: as near as the surface's, the
                # nearest point is on the boundary
                t = np.einsum("nki,ki->nk", q - r0[None], r1 - r0) / np.maximum(np.einsum("ki,ki->k", r1 - r0, r1 - r0), 1e-300)
                ps = r0[None] + np.clip(t, 0.0, 1.0)[..., None] * (r1 - r0)[None]
                drim = np.sqrt(np.min(np.einsum("nki,nki->nk", q - ps, q - ps), axis=1))
                inside &= drim > dist * (1.0 + 1e-9) + 1e-12 * (1.0 + dist)
        out[s:s + chunk] = np.where(inside, -dist, dist)
    return out


def signed_distance(body: Body, points) -> np.ndarray:
    """Signed distance (m) of world points to the body's surface: > 0 outside, < 0 inside
    (an open body: behind its faces). Exact for primitives; for a mesh the distance to its
    nearest triangle."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, body.dim)
    if body.shape == "mesh":
        return _sd_mesh(p, body.vertices, body.faces, body.closed)
    q = body.to_local(p)
    if body.shape == "box":
        return _sd_box(q, body.half)
    if body.shape in ("sphere", "circle") or (body.shape == "cylinder" and body.dim == 2):
        return np.linalg.norm(q, axis=1) - body.radius
    if body.shape == "cylinder":
        d = np.column_stack([np.linalg.norm(q[:, :2], axis=1) - body.radius, np.abs(q[:, 2]) - 0.5 * body.height])
        return np.linalg.norm(np.maximum(d, 0.0), axis=1) + np.minimum(d.max(axis=1), 0.0)
    # plane: a rectangle in local z = 0, its inside behind it (local z < 0) and within its
    # edges (a thin wall's layers do not wrap round them)
    h = body.half
    dxy = np.maximum(np.abs(q[:, :2]) - h[:2], 0.0)
    dist = np.sqrt(np.sum(dxy ** 2, axis=1) + q[:, 2] ** 2)
    return np.where((q[:, 2] < 0.0) & np.all(dxy == 0.0, axis=1), -dist, dist)


# ---------------------------------------------------------------------------------------------
# boundary particles
# ---------------------------------------------------------------------------------------------


def _where_sd(body: Body, pts: np.ndarray, pred, a: float, b: float, block: float) -> np.ndarray:
    """pred(signed distance) for each point, where pred is false outside [a, b] and true
    strictly inside it: points are binned in cubes of edge ``block``, the exact distance is
    taken at each cube's centre, and only points whose cube's range of distances (the centre's
    plus or minus the half diagonal: the distance changes no faster than the position) meets
    a or b get their own (a closed body's signed distance is 1-Lipschitz)."""
    out = np.zeros(len(pts), dtype=bool)
    if len(pts) == 0:
        return out
    if not body.closed:
        # an open body's signed distance jumps across its plane beyond its edges: every point
        return pred(signed_distance(body, pts))
    base = pts.min(axis=0)
    idx = np.floor((pts - base) / block).astype(np.int64)
    cubes, inverse = np.unique(idx, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    sd_c = signed_distance(body, base + (cubes + 0.5) * block)
    r = 0.5 * block * math.sqrt(body.dim) * (1.0 + 1e-9)
    sure = (sd_c - r > a) & (sd_c + r < b)
    maybe = ~sure & (sd_c + r >= a) & (sd_c - r <= b)
    out[sure[inverse]] = True
    m = np.flatnonzero(maybe[inverse])
    if m.size:
        out[m] = pred(signed_distance(body, pts[m]))
    return out


def sample_boundary(body: Body, dp: float, layers: int, *, offset=None) -> np.ndarray:
    """A body's boundary particles: the points of the lattice (i + 1/2) dp + offset inside
    the body (signed distance <= 0) and within ``layers`` spacings of its surface (the
    kernel support's depth), float64 (n, dim). An open body (a thin wall) gets its layers
    behind its faces."""
    D = body.dim
    off = np.zeros(D) if offset is None else np.asarray(offset, dtype=np.float64)
    lo, hi = body.bounds()
    c0 = np.floor((lo - off) / dp - 0.5).astype(np.int64) - 1
    c1 = np.ceil((hi - off) / dp - 0.5).astype(np.int64) + 2
    if not body.closed:  # the layers may reach past the faces' bounds
        c0 -= layers
        c1 += layers
    cells = np.prod((c1 - c0).astype(np.float64))
    if cells > 5e8:
        raise SceneError(f"body {body.name!r}: {cells:.3g} lattice cells in its bounds at spacing {dp:.3g} m "
                         f"(too many: a coarser spacing or a smaller body)")
    axes = [(np.arange(a, b) + 0.5) * dp + o for a, b, o in zip(c0, c1, off)]
    band = layers * dp
    out = []
    # a few planes of the first axis at a time (bounded memory), distances in cubes of 4 dp
    for s in range(0, len(axes[0]), 4):
        grids = np.meshgrid(axes[0][s:s + 4], *axes[1:], indexing="ij")
        pts = np.column_stack([g.ravel() for g in grids])
        keep = _where_sd(body, pts, lambda sd: (sd <= 0.0) & (sd > -band), -band, 0.0, 4.0 * dp)
        out.append(pts[keep])
    return np.concatenate(out) if out else np.zeros((0, D))


def fluid_clear(bodies: Sequence[Body], points, dp: float, layers: int) -> np.ndarray:
    """A mask of the points no body excludes: True where a point lies outside every body
    by at least half a spacing (and, behind a thin wall, beyond its boundary layers)."""
    p = np.asarray(points, dtype=np.float64)
    keep = np.ones(len(p), dtype=bool)
    for b in bodies:
        lo, hi = b.bounds()
        margin = (layers + 1) * dp
        near = np.flatnonzero(np.all((p >= lo - margin) & (p <= hi + margin), axis=1))
        if near.size == 0:
            continue
        # (a point exactly half a spacing off a face, as the lattice puts it beside a face on a
        # cell boundary, is kept: the sign of the rounding would otherwise differ face to face)
        half = 0.5 * dp * (1.0 - 1e-9)
        if b.closed:
            blocked = _where_sd(b, p[near], lambda sd: sd < half, -math.inf, 0.5 * dp, 4.0 * dp)
        else:
            deep = (layers + 0.5) * dp
            blocked = _where_sd(b, p[near], lambda sd: (sd < half) & (sd > -deep), -deep, 0.5 * dp, 4.0 * dp)
        keep[near[blocked]] = False
    return keep


def read_motion_table(path: str, dim: int, label: str) -> np.ndarray:
    """A motion table (``motion_file``): rows of t, position (dim numbers), rotation (3
    angles in 3-D, 1 in 2-D; degrees), comma- or space-separated, ``#`` comments; times
    strictly increasing. Returns float64 (rows, 1 + dim + angles)."""
    from ._files import FileTooLarge, read_bounded
    cols = 1 + dim + (3 if dim == 3 else 1)
    try:
        text = read_bounded(path, 16 << 20, "a motion table").decode("utf-8", errors="replace")
    except (FileTooLarge, OSError) as e:
        raise SceneError(f"{label}: cannot read {path}: {getattr(e, 'strerror', None) or e}") from None
    rows = []
    for n, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.replace(",", " ").split()
        try:
            row = [float(x) for x in parts]
        except ValueError:
            if not rows:  # a header row
                continue
            raise SceneError(f"{label}: {path} line {n}: not numbers: {line[:60]!r}") from None
        if len(row) != cols or not all(math.isfinite(x) for x in row):
            raise SceneError(f"{label}: {path} line {n}: {cols} finite numbers expected (t, position, "
                             f"{'rx, ry, rz' if dim == 3 else 'angle'}), got {len(row)}")
        rows.append(row)
        if len(rows) > MOTION_MAX_ROWS:
            raise SceneError(f"{label}: {path} has more than {MOTION_MAX_ROWS:,} rows")
    if len(rows) < 2:
        raise SceneError(f"{label}: {path} needs at least 2 rows (t, position, angles), got {len(rows)}")
    table = np.asarray(rows, dtype=np.float64)
    if np.any(np.diff(table[:, 0]) <= 0.0):
        raise SceneError(f"{label}: {path}: the times must increase strictly")
    return table


def shipped_meshes() -> dict[str, str]:
    """The example meshes shipped in corpuscle/data/meshes: name (without extension) -> path
    (``sphere``: radius 0.05 m, 320 triangles; ``wing_naca0012``: a NACA 0012 section of
    chord 0.1 m along x and span 0.2 m along y, leading edge at the origin)."""
    from importlib import resources
    d = resources.files("corpuscle") / "data" / "meshes"
    return {f.name.rsplit(".", 1)[0]: str(f) for f in d.iterdir() if f.name.endswith((".stl", ".obj", ".ply"))}
