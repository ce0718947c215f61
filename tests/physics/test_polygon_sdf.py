"""physics/polygon.h (through corpuscle._testing.polygon_sdf): the signed distance, normal and
closest point against a float64 NumPy brute force (minimum distance to the segments, the sign
by an even-odd point-in-polygon test) on a square, a triangle, Eppler 398 and NACA 0012,
including points near the sharp trailing edge and on the extensions of edges."""

import numpy as np
import pytest

from corpuscle import airfoils

_testing = pytest.importorskip("corpuscle._testing")


def reference_sdf(poly, pts):
    """float64 brute force: distance to every segment, sign by crossing parity."""
    a = poly[None, :, :]
    b = np.roll(poly, -1, axis=0)[None, :, :]
    p = pts[:, None, :]
    d = b - a
    t = np.clip(np.sum((p - a) * d, axis=2) / np.sum(d * d, axis=2), 0.0, 1.0)
    q = a + t[..., None] * d
    dist = np.sqrt(np.min(np.sum((p - q) ** 2, axis=2), axis=1))
    ay, by = a[..., 1], b[..., 1]
    straddle = (ay > p[..., 1]) != (by > p[..., 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = a[..., 0] + (p[..., 1] - ay) * d[..., 0] / d[..., 1]
    inside = np.sum(straddle & (xc > p[..., 0]), axis=1) % 2 == 1
    return np.where(inside, -dist, dist), inside


def f32(x):
    return np.ascontiguousarray(x, dtype=np.float32)


SQUARE = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
TRIANGLE = np.array([[0, 0], [2, 0], [1, 1]], dtype=float)


def shapes():
    return {
        "square": SQUARE,
        "triangle": TRIANGLE,
        "e398": airfoils.place(airfoils.load("e398"), 0.5, 10.0, (-1.2, 0.0)),
        "naca0012": airfoils.naca4("0012", n=80, closed_te=True),
    }


def probe_points(poly, rng):
    lo, hi = poly.min(0), poly.max(0)
    span = hi - lo
    pts = [rng.uniform(lo - 0.3 * span, hi + 0.3 * span, size=(3000, 2))]
    te = poly[0]
    for r in (1e-4, 1e-3, 1e-2):
        phi = rng.uniform(0, 2 * np.pi, 200)
        pts.append(te + r * np.column_stack([np.cos(phi), np.sin(phi)]))
    b = np.roll(poly, -1, axis=0)
    for s in (-0.5, -0.01, 1.01, 1.5, 3.0):  # on the extensions of every edge
        pts.append(poly + s * (b - poly))
    return np.vstack(pts)


@pytest.mark.parametrize("name", ["square", "triangle", "e398", "naca0012"])
def test_sdf_matches_numpy_brute_force(name):
    rng = np.random.default_rng(7)
    poly = f32(shapes()[name]).astype(np.float64)  # the float32 polygon the kernel sees
    pts = f32(probe_points(poly, rng)).astype(np.float64)
    got = _testing.polygon_sdf(f32(poly), f32(pts))
    ref, inside = reference_sdf(poly, pts)
    scale = max(1.0, float(np.abs(poly).max()))
    tol = 4e-6 * scale
    np.testing.assert_allclose(got["distance"], ref, atol=tol, rtol=0)
    sure = np.abs(ref) > tol
    assert sure[:3000].sum() > 0.95 * 3000  # the random ones (edge extensions hug the boundary)
    np.testing.assert_array_equal(got["inside"].astype(bool)[sure], inside[sure])
    np.testing.assert_array_equal(got["distance"][sure] < 0, inside[sure])
    # the closest point is on the boundary, |d| away
    q = got["closest"].astype(np.float64)
    np.testing.assert_allclose(np.abs(reference_sdf(poly, q)[0]), 0.0, atol=tol)
    np.testing.assert_allclose(np.hypot(*(pts - q).T), np.abs(ref), atol=tol)
    # both layouts give the same answer
    by_edges = _testing.polygon_sdf(f32(poly), f32(pts), "edges")
    for k in got:
        np.testing.assert_array_equal(got[k], by_edges[k])


@pytest.mark.parametrize("name", ["square", "triangle", "e398", "naca0012"])
def test_normals_are_unit_and_point_out(name):
    rng = np.random.default_rng(3)
    poly = f32(shapes()[name]).astype(np.float64)
    pts = f32(probe_points(poly, rng)).astype(np.float64)
    got = _testing.polygon_sdf(f32(poly), f32(pts))
    n = got["normal"].astype(np.float64)
    np.testing.assert_allclose(np.hypot(*n.T), 1.0, atol=1e-6)
    d = got["distance"].astype(np.float64)
    ok = np.abs(d) > 1e-4 * max(1.0, np.abs(poly).max())
    # the normal is the gradient: a step h < |d| along it raises the signed distance by h
    h = 0.5 * np.abs(d[ok])
    after = reference_sdf(poly, pts[ok] + h[:, None] * n[ok])[0]
    np.testing.assert_allclose(after - reference_sdf(poly, pts[ok])[0], h, atol=2e-5 * max(1.0, np.abs(poly).max()))


def test_sharp_trailing_edge_of_naca0012():
    poly = airfoils.naca4("0012", n=80, closed_te=True)  # a sharp TE at vertex 0 = (1, 0)
    s = np.array([1e-5, 1e-4, 1e-3, 1e-2])
    behind = np.column_stack([1 + s, 0 * s])  # on the chord's extension, outside
    wedge = np.column_stack([1 - s, 0 * s])  # inside the thin wedge
    got = _testing.polygon_sdf(f32(poly), f32(np.vstack([behind, wedge])))
    d, n, v = got["distance"], got["normal"], got["vertex"]
    np.testing.assert_allclose(d[:4], f32(1 + s).astype(np.float64) - 1, rtol=1e-5, atol=1e-7)
    np.testing.assert_array_equal(v[:4], 0)  # the closest feature is the TE vertex
    np.testing.assert_allclose(n[:4], [[1, 0]] * 4, atol=1e-6)
    assert np.all(d[4:] < 0)
    # inside the wedge the nearer surface is pushed through, nearly vertical
    assert np.all(np.abs(n[4:, 1]) > 0.98)  # the surfaces meet at about 8 degrees to the chord
    # exactly at the TE: distance 0, the pseudo-normal along the bisector (+x)
    at = _testing.polygon_sdf(f32(poly), f32(poly[:1]))
    assert at["distance"][0] == 0.0 and at["vertex"][0] == 0
    np.testing.assert_allclose(at["normal"][0], (1.0, 0.0), atol=1e-6)


def test_points_on_the_lines_of_edges_and_through_vertices():
    # rays through vertices and along edges: the half-open rule and the exact side test
    xs = np.array([-1.0, -0.25, 1.25, 2.0, 3.0])
    sq = np.vstack([np.column_stack([xs, np.full(5, y)]) for y in (0.0, 1.0)])  # on the lines y = 0, 1
    got = _testing.polygon_sdf(f32(SQUARE), f32(sq))
    assert np.all(got["distance"] > 0) and not got["inside"].any()
    tri_pts = np.array([[-1, 1], [0.5, 1], [3, 1], [-1, 0], [3, 0], [1, 0.5], [1, 0.999], [1.5, 0.25]])
    got = _testing.polygon_sdf(f32(TRIANGLE), f32(tri_pts))
    np.testing.assert_array_equal(got["inside"].astype(bool), [False] * 5 + [True] * 3)
    on = np.array([[0.5, 0.0], [1.5, 0.5], [1.0, 1.0], [0.0, 0.0]])  # on edges and at vertices
    got = _testing.polygon_sdf(f32(TRIANGLE), f32(on))
    np.testing.assert_allclose(got["distance"], 0.0, atol=1e-7)
    np.testing.assert_allclose(np.hypot(*got["normal"].T), 1.0, atol=1e-6)
    # vertex pseudo-normals point away from the centroid for a convex polygon
    c = TRIANGLE.mean(0)
    at_vertices = _testing.polygon_sdf(f32(TRIANGLE), f32(TRIANGLE))
    assert np.all(np.sum(at_vertices["normal"] * (TRIANGLE - c), axis=1) > 0)


def test_edge_records_and_bounding_box():
    poly = shapes()["e398"]
    edges, box = _testing.polygon_edges(f32(poly))
    p32 = f32(poly)
    assert edges.shape == (len(poly), 8)
    np.testing.assert_array_equal(edges[:, 0:2], p32)
    np.testing.assert_array_equal(edges[:, 2:4], np.roll(p32, -1, axis=0))
    d = np.roll(p32, -1, axis=0).astype(np.float64) - p32
    out = np.column_stack([d[:, 1], -d[:, 0]]) / np.hypot(*d.T)[:, None]
    np.testing.assert_allclose(edges[:, 4:6], out, atol=1e-6)
    # the outward normal of a CCW polygon: the midpoint nudged along it is outside
    mid = 0.5 * (p32 + np.roll(p32, -1, axis=0)).astype(np.float64)
    assert np.all(reference_sdf(poly, mid + 1e-6 * out)[0] > 0)
    np.testing.assert_allclose(box, [*p32.min(0), *p32.max(0)])
