"""Colour ramps for particle values and the lookup tables the rasterizer reads.

A ramp is a list of evenly spaced RGB stops, interpolated linearly into a 256-entry table.
``heat`` is the seed's 7-stop pressure ramp (black, blue, cyan, green, yellow, red, white),
drawn on log(p + 1) in 2-D scenes.
"""

from __future__ import annotations

import numpy as np

# evenly spaced stops, low to high
RAMPS: dict[str, list[tuple[int, int, int]]] = {
    "heat": [(0, 0, 0), (0, 0, 255), (0, 255, 255), (0, 255, 0), (255, 255, 0), (255, 0, 0), (255, 255, 255)],
    "ocean": [(12, 34, 110), (22, 92, 190), (38, 160, 228), (132, 214, 245), (248, 252, 255)],
    "gray": [(38, 38, 42), (236, 236, 240)],
}

# colour of particles when no value colours them, and of NaN values
UNIFORM = (64, 146, 224)
NAN_COLOR = (128, 128, 128)


def make_lut(name: str, size: int = 256) -> np.ndarray:
    """A (size, 3) uint8 table sampling ramp ``name`` evenly, both ends included."""
    stops = np.asarray(RAMPS[name], dtype=np.float64)
    u = np.linspace(0.0, 1.0, size)
    x = np.linspace(0.0, 1.0, len(stops))
    lut = np.stack([np.interp(u, x, stops[:, c]) for c in range(3)], axis=1)
    return np.ascontiguousarray(np.round(lut).astype(np.uint8))


def transform(values: np.ndarray, log: bool) -> np.ndarray:
    """Values as the ramp sees them: signed log(1 + |v|) when ``log`` (log(p+1) for p >= 0)."""
    v = np.asarray(values, dtype=np.float64)
    return np.sign(v) * np.log1p(np.abs(v)) if log else v


def inverse_transform(values: np.ndarray | float, log: bool) -> np.ndarray:
    """Inverse of :func:`transform`, for colour-bar labels in the field's own units."""
    v = np.asarray(values, dtype=np.float64)
    return np.sign(v) * np.expm1(np.abs(v)) if log else v


def map_values(values: np.ndarray, lut: np.ndarray, lo: float, hi: float, log: bool) -> np.ndarray:
    """NumPy reference of the rasterizer's colour mapping: (n,) values -> (n, 3) uint8."""
    t = transform(values, log)
    u = np.clip((t - lo) / (hi - lo), 0.0, 1.0)
    k = np.minimum((u * len(lut)).astype(np.int64), len(lut) - 1)
    out = lut[k]
    out[np.isnan(t)] = NAN_COLOR
    return out
