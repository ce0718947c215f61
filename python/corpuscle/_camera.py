"""Cameras for the renderer: an orbit (perspective) camera for 3-D scenes and an orthographic
fit for 2-D ones, with the same projection the compiled rasterizer uses (raster.h ``project``).

View space: x right, y up, z forward (depth). Screen: pixels, x right, y down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# vertical field of view of the orbit camera, degrees
FOV_DEG = 35.0


@dataclass
class Camera:
    """A 3x4 world-to-view matrix (rows right, up, forward), intrinsics and projection kind."""

    matrix: np.ndarray  # (3, 4)
    focal: float  # perspective: pixels per unit at depth 1; orthographic: pixels per unit
    cx: float
    cy: float
    ortho: bool
    eye: np.ndarray | None = None  # world position of a perspective eye

    def packed(self) -> np.ndarray:
        """The 15 floats the rasterizer takes: matrix, focal, cx, cy."""
        return np.concatenate([self.matrix.reshape(-1), [self.focal, self.cx, self.cy]]).astype(np.float32)

    def view(self, points: np.ndarray) -> np.ndarray:
        """World points (n, 2|3) -> view coordinates (n, 3)."""
        p = np.asarray(points, dtype=np.float64)
        if p.shape[1] == 2:
            p = np.hstack([p, np.zeros((len(p), 1))])
        return p @ self.matrix[:, :3].T + self.matrix[:, 3]

    def project(self, points: np.ndarray) -> np.ndarray:
        """World points -> (n, 4): screen x, screen y, view depth, pixels per world unit."""
        v = self.view(points)
        s = np.full(len(v), self.focal) if self.ortho else self.focal / np.maximum(v[:, 2], 1e-6)
        return np.stack([self.cx + s * v[:, 0], self.cy - s * v[:, 1], v[:, 2], s], axis=1)

    def facing(self, point: np.ndarray, normal: np.ndarray) -> bool:
        """True when a surface at ``point`` with outward ``normal`` faces the camera."""
        if self.ortho or self.eye is None:
            return float(np.dot(normal, -self.matrix[2, :3])) > 0.0
        return float(np.dot(normal, self.eye - point)) > 0.0


def basis(up: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Right-handed world axes (e1, e2, up) for an up axis such as '+z' or '-y'."""
    sign = -1.0 if up.startswith("-") else 1.0
    axis = "xyz".index(up[-1])
    u = np.zeros(3)
    u[axis] = sign
    e1 = np.zeros(3)
    e1[(axis + 1) % 3] = 1.0
    e2 = np.cross(u, e1)
    return e1, e2, u


def orbit(target, azimuth: float, elevation: float, distance: float, up: str, width: int, height: int,
          cx: float | None = None) -> Camera:
    """A perspective camera on a sphere around ``target``: azimuth from the first horizontal
    axis toward the second, elevation above the horizontal plane, both in degrees."""
    e1, e2, u = basis(up)
    az, el = math.radians(azimuth), math.radians(max(-89.5, min(89.5, elevation)))
    target = np.asarray(target, dtype=np.float64)
    eye = target + distance * (math.cos(el) * math.cos(az) * e1 + math.cos(el) * math.sin(az) * e2 + math.sin(el) * u)
    fwd = target - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, u)
    right /= np.linalg.norm(right)
    upv = np.cross(right, fwd)
    rot = np.stack([right, upv, fwd])
    matrix = np.hstack([rot, (-rot @ eye)[:, None]])
    focal = 0.5 * height / math.tan(math.radians(FOV_DEG) / 2)
    return Camera(matrix, focal, width / 2 if cx is None else cx, height / 2, False, eye)


def fit_distance(radius: float, width: int, height: int, fill: float = 0.88) -> float:
    """Orbit distance at which a sphere of ``radius`` spans ``fill`` of the narrower view."""
    half_v = math.radians(FOV_DEG) / 2
    half_h = math.atan(math.tan(half_v) * width / height)
    half = min(half_v, half_h)
    # the sphere's silhouette subtends asin(r/d): keep it inside fill * the half-angle
    return radius / math.sin(math.atan(fill * math.tan(half)))


def fit_2d(lo, hi, width: int, height: int, margin: float = 0.04) -> Camera:
    """An orthographic camera showing the rectangle [lo, hi] whole, centred in width x height."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    span = np.maximum(hi - lo, 1e-12)
    scale = min(width * (1 - 2 * margin) / span[0], height * (1 - 2 * margin) / span[1])
    centre = 0.5 * (lo + hi)
    matrix = np.array([[1.0, 0, 0, -centre[0]], [0, 1.0, 0, -centre[1]], [0, 0, 1.0, 0]])
    return Camera(matrix, scale, width / 2, height / 2, True)


def quat_matrix(q) -> np.ndarray:
    """Rotation matrix of an orientation: a quaternion (w, x, y, z), or in 2-D one angle about z."""
    q = np.asarray(q, dtype=np.float64).reshape(-1)
    if q.size == 1:
        c, s = math.cos(q[0]), math.sin(q[0])
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    w, x, y, z = q / max(np.linalg.norm(q), 1e-300)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])
