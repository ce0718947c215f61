"""A body in the 3-D wind tunnel (``[[bodies]]`` of ``wind-tunnel-3d``, :mod:`corpuscle.geometry`):
a closed triangle mesh (an STL, OBJ or PLY file) or a primitive (box, sphere, cylinder; faceted)
that replaces the airfoil. Its triangles go to the core as world vertices and faces (the arrays
``body_vertices`` and ``body_faces``), where physics/triangle_mesh.h writes their records (face,
edge and vertex pseudo-normals) and dem/mesh_body.h holds them in the engine's LBVH: the gas
touches the body by signed distance (robust at edges and vertices), no centre ends a step
inside it, and its reaction (force, moment about z and torque about the body's centroid) is
summed every step as the airfoil's is (cpp/include/corpuscle/scenes/wind_tunnel/stages.h).

An open mesh (a thin wall) is refused: the gas is kept out of a body by its signed distance,
which a surface without an inside does not have. The body is fixed (``motion = "fixed"``)
and lies inside the channel, clear of the walls and within the periodic span (a body crossing
the span's ends would meet its own periodic image).

Coefficients use a reference area: ``body.reference_area`` or, 0, the body's frontal area (its
projection on the y-z plane: half the sum of |n_x| times the area over its triangles, exact for
a convex body), and a reference length for the moment: ``body.reference_length`` or, 0, its
length along x (docs/wind_tunnel.md, "Bodies")."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import geometry
from ..schema import KeySpec, SceneError, _fmt_value

__all__ = ["BODY_KEYS", "MOTIONS", "MAX_BODIES", "check_body", "WindBody", "build_body", "header_obstacle",
           "mesh_volume", "frontal_area"]

#: the motions a wind-tunnel body takes, and how many bodies a scene holds (the core has one mesh)
MOTIONS = ("fixed",)
MAX_BODIES = 1
#: the faceting of a primitive sphere or cylinder (segments around)
SEGMENTS = 48

BODY_KEYS: dict[str, KeySpec] = {
    "body.reference_area": KeySpec("float", 0.0, "m^2", 0.0, 1e8,
                                   "[[bodies]]: the area of C_L, C_D, C_M; 0: the body's frontal area (its "
                                   "projection on the y-z plane)"),
    "body.reference_length": KeySpec("float", 0.0, "m", 0.0, 1e4,
                                     "[[bodies]]: the length of C_M; 0: the body's length along x"),
}


def mesh_volume(v: np.ndarray, f: np.ndarray) -> float:
    """The enclosed volume of a closed, outward mesh (the divergence theorem), float64."""
    t = np.asarray(v, dtype=np.float64)[np.asarray(f)]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0)


def frontal_area(v: np.ndarray, f: np.ndarray) -> float:
    """The projection of a closed mesh on the y-z plane (exact for a convex body): half the
    sum over its triangles of |n_x| times the area."""
    t = np.asarray(v, dtype=np.float64)[np.asarray(f)]
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])  # twice the area along the normal
    return float(0.25 * np.abs(n[:, 0]).sum())


@dataclass
class WindBody:
    """The placed body and what the tunnel needs of it."""
    body: geometry.Body
    vertices: np.ndarray  # world (n, 3), float64
    faces: np.ndarray     # (m, 3) int64, outward
    volume: float
    lo: np.ndarray
    hi: np.ndarray
    centroid: np.ndarray  # the torque's reference point (the vertices' mean, as the core takes it)
    reference_area: float
    reference_length: float

    def signed_distance(self, pts: np.ndarray) -> np.ndarray:
        """Signed distance (m, float64) of points to the faceted surface the core uses."""
        return geometry._sd_mesh(np.asarray(pts, dtype=np.float64), self.vertices, self.faces, True)


def _label(b: dict[str, Any]) -> str:
    return f"bodies[1].file = {_fmt_value(b['file'])}" if b["shape"] == "mesh" else f"bodies[1] ({b['shape']})"


def _surface(entries: list[dict[str, Any]]) -> tuple[geometry.Body, np.ndarray, np.ndarray]:
    b = entries[0]
    if b["open"] or b["shape"] == "plane":
        raise SceneError(f"{_label(b)}: an open surface (a thin wall) is not taken by the wind tunnel: the gas is "
                         f"kept out of a body by its signed distance, which needs a closed mesh")
    geometry.check_bodies({"bodies": entries}, 3, motions=MOTIONS, open_allowed=False)
    body = geometry.make_body(b, 1, 3)  # a mesh: read and checked closed, oriented outward
    v, f = geometry.surface_mesh(body, SEGMENTS)
    v = np.asarray(v, dtype=np.float64)
    f = np.asarray(f, dtype=np.int64)
    if mesh_volume(v, f) < 0.0:  # a primitive wound inward: turn it (a mesh was checked outward)
        f = f[:, ::-1].copy()
    return body, v, f


def check_body(values: dict[str, Any], arrays) -> None:
    """The [[bodies]] checks of the 3-D wind tunnel: at most one body, closed and fixed, its
    mesh readable and closed, inside the channel (x, y) and within the span (z)."""
    entries = (arrays or {}).get("bodies", [])
    if not entries:
        return
    if len(entries) > MAX_BODIES:
        raise SceneError(f"bodies: {len(entries)} bodies, the wind tunnel takes {MAX_BODIES} (its force is that body's)")
    _, v, _ = _surface(entries)
    lo, hi = v.min(axis=0), v.max(axis=0)
    L, H, B = float(values["channel.length"]), float(values["channel.height"]), float(values["channel.span"])
    half = np.array([L / 2, H / 2, B / 2])
    if not (np.all(lo > -half) and np.all(hi < half)):
        raise SceneError(f"{_label(entries[0])}: the placed body spans x {lo[0]:.4g} .. {hi[0]:.4g}, y {lo[1]:.4g} .. "
                         f"{hi[1]:.4g}, z {lo[2]:.4g} .. {hi[2]:.4g} m, not inside the channel (x within +-{L / 2:.4g}, "
                         f"y within +-{H / 2:.4g}, z within +-{B / 2:.4g} m: channel.length, channel.height, "
                         f"channel.span)")


def build_body(values: dict[str, Any], arrays) -> WindBody | None:
    """The scene's body (None: no [[bodies]])."""
    entries = (arrays or {}).get("bodies", [])
    if not entries:
        return None
    body, v, f = _surface(entries)
    lo, hi = v.min(axis=0), v.max(axis=0)
    area = float(values["body.reference_area"]) or frontal_area(v, f)
    length = float(values["body.reference_length"]) or float(hi[0] - lo[0])
    # the core's reference point: the mean of the float32 vertices it is given
    centroid = v.astype(np.float32).astype(np.float64).mean(axis=0)
    return WindBody(body, v, f, mesh_volume(v, f), lo, hi, centroid, area, length)


def core_arrays(wb: WindBody) -> dict[str, np.ndarray]:
    """The arrays the core reads (scenes/wind_tunnel/build.h: body_records)."""
    return {"body_vertices": np.ascontiguousarray(wb.vertices, dtype=np.float32),
            "body_faces": np.ascontiguousarray(wb.faces, dtype=np.float32)}


def header_obstacle(wb: WindBody) -> dict[str, Any]:
    """The body as the run header's obstacle (render, the live page and export draw it)."""
    return {"name": wb.body.name, "type": "mesh", "vertices": np.round(wb.vertices, 9).tolist(),
            "faces": wb.faces.tolist(), "reference_area": wb.reference_area,
            "reference_length": wb.reference_length}
