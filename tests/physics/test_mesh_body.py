"""dem/mesh_body.h (through corpuscle._testing.mesh_tree_sdf): a closed mesh's triangles in the
LBVH over their boxes, queried on every backend against the brute force over every triangle
(physics/triangle.h's mesh_sdf, itself checked against float64 in test_triangle.py): the exact
nearest point for points near, far outside and deep inside, and the contact query within a reach."""

import numpy as np
import pytest

_testing = pytest.importorskip("corpuscle._testing")
if not hasattr(_testing, "mesh_tree_sdf"):
    pytest.skip("corpuscle._testing predates the triangle tree (rebuild it)", allow_module_level=True)

from test_triangle import box_mesh, f32, icosphere, l_prism  # noqa: E402


def shipped_sphere():
    trimesh = pytest.importorskip("trimesh")
    from importlib.resources import files

    m = trimesh.load(files("corpuscle") / "data" / "meshes" / "sphere.stl", force="mesh")
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


MESHES = {"box": box_mesh, "icosphere": lambda: icosphere(0.5, 3), "l_prism": l_prism, "sphere.stl": shipped_sphere}


def probes(v, f, rng):
    lo, hi = v.min(0), v.max(0)
    size = float((hi - lo).max())
    w = rng.dirichlet([1, 1, 1], len(f))
    on = np.einsum("fk,fkj->fj", w, v[f])
    return f32(np.vstack([rng.uniform(lo - 0.5 * size, hi + 0.5 * size, (2000, 3)),  # around, inside, far
                          on + 0.01 * size * rng.normal(size=on.shape),            # near the surface
                          v + 1e-4 * size * rng.normal(size=v.shape),              # at the vertices
                          0.5 * (lo + hi) + 0.02 * size * rng.normal(size=(50, 3)),  # deep inside
                          hi + 3 * size]))                                          # far away


@pytest.mark.parametrize("mesh", list(MESHES))
def test_tree_finds_the_nearest_point(backend, mesh):
    v, f = MESHES[mesh]()
    p = probes(v, f, np.random.default_rng(11))
    ref = _testing.mesh_sdf(v, f, p)
    size = float((v.max(0) - v.min(0)).max())
    r = _testing.mesh_tree_sdf(backend, v, f, p, reach=0.01 * size, exact=True)
    assert r["overflow"] == 0
    assert np.all(r["triangle"] >= 0)
    if backend == "cuda":  # the device may contract products into fused multiply-adds
        np.testing.assert_allclose(r["distance"], ref["distance"], atol=2e-6 * size)
    else:  # the same float operations on the same candidates: the same minimum, bit for bit
        np.testing.assert_array_equal(r["distance"], ref["distance"])
    # the closest point is at that distance; where it is the brute force's point (all but exact
    # ties: a point deep inside a sphere equally near two faces), the normal is the same
    np.testing.assert_allclose(np.linalg.norm(p.astype(float) - r["closest"], axis=1), np.abs(ref["distance"]),
                               rtol=1e-5, atol=2e-6 * size)
    same = np.all(np.abs(r["closest"] - ref["closest"]) <= 2e-6 * size, axis=1)
    assert same.mean() > 0.99
    np.testing.assert_allclose(r["normal"][same], ref["normal"][same], atol=1e-5)


@pytest.mark.parametrize("mesh", ["icosphere", "l_prism"])
def test_contact_query_within_a_reach(backend, mesh):
    v, f = MESHES[mesh]()
    p = probes(v, f, np.random.default_rng(5))
    ref = _testing.mesh_sdf(v, f, p)
    reach = 0.02 * float((v.max(0) - v.min(0)).max())
    r = _testing.mesh_tree_sdf(backend, v, f, p, reach=reach, exact=False)
    within = np.abs(ref["distance"]) <= reach
    assert within.sum() > 100
    # every point within the reach gets the mesh's nearest point; a point with no triangle in
    # its cube is farther than the reach
    np.testing.assert_allclose(r["distance"][within], ref["distance"][within], atol=2e-6)
    assert np.all(np.abs(ref["distance"][r["triangle"] < 0]) > reach)


def test_contact_force_follows_the_law_at_faces_edges_and_corners(backend):
    if not hasattr(_testing, "mesh_contact"):
        pytest.skip("corpuscle._testing predates mesh_contact (rebuild it)")
    v, f = box_mesh()  # the unit cube
    k, c, r = 5e4, 50.0, 0.05
    x = f32([[0.5, 0.5, 1.03], [0.5, 0.5, 0.98], [0.5, 0.5, 1.2], [1.02, 0.5, 1.02], [1.02, 1.02, 1.02]])
    u = f32([[0.3, 0.0, -2.0], [0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, -1.0], [0.0, 0.0, 0.0]])
    out = _testing.mesh_contact(backend, v, f, x, u, r, k, c)
    F = out["force"]
    np.testing.assert_allclose(F[0], [0.0, 0.0, k * (r - 0.03) + c * 2.0], rtol=1e-5)  # above a face
    np.testing.assert_allclose(F[1], [0.0, 0.0, k * (r + 0.02)], rtol=1e-5)  # just inside: out through the top
    np.testing.assert_array_equal(F[2], [0.0, 0.0, 0.0])  # apart
    n = np.array([1.0, 0.0, 1.0]) / np.sqrt(2)  # from the edge, along the bisector
    np.testing.assert_allclose(F[3], (k * (r - 0.02 * np.sqrt(2)) + c * np.sqrt(2)) * n, rtol=1e-4)
    n = np.ones(3) / np.sqrt(3)  # from the corner
    np.testing.assert_allclose(F[4], k * (r - 0.02 * np.sqrt(3)) * n, rtol=1e-4)
    np.testing.assert_allclose(out["magnitude"], np.linalg.norm(F, axis=1), rtol=1e-6)
    # only the centre inside was moved: back out through the nearest face, its velocity kept
    # (it was not moving in)
    np.testing.assert_array_equal(out["moved"], [0, 1, 0, 0, 0])
    assert 1.0 < out["x"][1, 2] <= 1.0 + 0.05 * r + 1e-6
    np.testing.assert_allclose(out["x"][1, :2], [0.5, 0.5])


@pytest.mark.parametrize("mesh", ["icosphere", "l_prism", "sphere.stl"])
def test_keep_out_leaves_no_centre_inside(backend, mesh):
    if not hasattr(_testing, "mesh_contact"):
        pytest.skip("corpuscle._testing predates mesh_contact (rebuild it)")
    v, f = MESHES[mesh]()
    rng = np.random.default_rng(2)
    lo, hi = v.min(0), v.max(0)
    size = float((hi - lo).max())
    x = f32(rng.uniform(lo - 0.1 * size, hi + 0.1 * size, (3000, 3)))
    u = f32(rng.normal(size=x.shape))
    r = 0.01 * float((hi - lo).max())
    ref = _testing.mesh_sdf(v, f, x)
    before = ref["distance"]
    out = _testing.mesh_contact(backend, v, f, x, u, r, 1e4, 0.0)
    inside = before < 0
    assert inside.sum() > 100
    np.testing.assert_array_equal(out["moved"].astype(bool), inside)
    after = _testing.mesh_sdf(v, f, f32(out["x"]))["distance"]
    assert np.all(after >= 0.0)  # no centre ends inside
    assert np.all(after[inside] <= 0.05 * r * 2 ** 8 + 1e-6)  # put back on the surface
    # the velocity's component along the surface normal it left through now points out
    # (reflected where it pointed in)
    n = ref["normal"][inside]
    assert np.all(np.sum(out["v"][inside] * n, axis=1) >= -1e-4)
    np.testing.assert_array_equal(out["x"][~inside], x[~inside])
