"""Closed-form momentum transfer to a body in a collisionless (free-molecular) gas: the
reference `corpuscle validate wind-tunnel` and `corpuscle polar` compare the wind tunnel
with.

A surface element with outward unit normal n in a free stream of number density n_inf,
particle mass m, drift U (unit direction u) and temperature T (most probable thermal speed
c_m = sqrt(2 k T / m), speed ratio S = U / c_m; S = inf: the cold beam) receives the particles
whose velocity points into it. Let s_n = S cos(theta), cos(theta) = -u . n the normal
component of the stream towards the element. The incident normal momentum flux is (the
moments of a one-dimensional drifting Maxwellian over w > 0: Schaaf & Chambre, "Flow of
rarefied gases", in Fundamentals of Gas Dynamics, Princeton 1958, sec. H.4; Bird, "Molecular
Gas Dynamics and the Direct Simulation of Gas Flows", Oxford 1994, sec. 7.2, eqs. 7.31-7.36)

    p_i = rho c_m^2 / (2 sqrt(pi)) [ s_n exp(-s_n^2) + sqrt(pi) (1/2 + s_n^2) (1 + erf s_n) ]

A frictionless wall that returns each particle's normal velocity times e (restitution e;
e = 1: specular reflection) and keeps its tangential velocity takes the normal momentum
(1 + e) p_i per unit area and no shear, so with q = rho U^2 / 2 the pressure coefficient is

    C_p(s_n) = (1 + e) / S^2 [ (s_n / sqrt(pi)) exp(-s_n^2) + (1/2 + s_n^2) (1 + erf s_n) ]

(for e = 1 Bird's eq. 7.46 with the specular accommodation), and for the cold beam (S -> inf)
the Newtonian law C_p = 2 (1 + e) cos^2(theta) on the windward side, 0 on the lee side.

A thin flat plate at angle of attack alpha (both faces, windward s_n = S sin alpha, lee
-S sin alpha) has no axial force, and its normal-force coefficient (per chord) is

    C_N = (1 + e) (2 / S^2) [ (s / sqrt(pi)) exp(-s^2) + (1/2 + s^2) erf(s) ],  s = S sin alpha
    C_N = 2 (1 + e) sin^2(alpha) sign(alpha)                                   (cold beam)

with C_L = C_N cos alpha, C_D = C_N sin alpha (plus C_A terms for a plate of finite
thickness). In free-molecular flow a convex body neither shadows nor re-hits itself, so its
force is the integral of -C_p n over its surface: :func:`convex_body` does that for the
surface the simulated particle centres actually touch, the polygon offset by the particle
radius (its edges, moved out by r, and circular arcs of radius r at its vertices, by
Gauss-Legendre quadrature), which tends to the thin-plate result as the thickness and the
radius go to zero.

The same holds in 3-D, per unit span, for a section extruded along z (the wind-tunnel-3d
kind, span-periodic): every surface normal n lies in the x-y plane, and p_i above uses only
the marginal of the velocity component w = c . n. For the 3-D drifting Maxwellian
f(c) = n_inf (pi c_m^2)^(-3/2) exp(-|c - U|^2 / c_m^2), write c in an orthonormal basis
(n, t, z); the exponent is the sum of the three components' squares, so f factorises and the
integrals over the t and z components are 1: the marginal of w is
(pi c_m^2)^(-1/2) exp(-(w - U . n)^2 / c_m^2), the same 1-D drifting Maxwellian as the 2-D
gas's (whose marginal is found the same way with one tangential component). The reflection
changes only w (frictionless, restitution e), so the t and z components carry no force; C_p,
thin_plate and convex_body hold unchanged with rho = m n_inf the mass per unit volume and the
force per unit span.

A sphere (a 3-D body, :func:`sphere`): with mu = cos(theta) = -u . n over the sphere of radius R
(dA = 2 pi R^2 dmu), the drag per q pi R^2 is C_D = 2 int_{-1}^{1} C_p(S mu) mu dmu. With the
C_p above the integral is elementary (substitute s = S mu; the erf terms by parts):

    C_D = (1 + e) / 2 [ (2 S^2 + 1) / (sqrt(pi) S^3) exp(-S^2) + (4 S^4 + 4 S^2 - 1) / (2 S^4) erf(S) ]

which for e = 1 is the specular sphere of the free-molecular literature (Schaaf & Chambre 1958; Bird 1994, ch. 7), and tends
to the Newtonian 1 + e (2 for specular) as S -> inf. The DEM particles touch the body when their
centres reach the sphere of radius R + r (the body's radius plus the particle's), so R there is
that sum; a sphere neither shadows nor re-hits itself, so nothing else enters.

A convex polyhedron (:func:`convex_polyhedron`: a sphere as the triangles of a mesh, which is
what the wind tunnel's body is) offset by the particle radius r, the surface the centres touch:
its surface area measure over the normal directions is (Steiner's formula for the Minkowski
sum K + rB; Schneider, "Convex Bodies: the Brunn-Minkowski Theory", 2nd ed., sec. 4.2) the
faces' (area A_f at normal n_f), the edges' cylinders (r |e| dphi over the arc of normals
from one adjacent face's normal to the other's) and the vertices' spherical patches, whose
normals together cover the whole sphere once with r^2 dOmega. The force is the integral of
-q C_p n over that measure, so the drag is

    D / q = sum_f A_f mu_f C_p(mu_f) + r sum_e |e| int_arc mu C_p(mu) dphi + pi r^2 C_D,sphere(S, e)

(mu = -u . n; the last term the sphere of radius r), the faces exactly, the arcs by
Gauss-Legendre quadrature. As the facets shrink it tends to the sphere of radius R + r.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["pressure_coefficient", "thin_plate", "convex_body", "sphere", "convex_polyhedron", "body_axes",
           "flux_factor"]

_SQPI = math.sqrt(math.pi)


def _erf(x):
    x = np.asarray(x, dtype=np.float64)
    return np.vectorize(math.erf, otypes=[np.float64])(x) if x.ndim else np.float64(math.erf(float(x)))


def pressure_coefficient(cos_in, speed_ratio: float = math.inf, restitution: float = 1.0):
    """C_p of a frictionless surface element; cos_in = -u . n (> 0: the stream approaches it)."""
    c = np.asarray(cos_in, dtype=np.float64)
    e = float(restitution)
    if not math.isfinite(speed_ratio):
        return 2.0 * (1.0 + e) * np.where(c > 0.0, c * c, 0.0)
    S = float(speed_ratio)
    s = S * c
    return (1.0 + e) / (S * S) * (s / _SQPI * np.exp(-s * s) + (0.5 + s * s) * (1.0 + _erf(s)))


def thin_plate(alpha_deg, speed_ratio: float = math.inf, restitution: float = 1.0) -> dict[str, np.ndarray]:
    """C_N, C_A, C_L, C_D of an infinitely thin frictionless flat plate (closed form)."""
    a = np.radians(np.asarray(alpha_deg, dtype=np.float64))
    e = float(restitution)
    if math.isfinite(speed_ratio):
        S = float(speed_ratio)
        s = S * np.sin(a)
        cn = (1.0 + e) * 2.0 / (S * S) * (s / _SQPI * np.exp(-s * s) + (0.5 + s * s) * _erf(s))
    else:
        cn = 2.0 * (1.0 + e) * np.sin(a) ** 2 * np.sign(a)
    return {"cn": cn, "ca": np.zeros_like(cn), "cl": cn * np.cos(a), "cd": cn * np.sin(a)}


def _gauss(n: int):
    x, w = np.polynomial.legendre.leggauss(n)
    return x, w


def convex_body(polygon, radius: float, chord: float, speed_ratio: float = math.inf, restitution: float = 1.0,
                stream=(1.0, 0.0), nodes: int = 64) -> dict[str, float]:
    """Force coefficients (per q * chord) on a convex counter-clockwise polygon offset by
    `radius`: C_D along the stream, C_L normal to it (the stream rotated by +90 degrees)."""
    P = np.asarray(polygon, dtype=np.float64)
    u = np.asarray(stream, dtype=np.float64)
    u = u / np.linalg.norm(u)
    a, b = P, np.roll(P, -1, axis=0)
    d = b - a
    L = np.hypot(d[:, 0], d[:, 1])
    keep = L > 0
    a, d, L = a[keep], d[keep], L[keep]
    n = np.column_stack([d[:, 1], -d[:, 0]]) / L[:, None]  # outward for counter-clockwise
    cross = d[:, 0] * np.roll(d, -1, axis=0)[:, 1] - d[:, 1] * np.roll(d, -1, axis=0)[:, 0]
    if np.any(cross < -1e-12 * np.max(L) ** 2):
        raise ValueError("convex_body: the polygon is not convex (or not counter-clockwise)")
    F = np.zeros(2)
    cp = pressure_coefficient(-(n @ u), speed_ratio, restitution)
    F -= (cp * L) @ n
    if radius > 0:
        x, w = _gauss(nodes)
        th = np.arctan2(n[:, 1], n[:, 0])
        th_next = np.roll(th, -1)
        turn = np.mod(th_next - th, 2.0 * math.pi)  # the arc at the vertex between edge k and k + 1
        for t0, dt in zip(th, turn):
            if dt <= 0:
                continue
            phi = t0 + 0.5 * dt * (x + 1.0)
            nn = np.column_stack([np.cos(phi), np.sin(phi)])
            c = pressure_coefficient(-(nn @ u), speed_ratio, restitution)
            F -= (0.5 * dt * radius) * ((w * c) @ nn)
    lift_dir = np.array([-u[1], u[0]])
    return {"cd": float(F @ u) / chord, "cl": float(F @ lift_dir) / chord}


def sphere(speed_ratio: float = math.inf, restitution: float = 1.0) -> float:
    """The drag coefficient (per q pi R^2) of a frictionless sphere in free-molecular flow, closed form."""
    e = float(restitution)
    if not math.isfinite(speed_ratio):
        return 1.0 + e
    S = float(speed_ratio)
    if not S > 0.0:
        raise ValueError(f"speed_ratio must be positive, got {speed_ratio}")
    return 0.5 * (1.0 + e) * ((2 * S * S + 1) / (_SQPI * S ** 3) * math.exp(-S * S)
                              + (4 * S ** 4 + 4 * S * S - 1) / (2 * S ** 4) * math.erf(S))


def convex_polyhedron(vertices, faces, radius: float, speed_ratio: float = math.inf, restitution: float = 1.0,
                      stream=(1.0, 0.0, 0.0), order: int = 16) -> np.ndarray:
    """The force over q (m^2: a force coefficient times its area) on a closed convex triangle
    mesh (outward faces) offset by ``radius``, in a free-molecular stream along ``stream``
    (see the module's docstring): faces exactly, the edges' cylinders by Gauss-Legendre
    quadrature of ``order`` points, the vertices' patches as the sphere of that radius."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    u = np.asarray(stream, dtype=np.float64)
    u = u / np.linalg.norm(u)
    t = v[f]
    cr = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    area = 0.5 * np.linalg.norm(cr, axis=1)
    n = cr / (2.0 * area[:, None])
    F = -(area * pressure_coefficient(-(n @ u), speed_ratio, restitution)) @ n
    r = float(radius)
    if r > 0.0:
        # each undirected edge and its two faces' normals
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        face = np.tile(np.arange(len(f)), 3)
        key = np.sort(e, axis=1)
        order_ = np.lexsort((key[:, 1], key[:, 0]))
        key, face = key[order_], face[order_]
        if len(key) % 2 or not np.all(key[0::2] == key[1::2]):
            raise ValueError("the mesh is not closed (an edge without exactly two faces)")
        a, b = key[0::2], key[1::2]
        n1, n2 = n[face[0::2]], n[face[1::2]]
        length = np.linalg.norm(v[a[:, 1]] - v[a[:, 0]], axis=1)
        cosang = np.clip(np.einsum("ij,ij->i", n1, n2), -1.0, 1.0)
        ang = np.arccos(cosang)
        w = n2 - cosang[:, None] * n1
        wl = np.linalg.norm(w, axis=1)
        ok = wl > 1e-12
        tdir = np.zeros_like(w)
        tdir[ok] = w[ok] / wl[ok, None]
        x, wq = np.polynomial.legendre.leggauss(int(order))
        for xk, wk in zip(x, wq):
            phi = 0.5 * ang * (xk + 1.0)
            nn = np.cos(phi)[:, None] * n1 + np.sin(phi)[:, None] * tdir
            c = pressure_coefficient(-(nn @ u), speed_ratio, restitution)
            F -= (r * length * 0.5 * ang * wk * c) @ nn
        F += math.pi * r * r * sphere(speed_ratio, restitution) * u
    return F


def body_axes(cl, cd, alpha_deg) -> tuple:
    """(C_N, C_A) from (C_L, C_D) at angle of attack alpha (nose up positive, flow along +x):
    C_N normal to the chord (upwards), C_A along it towards the trailing edge."""
    a = np.radians(alpha_deg)
    return cd * np.sin(a) + cl * np.cos(a), cd * np.cos(a) - cl * np.sin(a)


def flux_factor(speed_ratio: float) -> float:
    """One-sided number flux of the drifting Maxwellian through a plane normal to it, over
    n_inf U: exp(-S^2) / (2 sqrt(pi) S) + (1 + erf S) / 2 (1 for the cold beam)."""
    S = float(speed_ratio)
    if not math.isfinite(S):
        return 1.0
    return math.exp(-S * S) / (2.0 * _SQPI * S) + 0.5 * (1.0 + math.erf(S))
