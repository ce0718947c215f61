"""physics/mesh_body.h (through corpuscle._testing.mesh_tree_sdf): a closed mesh's triangles in the
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
