"""The wind tunnel's start: where the gas particles are placed (a jittered lattice clear of
the airfoil, or the inflow conveyor's slots), and the airfoil's signed distance they are
kept clear by. The kind itself is :mod:`corpuscle.kinds.wind_tunnel`."""

from __future__ import annotations

import math

import numpy as np

from .. import airfoils
from ..schema import SceneError

KMAX_ROWS = 16384  # the inflow conveyor's rows the core holds (scenes/wind_tunnel/model.h kMaxRows)


def _inside(poly: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Crossing-parity point in polygon, vectorised over points."""
    inside = np.zeros(len(pts), dtype=bool)
    x, y = pts[:, 0], pts[:, 1]
    a, b = poly, np.roll(poly, -1, axis=0)
    for (ax, ay), (bx, by) in zip(a, b):
        cross = (ay > y) != (by > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xi = ax + (y - ay) * (bx - ax) / (by - ay)
        inside ^= cross & (x < xi)
    return inside


def _distance(poly: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Unsigned distance from points to the polygon's boundary."""
    d2 = np.full(len(pts), np.inf)
    a, b = poly, np.roll(poly, -1, axis=0)
    for p0, p1 in zip(a, b):
        e = p1 - p0
        t = np.clip(((pts - p0) @ e) / max(float(e @ e), 1e-300), 0.0, 1.0)
        q = p0 + t[:, None] * e
        d2 = np.minimum(d2, np.einsum("ij,ij->i", pts - q, pts - q))
    return np.sqrt(d2)


def signed_distance(poly: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Signed distance (negative inside), float64, for tests and placement."""
    pts = np.asarray(pts, dtype=np.float64)
    d = _distance(poly, pts)
    return np.where(_inside(poly, pts), -d, d)


def start_spacing(n, radius, lo, hi, poly, body=None):
    """The start lattice's extent (a radius off the walls; the whole periodic span in 3-D)
    and spacing: n sites and 10% more over the free area (x-y, less the section) or volume
    (less a 3-D body's, _wind_tunnel_body.WindBody; poly None: no airfoil)."""
    ext = hi - lo - 2 * radius
    if len(lo) == 3:
        ext[2] = hi[2] - lo[2]  # the periodic span: no wall to keep clear of
    free = float(np.prod(ext[:2])) - (abs(airfoils.signed_area(poly)) if poly is not None else 0.0)
    if len(lo) == 2:
        a = math.sqrt(free / (n * 1.1))
    else:
        a = (max(free * ext[2] - (body.volume if body is not None else 0.0), 1e-300) / (n * 1.1)) ** (1 / 3)
    return ext, a


def keep_clear(pts, poly, clearance, body=None):
    """Which points lie farther than clearance from the airfoil section (x-y; poly None: no
    airfoil) and from a 3-D body (its signed distance)."""
    keep = clear(pts[:, :2], poly, clearance) if poly is not None else np.ones(len(pts), dtype=bool)
    if body is not None:
        near = np.all((pts > body.lo - clearance) & (pts < body.hi + clearance), axis=1) & keep
        if near.any():
            keep[near] = body.signed_distance(pts[near]) > clearance
    return keep

def place(n, radius, lo, hi, poly, params, seed, body=None):
    """A jittered square lattice over the channel, a radius clear of the walls and the
    airfoil, n of its sites drawn at random; velocities are the free stream. A
    collisionless gas (contact.enabled = false) is a uniform random (Poisson) gas instead:
    its particles may overlap."""
    rng = np.random.default_rng(seed)
    if not params.get("collide", 1):
        return place_uniform(n, radius, lo, hi, poly, params, rng, body)
    if params.get("conv_rows", 0):
        return place_conveyor(n, radius, lo, hi, poly, params, rng, body)
    d = len(lo)
    ext, a = start_spacing(n, radius, lo, hi, poly, body)
    if a <= 2 * radius * 1.0001:
        raise SceneError(f"gas.particles = {n} of radius {radius:.3g} m do not fit in the channel "
                         f"(lattice spacing {a:.3g} m < a diameter)")
    while True:
        # at least one site each way: a spacing wider than the channel (a handful of
        # particles) would leave no row and divide by zero
        counts = [max(1, int(ext[k] / a)) for k in range(d)]
        axes = [lo[k] + radius + (np.arange(counts[k]) + 0.5) * (ext[k] / counts[k]) for k in range(2)]
        if d == 3:
            axes.append(lo[2] + (np.arange(counts[2]) + 0.5) * (ext[2] / counts[2]))
        grids = np.meshgrid(*axes, indexing="ij")
        pts = np.column_stack([g.ravel() for g in grids])
        gap = min(ext[k] / counts[k] for k in range(d))
        pts += rng.uniform(-1, 1, pts.shape) * 0.45 * (gap - 2 * radius)
        # the airfoil section (extruded along z in 3-D: the x-y distance) or the 3-D body
        pts = pts[keep_clear(pts, poly, 1.05 * radius, body)]
        if len(pts) >= n:
            break
        a *= 0.97
        if a <= 2 * radius * 1.0001:
            raise SceneError(f"gas.particles = {n} of radius {radius:.3g} m do not fit around the "
                             f"{'body' if body is not None else 'airfoil'}")
    pick = np.sort(rng.choice(len(pts), size=n, replace=False))
    pos = pts[pick]
    U = params["speed"]
    sigma = params["thermal"] * U
    vel = np.zeros_like(pos)
    vel[:, 0] = U
    if sigma > 0:
        vel += rng.normal(0.0, sigma, vel.shape)
    return np.ascontiguousarray(pos, dtype=np.float32), np.ascontiguousarray(vel, dtype=np.float32)

def conveyor_slots(radius, lo, hi, c):
    """Unjittered slot centres of the cold beam's lattice over the channel: row r at height
    y0 + (r mod ny) dy (3-D: in the span's layer r // ny, z0 + (r // ny) dz), columns dx
    apart from the inlet at the row's phase (stages.h, "The inflow conveyor": the same
    formulas, so the stream entering later continues this lattice)."""
    rows, ny, dx, dy = c["conv_rows"], c["conv_ny"], c["conv_dx"], c["conv_dy"]
    g = np.arange(rows) * 0.6180339887498949
    phase = dx * (g - np.floor(g))
    L = hi[0] - lo[0]
    ncol = np.maximum(np.ceil((L - phase) / dx).astype(np.int64) - 1, 0)  # columns 1 .. ncol
    r = np.repeat(np.arange(rows), ncol)
    col = np.concatenate([np.arange(1, k + 1) for k in ncol]) if rows else np.empty(0, np.int64)
    x = lo[0] + phase[r] + col * dx
    cols = [x, c["conv_y0"] + (r % ny) * dy]
    if len(lo) == 3:
        cols.append(c["conv_z0"] + (r // ny) * c["conv_dz"])
    pts = np.column_stack(cols)
    return pts[x < hi[0]]

def conveyor(n, radius, lo, hi, poly, body=None) -> dict:
    """The inflow conveyor of a cold beam with contacts: the start lattice's rows and
    spacing (n sites and 10% more over the free area or volume, as the random start had),
    so the stream that enters later is the lattice the run starts from. Deterministic (no
    random numbers): a resumed run rebuilds the same one. More rows than the core holds
    (stages.h kMaxRows): no conveyor (re-entry at random heights)."""
    d = len(lo)
    ext, a = start_spacing(n, radius, lo, hi, poly, body)
    while True:
        if a <= 2 * radius * 1.0001:
            raise SceneError(f"gas.particles = {n} of radius {radius:.3g} m do not fit in the channel "
                             f"(lattice spacing {a:.3g} m < a diameter)")
        ny = max(1, int(ext[1] / a))
        nz = max(1, int(ext[2] / a)) if d == 3 else 1
        if ny * nz > KMAX_ROWS:
            return {"conv_rows": 0}
        c = {"conv_rows": ny * nz, "conv_ny": ny, "conv_y0": lo[1] + radius + 0.5 * ext[1] / ny,
             "conv_dy": ext[1] / ny, "conv_dx": a}
        if d == 3:
            c.update(conv_z0=lo[2] + 0.5 * ext[2] / nz, conv_dz=ext[2] / nz)
        if min(c["conv_dy"], c.get("conv_dz", a)) > 2 * radius * 1.0001:
            pts = conveyor_slots(radius, lo, hi, c)
            gaps = [a - 2 * radius, c["conv_dy"] - 2 * radius] + ([c["conv_dz"] - 2 * radius] if d == 3 else [])
            jitter = 0.45 * math.hypot(gaps[0], gaps[1])  # in x-y, where the airfoil is
            if body is not None:  # the jitter in 3-D
                jitter = 0.45 * math.sqrt(sum(g * g for g in gaps))
            if len(pts) >= n and np.count_nonzero(keep_clear(pts, poly, 1.05 * radius + jitter, body)) >= n:
                return c
        a *= 0.97

def clear(pts, poly, clearance):
    box_lo, box_hi = poly.min(axis=0) - clearance, poly.max(axis=0) + clearance
    near = np.all((pts > box_lo) & (pts < box_hi), axis=1)
    keep = np.ones(len(pts), dtype=bool)
    if near.any():
        keep[near] = signed_distance(poly, pts[near]) > clearance
    return keep

def place_conveyor(n, radius, lo, hi, poly, params, rng, body=None):
    """The start as the conveyor's lattice (see _conveyor): its slots jittered as the entering
    ones are, those 1.05 radii clear of the airfoil kept, n of them drawn at random."""
    d = len(lo)
    pts = conveyor_slots(radius, lo, hi, params)
    gaps = [params["conv_dx"], params["conv_dy"]] + ([params["conv_dz"]] if d == 3 else [])
    pts = pts + rng.uniform(-1, 1, pts.shape) * 0.45 * (np.array(gaps) - 2 * radius)
    # the last column up to the outflow, never past it: a column trimmed short of it would
    # start the stream leaving late, and the conveyor's first slots would pass unfilled (a
    # seam of vacancies moving downstream). Pulled back by at most its jitter, a slot stays
    # more than a diameter from its neighbours (0.1 dx + 1.8 r apart at least)
    pts[:, 0] = np.minimum(pts[:, 0], float(np.nextafter(np.float32(hi[0]), np.float32(-np.inf))))  # (float32)
    if d == 3:  # the periodic span
        pts[:, 2] = lo[2] + np.mod(pts[:, 2] - lo[2], hi[2] - lo[2])
    pts = pts[keep_clear(pts, poly, 1.05 * radius, body)]  # (_conveyor made sure n of them are)
    pick = np.sort(rng.choice(len(pts), size=n, replace=False))
    pos = pts[pick]
    vel = np.zeros_like(pos)
    vel[:, 0] = params["speed"]
    return np.ascontiguousarray(pos, dtype=np.float32), np.ascontiguousarray(vel, dtype=np.float32)

def place_uniform(n, radius, lo, hi, poly, params, rng, body=None):
    d = len(lo)
    pts = np.empty((0, d))
    # a radius off the walls; from the inflow to the outflow in x, as the stream fills it
    # (a gap there would travel down the channel as a hole in the stream); all of the
    # periodic span in 3-D
    off = np.zeros(d)
    off[1] = radius
    a, b = lo + off, hi - off
    while len(pts) < n:
        p = rng.uniform(a, b, (int(1.2 * (n - len(pts))) + 16, d))
        pts = np.concatenate([pts, p[keep_clear(p, poly, radius, body)]])
    pos = pts[:n]
    U = params["speed"]
    sigma = params["thermal"] * U
    vel = np.zeros_like(pos)
    vel[:, 0] = U
    if sigma > 0:
        vel += rng.normal(0.0, sigma, vel.shape)
    return np.ascontiguousarray(pos, dtype=np.float32), np.ascontiguousarray(vel, dtype=np.float32)

# reading -------------------------------------------------------------------------
