"""Airfoil sections as polygons: Selig and Lednicer ``.dat`` files, NACA 4-digit sections,
flat plates, placement in a scene, and validation.

Every section is returned as a closed, counter-clockwise polygon: a float64 array of shape
(N, 2) without a repeated closing vertex, in chord units, with the leading edge at the origin
and the trailing edge on the +x axis (at (1, 0), or the midpoint of a finite trailing-edge
gap). It starts at the trailing edge on the upper surface, runs forward over the upper
surface to the leading edge and back along the lower surface (the Selig order).

The signed distance to such a polygon, for contacts, is ``cpp/include/corpuscle/physics/
polygon.h``; it expects this orientation.

    >>> from corpuscle import airfoils
    >>> wing = airfoils.place(airfoils.load("e398"), chord=0.5, angle_of_attack_deg=10,
    ...                       leading_edge=(-1.2, 0.0))
"""

from __future__ import annotations

import math
import os
import re
from importlib import resources
from pathlib import Path

import numpy as np

from ._files import AIRFOIL_FILE_BYTES, read_bounded

__all__ = [
    "read_dat",
    "naca4",
    "naca4_thickness",
    "naca4_camber",
    "flat_plate",
    "load",
    "place",
    "normalize",
    "signed_area",
    "validate_polygon",
    "shipped",
    "MAX_VERTICES",
]

#: the most vertices a section may have (the core's contact test walks every edge); checked
#: before anything costs more than reading the file (the self-intersection test is O(n^2))
MAX_VERTICES = 1024

# the NACA 4-digit thickness coefficients (Abbott & von Doenhoff, "Theory of Wing Sections",
# 1959, sec. 6.4; Jacobs, Ward & Pinkerton, NACA Report 460, 1933):
# y_t = 5 t (a0 sqrt(x) + a1 x + a2 x^2 + a3 x^3 + a4 x^4)
_NACA_A = (0.2969, -0.1260, -0.3516, 0.2843)
_A4_OPEN = -0.1015  # the classic coefficient: a finite trailing-edge thickness (0.00252 for t = 0.12)
_A4_CLOSED = -0.1036  # the modified one that closes the trailing edge (y_t(1) = 0 to 4 decimals)

_NUM = r"[-+]?(?:(?:\d+\.?\d*|\.\d+)(?:[eEdD][-+]?\d+)?|nan|inf(?:inity)?)"  # nan/inf: then "non-finite"
_TWO_NUMBERS = re.compile(rf"^\s*({_NUM})\s*[,;\s]\s*({_NUM})\s*$", re.IGNORECASE)


# ---------------------------------------------------------------------------------------------
# validation


def signed_area(polygon: np.ndarray) -> float:
    """Shoelace area: positive for a counter-clockwise polygon."""
    p = np.asarray(polygon, dtype=np.float64)
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _first_self_intersection(p: np.ndarray) -> tuple[int, int] | None:
    """The first pair of non-adjacent edges (i, j) that touch or cross, else None (O(n^2),
    vectorised per edge; exact orientation signs are not needed for a validation)."""
    n = len(p)
    a, b = p, np.roll(p, -1, axis=0)
    lo, hi = np.minimum(a, b), np.maximum(a, b)

    def orient(p0, p1, q):
        return (p1[..., 0] - p0[..., 0]) * (q[..., 1] - p0[..., 1]) - (p1[..., 1] - p0[..., 1]) * (q[..., 0] - p0[..., 0])

    for i in range(n):
        j = np.arange(i + 2, n)
        if i == 0:
            j = j[j != n - 1]  # edge n-1 shares vertex 0 with edge 0
        if not len(j):
            continue
        box = np.all((lo[j] <= hi[i]) & (hi[j] >= lo[i]), axis=1)
        j = j[box]
        if not len(j):
            continue
        d1 = orient(a[i], b[i], a[j])
        d2 = orient(a[i], b[i], b[j])
        d3 = orient(a[j], b[j], a[i][None, :])
        d4 = orient(a[j], b[j], b[i][None, :])
        hit = (d1 * d2 <= 0) & (d3 * d4 <= 0)
        # collinear disjoint segments pass the sign test only when their boxes overlap,
        # which the box filter above already required: touching counts as intersecting
        if np.any(hit):
            return i, int(j[np.argmax(hit)])
    return None


def validate_polygon(polygon, name: str = "polygon") -> np.ndarray:
    """Check that `polygon` is a simple, counter-clockwise polygon of shape (N, 2), N >= 3,
    finite, without a repeated closing vertex or repeated consecutive vertices, and without
    self-intersections. Returns it as float64; raises a one-line ValueError otherwise."""
    p = np.asarray(polygon, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"{name}: expected an array of shape (N, 2), got shape {p.shape}")
    if len(p) < 3:
        raise ValueError(f"{name}: a polygon needs at least 3 vertices, got {len(p)}")
    if len(p) > MAX_VERTICES:
        raise ValueError(f"{name}: {len(p):,} vertices, at most {MAX_VERTICES}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{name}: vertex {int(np.argmin(np.all(np.isfinite(p), axis=1)))} is not finite")
    if np.array_equal(p[0], p[-1]):
        raise ValueError(f"{name}: the last vertex repeats the first (give the polygon without its closing point)")
    same = np.all(p == np.roll(p, -1, axis=0), axis=1)
    if np.any(same):
        i = int(np.argmax(same))
        raise ValueError(f"{name}: vertices {i} and {(i + 1) % len(p)} coincide at {tuple(p[i])}")
    hit = _first_self_intersection(p)
    if hit is not None:
        raise ValueError(f"{name}: the polygon intersects itself (edges {hit[0]} and {hit[1]})")
    area = signed_area(p)
    if not area > 0:
        raise ValueError(
            f"{name}: the polygon is {'clockwise' if area < 0 else 'degenerate (zero area)'}; "
            "it must be counter-clockwise"
        )
    return p


# ---------------------------------------------------------------------------------------------
# normalisation and placement


def normalize(polygon: np.ndarray, trailing_edge=None) -> np.ndarray:
    """Chord units: the leading edge (the vertex farthest from the trailing edge) moved to
    the origin, the chord line rotated onto +x and scaled to length 1. The trailing edge
    defaults to the first vertex (the Selig start, a sharp trailing edge); give the midpoint
    of a finite trailing-edge gap explicitly. The vertex order is kept."""
    p = np.asarray(polygon, dtype=np.float64)
    te = p[0] if trailing_edge is None else np.asarray(trailing_edge, dtype=np.float64)
    le = p[int(np.argmax(np.sum((p - te) ** 2, axis=1)))]
    chord = te - le
    c = float(np.hypot(*chord))
    if not c > 0:
        raise ValueError("normalize: zero chord")
    cos, sin = chord / c
    rot = np.array([[cos, sin], [-sin, cos]])  # rotates the chord direction onto +x
    out = (p - le) @ rot.T / c
    out[np.all(p == le, axis=1)] = 0.0  # the leading edge exactly at the origin
    return out


def place(polygon, chord: float, angle_of_attack_deg: float, leading_edge=(0.0, 0.0)) -> np.ndarray:
    """The section in scene coordinates: scaled to `chord`, rotated about the leading edge
    (the origin of the chord-unit polygon) by the angle of attack, positive nose up for a
    flow along +x (the trailing edge moves down), and the leading edge moved to
    `leading_edge`. A clockwise rotation keeps the polygon counter-clockwise."""
    p = np.asarray(polygon, dtype=np.float64)
    if not (chord > 0 and math.isfinite(chord)):
        raise ValueError(f"place: chord must be positive and finite, got {chord}")
    a = math.radians(angle_of_attack_deg)
    c, s = math.cos(a), math.sin(a)
    rot = np.array([[c, s], [-s, c]])  # clockwise by a: (1, 0) -> (cos a, -sin a)
    return (chord * p) @ rot.T + np.asarray(leading_edge, dtype=np.float64)


# ---------------------------------------------------------------------------------------------
# .dat files


def _parse_pair(text: str):
    m = _TWO_NUMBERS.match(text)
    if not m:
        return None
    return tuple(float(v.replace("d", "e").replace("D", "e")) for v in m.groups())


def read_dat(path, normalize_chord: bool = True) -> np.ndarray:
    """Read a Selig or a Lednicer airfoil file.

    Selig: a title line, then x y pairs from the trailing edge over the upper surface to the
    leading edge and back along the lower surface. Lednicer: a title line, a line with the
    numbers of upper and lower points (e.g. ``36. 37.``), then the upper surface from the
    leading edge to the trailing edge and the lower surface likewise. Blank lines, ``#``
    comments and Windows line endings are accepted; numbers may be separated by spaces,
    tabs or commas. Bad input is a one-line ValueError naming the file and the line.

    Returns the counter-clockwise polygon (see the module docstring), normalised to chord
    units unless `normalize_chord` is False (then in the file's coordinates, still closed
    and counter-clockwise)."""
    path = Path(path)
    where = str(path)
    try:
        raw = read_bounded(path, AIRFOIL_FILE_BYTES, "an airfoil file")
    except OSError as e:
        raise ValueError(f"{where}: cannot read the airfoil file ({e.strerror or e})") from None
    if b"\0" in raw:  # text has no NUL bytes: an image, an archive, random bytes
        raise ValueError(f"{where}: not a text airfoil file (it holds binary data)")
    text = raw.decode("utf-8", errors="replace").replace("\r\n", "\n").replace("\r", "\n")
    rows: list[tuple[int, str]] = []  # (line number, content) without comments and blanks
    for k, line in enumerate(text.split("\n"), start=1):
        s = line.split("#", 1)[0].strip()
        if s:
            rows.append((k, s))
    if not rows:
        raise ValueError(f"{where}: empty airfoil file")
    # the title: the first line unless it is already a coordinate pair
    if _parse_pair(rows[0][1]) is not None and not _is_lednicer_counts(_parse_pair(rows[0][1])):
        body = rows
    else:
        body = rows[1:]
    if not body:
        raise ValueError(f"{where}:{rows[-1][0]}: no coordinates after the title")
    if len(body) > MAX_VERTICES + 2:  # a Lednicer count line and a repeated closing vertex at most
        raise ValueError(f"{where}: {len(body):,} coordinate lines, at most {MAX_VERTICES} vertices")

    points: list[tuple[float, float]] = []
    lines: list[int] = []
    for k, s in body:
        xy = _parse_pair(s)
        if xy is None:
            shown = s if len(s) <= 60 else s[:57] + "..."  # one readable line, not a whole file
            raise ValueError(f"{where}:{k}: expected two numbers 'x y', got {shown!r}")
        if not all(math.isfinite(v) for v in xy):
            raise ValueError(f"{where}:{k}: non-finite coordinate {s!r}")
        points.append(xy)
        lines.append(k)

    lednicer = _is_lednicer_counts(points[0])
    if lednicer:
        nu, nl = int(points[0][0]), int(points[0][1])
        pts, pl = points[1:], lines[1:]
        if len(pts) != nu + nl:
            raise ValueError(
                f"{where}:{lines[0]}: the Lednicer header announces {nu} upper and {nl} lower points, "
                f"but {len(pts)} follow"
            )
        upper, lower = pts[:nu], pts[nu:]
        _check_surface(where, upper, pl[:nu])
        _check_surface(where, lower, pl[nu:])
        if nu < 2 or nl < 2:
            raise ValueError(f"{where}:{lines[0]}: too few points ({nu} upper, {nl} lower; need at least 2 each)")
        # to the Selig order: upper reversed (TE -> LE), then lower (LE -> TE), the shared
        # leading edge once
        seq = upper[::-1] + (lower[1:] if lower[0] == upper[0] else lower)
    else:
        _check_surface(where, points, lines)
        seq = points
    p = np.array(seq, dtype=np.float64)
    te = 0.5 * (p[0] + p[-1])  # the trailing edge: the point listed at both ends, or the gap's middle
    if len(p) > 1 and np.array_equal(p[0], p[-1]):
        p = p[:-1]  # a closed trailing edge listed at both ends
    if len(p) < 3:
        raise ValueError(f"{where}:{lines[-1]}: too few points ({len(p)}; a section needs at least 3)")
    if signed_area(p) < 0:
        p = p[::-1].copy()  # written clockwise: reverse (the start stays at the trailing edge)
    if normalize_chord:
        p = normalize(p, te)
    try:
        return validate_polygon(p, where)
    except ValueError as e:
        raise ValueError(str(e)) from None


def _is_lednicer_counts(xy) -> bool:
    """A Lednicer header: two integral counts, both at least 2 (coordinates lie within [-1, 1]
    or so; no Selig coordinate pair looks like this)."""
    return xy is not None and all(v >= 2 and float(v).is_integer() for v in xy)


def _check_surface(where: str, pts, lines) -> None:
    for i in range(1, len(pts)):
        if pts[i] == pts[i - 1]:
            raise ValueError(f"{where}:{lines[i]}: duplicate point {pts[i]} (the same as the line before)")


# ---------------------------------------------------------------------------------------------
# generated sections


def _naca_digits(code: str) -> tuple[float, float, float]:
    s = str(code).lower().removeprefix("naca").strip()
    if not re.fullmatch(r"\d{4}", s):
        raise ValueError(f"naca4: expected four digits such as '2412', got {code!r}")
    m, p, t = int(s[0]) / 100.0, int(s[1]) / 10.0, int(s[2:]) / 100.0
    if t <= 0:
        raise ValueError(f"naca4: {code!r} has zero thickness")
    if (m > 0) != (p > 0):
        raise ValueError(f"naca4: {code!r}: camber and its position must both be zero or both non-zero")
    return m, p, t


def naca4_thickness(x, code: str = "0012", closed_te: bool = False):
    """Half thickness y_t(x) of the NACA 4-digit section at chord stations x in [0, 1]."""
    _, _, t = _naca_digits(code)
    x = np.asarray(x, dtype=np.float64)
    a0, a1, a2, a3 = _NACA_A
    a4 = _A4_CLOSED if closed_te else _A4_OPEN
    return 5.0 * t * (a0 * np.sqrt(x) + a1 * x + a2 * x**2 + a3 * x**3 + a4 * x**4)


def naca4_camber(x, code: str = "2412"):
    """Mean line y_c(x) and its slope dy_c/dx of the NACA 4-digit section (two parabolas
    meeting at the maximum camber m at x = p)."""
    m, p, _ = _naca_digits(code)
    x = np.asarray(x, dtype=np.float64)
    if m == 0:
        return np.zeros_like(x), np.zeros_like(x)
    fore = x < p
    yc = np.where(fore, m / p**2 * (2 * p * x - x**2), m / (1 - p) ** 2 * ((1 - 2 * p) + 2 * p * x - x**2))
    dyc = np.where(fore, 2 * m / p**2 * (p - x), 2 * m / (1 - p) ** 2 * (p - x))
    return yc, dyc


def naca4(code: str, n: int = 100, closed_te: bool = True) -> np.ndarray:
    """The NACA 4-digit section `code` ('0012', 'naca2412', ...) with n panels per surface on
    cosine spacing x = (1 - cos beta) / 2 (clustered at both edges). closed_te: the modified
    coefficient -0.1036 closing the trailing edge to a point at (1, 0); False: the classic
    -0.1015 with its finite trailing-edge gap (the base closes the polygon). Upper and lower
    points of one station are offset from the mean line along its normal (Abbott & von
    Doenhoff 1959, sec. 6.4), so their midpoint is the mean-line point."""
    if n < 4:
        raise ValueError(f"naca4: need at least 4 panels per surface, got {n}")
    beta = np.linspace(0.0, math.pi, n + 1)
    x = 0.5 * (1.0 - np.cos(beta))
    x[-1] = 1.0
    yt = naca4_thickness(x, code, closed_te)
    if closed_te:
        yt[-1] = 0.0  # -0.1036 leaves 1e-5 of the chord: close exactly
    yc, dyc = naca4_camber(x, code)
    th = np.arctan(dyc)
    xu, yu = x - yt * np.sin(th), yc + yt * np.cos(th)
    xl, yl = x + yt * np.sin(th), yc - yt * np.cos(th)
    upper = np.column_stack([xu, yu])[::-1]  # TE -> LE
    lower = np.column_stack([xl, yl])[1:]  # after the LE -> TE
    if closed_te:
        lower = lower[:-1]  # the trailing edge point once
    p = np.vstack([upper, lower])
    p[n] = 0.0  # the leading edge (x = 0, y_t = 0, y_c = 0)
    return validate_polygon(p, f"naca{str(code).lower().removeprefix('naca')}")


def flat_plate(thickness: float, rounded: bool = False, n_arc: int = 16) -> np.ndarray:
    """A flat plate of chord 1 and the given thickness (in chord units): a thin rectangle
    from x = 0 to 1, or with semicircular ends of diameter `thickness` (n_arc segments
    each) still spanning x = 0 to 1."""
    t = float(thickness)
    if not (0 < t < 1):
        raise ValueError(f"flat_plate: thickness must be in (0, 1) chord, got {thickness}")
    h = 0.5 * t
    if not rounded:
        return validate_polygon(np.array([[1.0, h], [0.0, h], [0.0, -h], [1.0, -h]]), "flat_plate")
    if n_arc < 2 or n_arc % 2:
        raise ValueError(f"flat_plate: n_arc must be even and at least 2 (a vertex at each end), got {n_arc}")
    a = np.linspace(0.5 * math.pi, 1.5 * math.pi, n_arc + 1)  # the nose, from the top round
    nose = np.column_stack([h + h * np.cos(a), h * np.sin(a)])
    tail = np.column_stack([1 - h - h * np.cos(a), -h * np.sin(a)])  # from the bottom round
    p = np.vstack([tail[-1:], nose, tail[:-1]])  # start at the top of the tail arc
    p[n_arc // 2 + 1] = (0.0, 0.0)  # the leading edge exactly
    return validate_polygon(p, "flat_plate")


# ---------------------------------------------------------------------------------------------
# names


def shipped() -> list[str]:
    """The names of the airfoil files shipped in corpuscle/data (without .dat)."""
    d = resources.files("corpuscle") / "data"
    return sorted(f.name[:-4] for f in d.iterdir() if f.name.endswith(".dat"))


def load(name) -> np.ndarray:
    """A section by name or path: a shipped file ('e398'), a NACA 4-digit code ('naca2412',
    'naca0012'; closed trailing edge), or the path of a Selig or Lednicer .dat file."""
    s = os.fspath(name)
    key = s.strip().lower()
    if re.fullmatch(r"naca\d{4}", key):
        return naca4(key)
    if key in shipped():
        with resources.as_file(resources.files("corpuscle") / "data" / f"{key}.dat") as f:
            return read_dat(f)
    if os.path.exists(s):
        return read_dat(s)
    raise ValueError(
        f"unknown airfoil {s!r}: give a .dat file path, a NACA 4-digit code such as 'naca2412', "
        f"or a shipped section ({', '.join(shipped())})"
    )
