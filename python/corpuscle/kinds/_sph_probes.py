"""The SPH box kinds' probes: the ``[[probes]]`` table (points and faces: discs or squares on a
wall, area-averaged; water-level gauges: vertical lines), their checks, the sample points of a face, the series drained from the
core, and the pressure impulse over a window (docs/sph_box.md, "Probes")."""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from ..schema import CrossCheck, KeySpec, SceneError, _fmt_value
from . import core

_K = KeySpec


def probe_keys(dim: int) -> dict[str, KeySpec]:
    return {"name": _K("str", "", "", doc="probe name (letters, digits, _ and -)"),
            "position": _K(f"vec{dim}", [0.0] * dim, "m", -1e4, 1e4,
                           "where pressure and velocity are sampled (a face: its centre)"),
            **probe_face_keys(dim)}


# ---- probes as the experiments have them (scenes/sph/probe.h) ---------------------------------
PROBE_SHAPES = {"point": 0, "disc": 1, "square": 2, "gauge": 3}
PROBE_MAX_SAMPLES = 4096  # kMaxProbeSamples of scenes/sph/probe.h
PROBE_SERIES = 32  # kProbeSeries of scenes/sph/model.h: samples per probe between drains


def probe_face_keys(dim: int) -> dict[str, KeySpec]:
    """A probe's face and sampling: a disc or square of a given size with a normal (a pressure
    sensor's membrane, area-averaged), sampled on its own interval."""
    return {
        "shape": _K("enum", "point", "", doc="point, or a face: disc (diameter size) or square (side size); "
                    "in 2-D both are a segment of length size across the normal; or gauge: a water-level gauge, "
                    "the vertical line from position up by size", choices=tuple(PROBE_SHAPES)),
        "size": _K("float", 0.0, "m", 0.0, 1e3, "a face's diameter (disc) or side (square); a gauge's length"),
        "normal": _K(f"vec{dim}", [1.0] + [0.0] * (dim - 1), "", -1e3, 1e3,
                     "the face's normal (any length; a sensor on the wall x = L: [1, 0] or [-1, 0])"),
        "samples": _K("int", 0, "", 0, PROBE_MAX_SAMPLES,
                      "sample points spread over the face's area (3-D square: a square number) or along a "
                      "gauge (2 or more, both ends included); 0: from the spacing (at most dp / 2 apart)"),
        "interval": _K("float", 0.0, "s", 0.0, 1e7, "time between the probe's samples (0: every step)"),
    }


def probe_samples_of(p: dict[str, Any], dim: int, dp: float | None) -> int:
    """The sample points a probe uses (its `samples`, or from the spacing when 0)."""
    shape = p.get("shape", "point")
    if shape == "point":
        return 1
    n = int(p.get("samples", 0) or 0)
    if n:
        return n
    per = max(1, math.ceil(2.0 * float(p["size"]) / dp)) if dp else 4  # at most dp / 2 apart
    if shape == "gauge":
        return min(per + 1, PROBE_MAX_SAMPLES)
    if dim == 2:
        n = per
    elif shape == "square":
        n = per * per
    else:
        n = max(1, math.ceil(math.pi / 4.0 * per * per))
    if dim == 3 and shape == "square":
        k = min(per, int(math.isqrt(PROBE_MAX_SAMPLES)))
        return k * k
    return min(n, PROBE_MAX_SAMPLES)


def _check_probe_faces(values, arrays) -> None:
    for k, p in enumerate(arrays.get("probes", []), start=1):
        where = f"probes[{k}]"
        shape = p.get("shape", "point")
        dim = len(p["position"])
        if shape == "point":
            if float(p.get("size", 0.0)) != 0.0:
                raise SceneError(f"{where}.size = {_fmt_value(p['size'])}: a point probe has no size "
                                 f"(shape = \"disc\" or \"square\" for a face)")
            if int(p.get("samples", 0)) > 1:
                raise SceneError(f"{where}.samples = {p['samples']}: a point probe samples one point")
            continue
        if not float(p.get("size", 0.0)) > 0.0:
            raise SceneError(f"{where}.size = {_fmt_value(p.get('size', 0.0))}: a {shape} probe needs a size > 0 (m)")
        if shape == "gauge":
            if int(p.get("samples", 0)) == 1:
                raise SceneError(f"{where}.samples = 1: a gauge samples its line at 2 points or more (0: from the spacing)")
            n = np.asarray(p.get("normal", [1.0] + [0.0] * (dim - 1)), dtype=np.float64)
            if not (np.allclose(n, gauge_axis(dim)) or np.allclose(n, [1.0] + [0.0] * (dim - 1))):
                raise SceneError(f"{where}.normal = {_fmt_value(p.get('normal'))}: a gauge is vertical (from its "
                                 f"position up by its size); leave normal out")
            continue
        n = np.asarray(p.get("normal"), dtype=np.float64)
        if not np.all(np.isfinite(n)) or not float(np.dot(n, n)) > 0.0:
            raise SceneError(f"{where}.normal = {_fmt_value(p.get('normal'))}: a face needs a non-zero normal")
        ns = int(p.get("samples", 0))
        if dim == 3 and shape == "square" and ns and math.isqrt(ns) ** 2 != ns:
            raise SceneError(f"{where}.samples = {ns}: a square face's samples form a k x k grid (a square number)")


def gauge_axis(dim: int) -> list[float]:
    """A gauge's axis: up (+y in 2-D, +z in 3-D)."""
    return [0.0] * (dim - 1) + [1.0]


def is_gauge(p: dict[str, Any]) -> bool:
    return p.get("shape", "point") == "gauge"


def probe_normal(p: dict[str, Any], dim: int) -> list[float]:
    """The unit normal of a face (a gauge: its axis, up) as the core takes it."""
    if is_gauge(p):
        return gauge_axis(dim)
    n = np.asarray(p.get("normal", [1.0] + [0.0] * (dim - 1)), dtype=np.float64)
    return (n / math.sqrt(float(np.dot(n, n))) if float(np.dot(n, n)) > 0 else n).tolist()


def probe_face_reach(p: dict[str, Any]) -> np.ndarray:
    """How far a face reaches from its centre along each axis: (size / 2) sqrt(1 - n_a^2)
    (a disc, and the 2-D segment), sqrt 2 times that for a 3-D square (its corners, whatever
    the turn of its sides about the normal); 0 for a point."""
    if p.get("shape", "point") in ("point", "gauge"):  # a gauge reaches up: gauge_top
        return np.zeros(len(p["position"]))
    n = np.asarray(p["normal"], dtype=np.float64)
    n = n / math.sqrt(float(np.dot(n, n)))
    r = 0.5 * float(p["size"]) * np.sqrt(np.clip(1.0 - n * n, 0.0, 1.0))
    return r * (math.sqrt(2.0) if p["shape"] == "square" and len(n) == 3 else 1.0)


def probe_face_params(arrays, dim: int, dp: float) -> dict[str, list[float]]:
    """The core's parameters of the probes' faces and sampling (scenes/sph/build.h)."""
    probes = arrays.get("probes", [])
    normal = []
    for p in probes:
        normal += probe_normal(p, dim)
    return {"probe_shape": [float(PROBE_SHAPES[p.get("shape", "point")]) for p in probes],
            "probe_size": [float(p.get("size", 0.0)) for p in probes],
            "probe_normal": normal,
            "probe_samples": [float(probe_samples_of(p, dim, dp)) for p in probes],
            "probe_interval": [float(p.get("interval", 0.0)) for p in probes]}


def probe_sample_points(p: dict[str, Any], dim: int, dp: float | None) -> np.ndarray:
    """A probe's sample points (samples x dim, the core's own: scenes/sph/probe.h)."""
    return core().probe_samples([float(x) for x in p["position"]], probe_normal(p, dim),
                                PROBE_SHAPES[p.get("shape", "point")], float(p.get("size", 0.0)),
                                probe_samples_of(p, dim, dp))


class ProbeSeries:
    """The probes' series of one simulation, drained from the core's rings (kProbeSeries
    samples per probe) after every call of at most PROBE_SERIES steps."""

    def __init__(self, names: list[str]):
        self.names = list(names)
        self.read = [0] * len(names)
        self.t: list[list[float]] = [[] for _ in names]
        self.p: list[list[float]] = [[] for _ in names]
        self.recorded = [0] * len(names)  # what the .cps frames carry so far

    def drain(self, s: dict[str, Any]) -> None:
        count = np.asarray(s["probe_series_count"], dtype=np.int64)
        ts = np.asarray(s["probe_series_time"], dtype=np.float64).reshape(-1, PROBE_SERIES)
        ps = np.asarray(s["probe_series_pressure"], dtype=np.float32).reshape(-1, PROBE_SERIES)
        for k in range(len(self.names)):
            total = int(count[k])
            if total < self.read[k]:  # a restored state: its rings start over
                self.read[k] = total
            if total - self.read[k] > PROBE_SERIES:
                raise RuntimeError(f"probe {self.names[k]!r}: {total - self.read[k]} samples since the last drain, "
                                   f"the ring holds {PROBE_SERIES}")
            for j in range(self.read[k], total):
                self.t[k].append(float(ts[k, j % PROBE_SERIES]))
                self.p[k].append(float(ps[k, j % PROBE_SERIES]))
            self.read[k] = total

    def series(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        if name not in self.names:
            raise KeyError(f"no probe {name!r} (probes: {', '.join(self.names) or 'none'})")
        k = self.names.index(name)
        return np.asarray(self.t[k], dtype=np.float64), np.asarray(self.p[k], dtype=np.float64)


def pressure_impulse(t: np.ndarray, p: np.ndarray, t0: float, t1: float) -> float:
    """The integral of p over [t0, t1] by the trapezoid rule over the samples, the series
    linearly interpolated at the window's ends (Pa s)."""
    t, p = np.asarray(t, dtype=np.float64), np.asarray(p, dtype=np.float64)
    if not (t1 >= t0):
        raise ValueError(f"the window's end {t1!r} is before its start {t0!r}")
    if t.size < 2 or t0 < t[0] or t1 > t[-1]:
        span = f"{t[0]:.6g} .. {t[-1]:.6g} s" if t.size else "no samples"
        raise ValueError(f"the window {t0:.6g} .. {t1:.6g} s is outside the series ({span})")
    inner = (t > t0) & (t < t1)
    tt = np.concatenate([[t0], t[inner], [t1]])
    pp = np.concatenate([[np.interp(t0, t, p)], p[inner], [np.interp(t1, t, p)]])
    return float(np.sum(0.5 * (pp[1:] + pp[:-1]) * np.diff(tt)))


def _check_probes(values, arrays) -> None:
    seen = set()
    for k, p in enumerate(arrays.get("probes", [])):
        name = str(p.get("name", ""))
        if not name or not all(c.isalnum() or c in "_-" for c in name):
            raise SceneError(f"probes[{k}].name must be letters, digits, _ and -, got {name!r}")
        if name in seen:
            raise SceneError(f"probes[{k}].name = {name!r} is used twice")
        seen.add(name)
    if len(arrays.get("probes", [])) > 64:
        raise SceneError(f"probes: {len(arrays['probes'])} probes, at most 64")


def _probes_inside(box: Callable[[dict[str, Any]], Any]) -> CrossCheck:
    """A probe samples the fluid of the tank: one outside it (box(values): the inner size,
    from the origin) would measure nothing, and is refused."""
    def check(values, arrays) -> None:
        size = np.asarray(box(values), dtype=np.float64)
        for k, p in enumerate(arrays.get("probes", [])):
            x = np.asarray(p["position"], dtype=np.float64)
            if not np.all((x >= 0.0) & (x <= size)):
                raise SceneError(f"probes[{k}].position = {_fmt_value(p['position'])} ({p['name']!r}) is outside the "
                                 f"tank (0 .. {_fmt_value(size.tolist())} m): a probe there measures nothing")
            if is_gauge(p):
                top = x[-1] + float(p["size"])
                if top > size[-1] * (1 + 1e-9):
                    raise SceneError(f"probes[{k + 1}].size = {_fmt_value(p['size'])} ({p['name']!r}): the gauge "
                                     f"from {_fmt_value(p['position'])} up to {top:g} m reaches above the tank "
                                     f"({size[-1]:g} m)")
                continue
            reach = probe_face_reach(p)
            if np.any(reach > 0.0) and not np.all((x - reach >= -1e-9 * size) & (x + reach <= size * (1 + 1e-9))):
                raise SceneError(f"probes[{k + 1}].size = {_fmt_value(p['size'])} ({p['name']!r}): the {p['shape']} "
                                 f"centred at {_fmt_value(p['position'])} reaches outside the tank "
                                 f"(0 .. {_fmt_value(size.tolist())} m)")
    return check
