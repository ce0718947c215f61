"""Bodies in the SPH box kinds (``[[bodies]]``, :mod:`corpuscle.geometry`): each body's
surface becomes dynamic boundary particles (DBC, as the tank's walls) on the fluid's lattice
(i + 1/2) dp, inside the body and as many layers deep as the kernel support; fluid is never
placed inside a body or within half a spacing of it. The body particles join the walls
(slots [n_fluid, n)), so the core needs nothing new for them.

Fixed bodies only: ``motion`` other than "fixed" is refused with one line (moving and free
bodies are not in the core yet)."""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from .. import geometry
from ..schema import CrossCheck, SceneError, _fmt_value

#: the most [[bodies]] entries of an SPH box scene
MAX_BODIES = 64
#: the motions the SPH box kinds support
MOTIONS = ("fixed",)


def body_keys(dim: int):
    return geometry.body_keys(dim)


def check_bodies(box: Callable[[dict[str, Any]], Any], dim: int) -> CrossCheck:
    """The [[bodies]] checks: each entry's keys (geometry.check_bodies), its mesh readable and
    closed, and the body inside the tank (box(values): its inner size from the origin)."""
    def check(values, arrays) -> None:
        entries = arrays.get("bodies", [])
        if not entries:
            return
        geometry.check_bodies(arrays, dim, motions=MOTIONS, open_allowed=True)
        size = np.asarray(box(values), dtype=np.float64)
        tol = 1e-9 * max(float(size.max()), 1.0)
        for k, b in enumerate(geometry.make_bodies(arrays, dim), start=1):
            lo, hi = b.bounds()
            if np.any(lo < -tol) or np.any(hi > size + tol):
                raise SceneError(f"bodies[{k}] ({b.name!r}) reaches outside the tank: its bounds "
                                 f"{_fmt_value(np.round(lo, 6).tolist())} .. {_fmt_value(np.round(hi, 6).tolist())} m, "
                                 f"the tank 0 .. {_fmt_value(size.tolist())} m (check bodies[{k}].position, size, "
                                 f"scale and units)")
    return check


def build_bodies(arrays: dict[str, list], dim: int, dp: float, layers: int,
                 fluid: np.ndarray) -> tuple[list, np.ndarray, np.ndarray, np.ndarray]:
    """(bodies, their boundary particles (n, dim), each particle's body index, the mask of
    the fluid points no body excludes). Particles two bodies share (overlapping bodies) are
    kept once."""
    bodies = geometry.make_bodies(arrays, dim)
    if not bodies:
        return [], np.zeros((0, dim)), np.zeros(0, np.int32), np.ones(len(fluid), bool)
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
    return bodies, pts[first], owner[first], keep


def header_obstacles(bodies: list) -> list[dict[str, Any]]:
    """The bodies as the run header's obstacles (render, live and export draw them): an
    unrotated 3-D box as a box, a 2-D body as its outline polygon, any other 3-D body as its
    triangles (``type = "mesh"``: ``vertices``, ``faces``)."""
    out = []
    for b in bodies:
        v, f = geometry.surface_mesh(b)
        if b.dim == 2:
            out.append({"name": b.name, "type": "polygon", "points": np.round(v, 9).tolist()})
        elif b.shape == "box" and np.allclose(b.rotation, np.eye(3)):
            lo, hi = b.bounds()
            out.append({"name": b.name, "type": "box", "min": lo.tolist(), "max": hi.tolist()})
        else:
            out.append({"name": b.name, "type": "mesh", "vertices": np.round(v, 9).tolist(),
                        "faces": np.asarray(f, np.int64).tolist()})
    return out
