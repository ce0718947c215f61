"""physics/polygon_grid.h (through corpuscle._testing.polygon_grid_sdf): the airfoil's edge grid
gives, for every point within the contact reach of the boundary and every point inside, the
hit of the all-edges polygon_sdf bit for bit (distance, normal, closest point, edge, vertex,
sign), and the same inside/outside answer everywhere; farther points are reported beyond the
reach. Checked on thousands of random and adversarial points (around the sharp trailing edge,
on vertices, on edges, on the lines of edges, at exactly the reach, on cell boundaries) for
e398, NACA 0012, NACA 2412 and a flat plate at several angles and reaches, against the
brute force and a float64 NumPy reference; and each cell lists only a few of the edges."""

import numpy as np
import pytest

from corpuscle import airfoils

_testing = pytest.importorskip("corpuscle._testing")

from test_polygon_sdf import reference_sdf  # noqa: E402  (the float64 brute force)


def f32(x):
    return np.ascontiguousarray(x, dtype=np.float32)


def shape(name, aoa):
    base = {"e398": lambda: airfoils.load("e398"), "naca0012": lambda: airfoils.naca4("0012"),
            "naca2412": lambda: airfoils.naca4("2412"), "flat-plate": lambda: airfoils.flat_plate(0.02)}[name]()
    return f32(airfoils.place(base, 0.5, aoa, (-1.2, 0.0))).astype(np.float64)


def probe_points(poly, reach, cell, origin, rng):
    """Random points over the grid and the adversarial ones."""
    lo, hi = poly.min(0) - 2 * reach, poly.max(0) + 2 * reach
    b = np.roll(poly, -1, axis=0)
    pts = [rng.uniform(lo, hi, size=(4000, 2))]
    # a band hugging the boundary: points on random edges, pushed off by up to 1.5 reach either way
    k = rng.integers(0, len(poly), 4000)
    t = rng.uniform(0, 1, 4000)[:, None]
    e = b[k] - poly[k]
    nrm = np.column_stack([e[:, 1], -e[:, 0]]) / np.hypot(*e.T)[:, None]
    pts.append(poly[k] + t * e + rng.uniform(-1.5, 1.5, (4000, 1)) * reach * nrm)
    # exactly at the reach from edge midpoints, and on the edges
    mid = 0.5 * (poly + b)
    en = np.column_stack([(b - poly)[:, 1], -(b - poly)[:, 0]]) / np.hypot(*(b - poly).T)[:, None]
    pts += [mid + reach * en, mid - reach * en, mid, mid + 0.999 * reach * en]
    # the vertices themselves, and rings around the trailing edge (vertex 0) and every vertex
    pts.append(poly)
    for r in (1e-6, 1e-4, 0.3 * reach, reach, 1.01 * reach):
        phi = rng.uniform(0, 2 * np.pi, 300)
        pts.append(poly[0] + r * np.column_stack([np.cos(phi), np.sin(phi)]))
        pts.append(poly + r * np.column_stack([np.cos(phi[: len(poly)]), np.sin(phi[: len(poly)])]))
    # on the lines of the edges, beyond and before them
    for s in (-0.5, -0.01, 1.01, 1.5):
        pts.append(poly + s * (b - poly))
    # on cell boundaries and corners (the lookup's rounding)
    gx = origin[0] + cell * rng.integers(0, int((hi[0] - origin[0]) / cell) + 1, 600)
    gy = origin[1] + cell * rng.integers(0, int((hi[1] - origin[1]) / cell) + 1, 600)
    pts += [np.column_stack([gx, rng.uniform(lo[1], hi[1], 600)]), np.column_stack([rng.uniform(lo[0], hi[0], 600), gy]),
            np.column_stack([gx, gy])]
    return f32(np.vstack(pts)).astype(np.float64)


KEYS = ("distance", "normal", "closest", "edge", "vertex", "inside")


# every shape at four angles, the reaches of the default 2M and 131k runs and a coarse one
CASES = [(name, aoa, reach) for i, name in enumerate(["e398", "naca0012", "naca2412", "flat-plate"])
         for j, (aoa, reach) in enumerate(zip([-12.0, 0.0, 10.0, 37.0], np.roll([3.3e-4, 1.3e-3, 1e-2, 1.3e-3], i)))]


@pytest.mark.parametrize("name,aoa,reach", CASES)
def test_grid_hits_are_the_all_edges_hits(name, aoa, reach):
    rng = np.random.default_rng(int(aoa * 10) + 1000 + int(reach * 1e5))
    poly = shape(name, aoa)
    info = _testing.polygon_grid_sdf(f32(poly), f32(poly[:1]), reach)
    pts = probe_points(poly, reach, info["cell"], info["origin"], rng)
    grid = _testing.polygon_grid_sdf(f32(poly), f32(pts), reach)
    brute = _testing.polygon_sdf(f32(poly), f32(pts), "edges")
    within = brute["distance"] < reach  # every point in contact range, every point inside
    assert within.sum() > 3000 and (brute["distance"] < 0).sum() > 300
    for k in KEYS:
        np.testing.assert_array_equal(grid[k][within], brute[k][within], err_msg=k)
    # the sign everywhere, and farther points beyond the reach
    np.testing.assert_array_equal(grid["inside"], brute["inside"])
    assert np.all(grid["distance"][~within] >= reach)
    # listed cells hold every point within reach; the far ones none
    assert np.all(grid["flag"][within] != 0) and np.all(grid["flag"][within] != 255)
    # the float64 reference agrees where the sign is sure
    ref, inside = reference_sdf(poly, pts)
    tol = 4e-6 * max(1.0, float(np.abs(poly).max()))
    np.testing.assert_allclose(grid["distance"][within], ref[within], atol=tol, rtol=0)
    sure = within & (np.abs(ref) > tol)
    np.testing.assert_array_equal(grid["inside"][sure].astype(bool), inside[sure])


@pytest.mark.parametrize("name", ["e398", "naca2412"])
def test_cells_list_a_few_edges(name):
    poly = shape(name, 10.0)
    rng = np.random.default_rng(1)
    lo, hi = poly.min(0), poly.max(0)
    pts = f32(rng.uniform(lo, hi, (5000, 2))).astype(np.float64)
    grid = _testing.polygon_grid_sdf(f32(poly), f32(pts), 1.3e-3)
    brute = _testing.polygon_sdf(f32(poly), f32(pts), "edges")
    near = np.abs(brute["distance"]) < 1.3e-3
    assert near.sum() > 100
    assert grid["listed"][near].mean() < 0.2 * len(poly)  # not every edge
    assert grid["listed"][near].max() < len(poly)
    assert set(np.unique(grid["flag"])) <= {0, 1, 2, 3}
    assert grid["dims"][0] in (256, 257)  # cells along the longer side (ceil of a rounded ratio)


def test_a_square_grid_on_its_own_cell_lines():
    """A square whose edges lie on cell boundaries (the grid origin and cell edge are round):
    points on, just inside and just outside the edges and at the corners."""
    sq = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    reach = 0.05
    xs = np.linspace(-0.1, 1.1, 241)
    P = np.array(np.meshgrid(xs, xs)).reshape(2, -1).T
    P = np.vstack([P, sq, sq + 1e-7, sq - 1e-7])
    grid = _testing.polygon_grid_sdf(f32(sq), f32(P), reach, 16)
    brute = _testing.polygon_sdf(f32(sq), f32(P), "edges")
    within = brute["distance"] < reach
    for k in KEYS:
        np.testing.assert_array_equal(grid[k][within], brute[k][within], err_msg=k)
    np.testing.assert_array_equal(grid["inside"], brute["inside"])
