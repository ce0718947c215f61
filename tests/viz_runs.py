"""Small recorded runs for the render, plot and export tests (written with corpuscle.io)."""

from __future__ import annotations

import numpy as np

from corpuscle.io import FrameWriter

# the simulator's die: face number -> outward normal in the body frame
DIE_FACES = {"1": [1, 0, 0], "6": [-1, 0, 0], "2": [0, 1, 0], "5": [0, -1, 0], "3": [0, 0, 1], "4": [0, 0, -1]}


def magic8ball_header(radius: float = 0.15, half: float = 0.032, particle_radius: float = 0.008) -> dict:
    """A 3-D header in the simulator's conventions (sphere container, a die)."""
    return {
        "scene": "magic8ball", "kind": "magic8ball", "dim": 3, "backend": "cpu",
        "parameters": {"gravity": {"g": [0.0, 0.0, -9.81]}},
        "container": {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": radius},
        "bodies": [{"name": "die", "shape": "box", "half_extents": [half] * 3, "faces": DIE_FACES}],
        "particle_radius": particle_radius, "h": 0.05,
    }


def quat(angle: float, axis) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation by ``angle`` about ``axis``."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * a])


def write_magic8ball(path, frames: int = 4, n: int = 600, ghosts: bool = True, velocity: bool = True, seed: int = 0):
    """A 3-D run: fluid in the lower half of the sphere, the die above it, ghosts outside."""
    rng = np.random.default_rng(seed)
    header = magic8ball_header()
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    pos = d * 0.14 * rng.random((n, 1)) ** (1 / 3)
    pos[:, 2] = -np.abs(pos[:, 2])
    with FrameWriter(path, header) as w:
        for k in range(frames):
            fields = {"position": pos.astype(np.float32),
                      "density": (1000 + 5 * rng.standard_normal(n)).astype(np.float32),
                      "pressure": (200 * rng.random(n)).astype(np.float32)}
            groups = {}
            if velocity:
                fields["velocity"] = (0.05 * (k + 1) * rng.standard_normal((n, 3))).astype(np.float32)
            if ghosts:
                fields["ghost_position"] = (pos[:50] / np.linalg.norm(pos[:50], axis=1)[:, None] * 0.16).astype(np.float32)
                groups["ghost_position"] = "ghost"
            rigid = {"die": {"position": np.array([0.0, 0.0, 0.05]), "orientation": quat(0.3 * k, [0.2, 0.3, 1.0]),
                             "velocity": np.array([0.0, 0.01 * k, 0.0])}}
            diag = {"kinetic_energy": 0.01 * (k + 1), "density_error": 0.002 * k, "mean_density": 1000.0 + k,
                    "die_height": 0.05 - 0.001 * k, "die_speed": 0.01 * k, "n_particles": float(n),
                    "n_ghosts": 50.0 if ghosts else 0.0}
            w.write_frame(100 * k, 0.02 * k, 1e-4 * (1 + k), fields, groups=groups, rigid=rigid, diagnostics=diag)
    return header


def tunnel_header() -> dict:
    """A 2-D wind-tunnel header: a box channel and an airfoil polygon."""
    t = np.linspace(0, 2 * np.pi, 41)[:-1]
    foil = np.stack([0.8 + 0.35 * np.cos(t), 0.5 + 0.06 * np.sin(t)], 1)
    return {"scene": "wind_tunnel", "kind": "wind_tunnel", "dim": 2,
            "container": {"type": "box", "min": [0.0, 0.0], "max": [2.0, 1.0]},
            "obstacles": [{"type": "polygon", "name": "airfoil", "points": foil.tolist()}],
            "particle_radius": 0.004}


def write_tunnel(path, frames: int = 3, n: int = 3000, seed: int = 1):
    """A 2-D DEM run: particles in the channel (not inside the airfoil), lift and drag series."""
    rng = np.random.default_rng(seed)
    header = tunnel_header()
    with FrameWriter(path, header) as w:
        for k in range(frames):
            pos = rng.random((n, 2)) * [2.0, 1.0]
            inside = ((pos[:, 0] - 0.8) / 0.36) ** 2 + ((pos[:, 1] - 0.5) / 0.07) ** 2 < 1
            pos[inside, 1] = 0.9
            pres = np.where(rng.random(n) < 0.3, 0.0, np.exp(3 * rng.random(n))).astype(np.float32)
            w.write_frame(k, 0.1 * k, 1e-3, {"position": pos.astype(np.float32), "pressure": pres,
                                             "velocity": rng.standard_normal((n, 2)).astype(np.float32)},
                          diagnostics={"lift": 1.0 + k, "drag": 0.5 + 0.1 * k, "cl": 0.8, "cd": 0.2 + 0.01 * k,
                                       "n_particles": float(n)})
    return header


def write_points(path, header: dict, positions, values=None, field: str = "pressure", frames: int = 1):
    """A run whose frames all hold the given particles (and one value field)."""
    with FrameWriter(path, header) as w:
        for k in range(frames):
            fields = {"position": np.asarray(positions, np.float32)}
            if values is not None:
                fields[field] = np.asarray(values, np.float32)
            w.write_frame(k, 0.5 * k, 1e-3, fields)
