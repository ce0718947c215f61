"""physics/triangle.h and triangle_mesh.h (through corpuscle._testing): the closest point on a
triangle and its feature against a float64 NumPy brute force (faces, edges, vertices, points on
the extensions of the edges and on the surface), and the signed distance to closed meshes (a
cube with sharp edges and corners, an icosphere, a non-convex L-shaped prism) against the
float64 minimum over the triangles with the sign of the generalised winding number."""

import numpy as np
import pytest

_testing = pytest.importorskip("corpuscle._testing")
if not hasattr(_testing, "mesh_sdf"):
    pytest.skip("corpuscle._testing predates the triangle meshes (rebuild it)", allow_module_level=True)


def f32(x):
    return np.ascontiguousarray(x, dtype=np.float32)


def segment_closest(p, a, b):
    d = b - a
    t = np.clip(np.sum((p - a) * d, axis=-1) / np.sum(d * d, axis=-1), 0.0, 1.0)
    return a + t[..., None] * d, t


def reference_closest(p, a, b, c):
    """float64: the plane projection when it falls inside, else the nearest of the three edges;
    the feature (0 face, 1 ab, 2 bc, 3 ca, 4 a, 5 b, 6 c) and the distance."""
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    proj = p - np.sum((p - a) * n, axis=-1, keepdims=True) * n
    inside = np.ones(len(p), bool)
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= np.sum(np.cross(v - u, proj - u) * n, axis=-1) >= 0
    cands, feats = [proj], [np.zeros(len(p), int)]
    for k, (u, v) in enumerate(((a, b), (b, c), (c, a))):
        q, t = segment_closest(p, u, v)
        cands.append(q)
        feats.append(np.where(t <= 0, 4 + k, np.where(t >= 1, 4 + (k + 1) % 3, 1 + k)))
    d = np.stack([np.linalg.norm(p - q, axis=-1) for q in cands], 1)
    d[:, 0] = np.where(inside, d[:, 0], np.inf)
    best = np.argmin(d, axis=1)
    q = np.stack(cands, 1)[np.arange(len(p)), best]
    f = np.stack(feats, 1)[np.arange(len(p)), best]
    return q, f, d[np.arange(len(p)), best]


def triangle_probes(rng, m=4000):
    """Random triangles (some thin and obtuse) and points around them, on their planes, on the
    extensions of their edges and near their corners."""
    a = rng.normal(size=(m, 3))
    b = a + rng.normal(size=(m, 3))
    c = a + rng.normal(size=(m, 3)) * rng.choice([1.0, 0.05], size=(m, 1))
    kind = rng.integers(0, 4, m)
    w = rng.dirichlet([1, 1, 1], m)
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    s = rng.uniform(-1.5, 2.5, (m, 1))
    p = np.where(kind[:, None] == 0, a + rng.normal(size=(m, 3)) * 2,               # anywhere
        np.where(kind[:, None] == 1, w[:, :1] * a + w[:, 1:2] * b + w[:, 2:] * c,    # on the face
        np.where(kind[:, None] == 2, a + s * (b - a) + 0.3 * rng.normal(size=(m, 1)) * n,  # over ab's line
                 a + 1e-3 * rng.normal(size=(m, 3)))))                             # near a corner
    return f32(p), f32(a), f32(b), f32(c)


def test_closest_point_on_triangle_matches_float64():
    p, a, b, c = triangle_probes(np.random.default_rng(3))
    q, feature = _testing.triangle_closest(p, a, b, c)
    P, A, B, C = (x.astype(np.float64) for x in (p, a, b, c))
    qr, fr, dr = reference_closest(P, A, B, C)
    scale = np.max(np.abs(np.stack([A, B, C, P], 1)), axis=(1, 2))
    # float32 arithmetic on coordinates of order `scale`: a few ulps of it, relative to the size
    tol = 64 * np.finfo(np.float32).eps * scale * (1 + np.linalg.norm(B - A, axis=1) / np.linalg.norm(np.cross(B - A, C - A), axis=1) ** 0.5)
    d = np.linalg.norm(P - q, axis=1)
    # the distance is the minimum (never shorter than the true one, longer only by roundoff)
    assert np.all(d >= dr - tol) and np.all(d <= dr + tol)
    # the point lies on the triangle, on the feature it names
    for f, corner in ((4, A), (5, B), (6, C)):
        at = feature == f
        np.testing.assert_allclose(q[at], corner[at], atol=1e-6 * scale.max())
    # where the reference's feature is not within roundoff of a region boundary, they agree
    clear = np.abs(d - dr) < tol
    agree = (feature == fr) | ~clear
    assert agree.mean() > 0.99
    assert set(np.unique(feature)) == set(range(7))  # every feature was probed


def box_mesh(lo=(0, 0, 0), hi=(1, 1, 1)):
    """A cube of 12 outward triangles (sharp edges and corners)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[(hi if (k >> a) & 1 else lo)[a] for a in range(3)] for k in range(8)])
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    f = [[q[0], q[1], q[2]] for q in quads] + [[q[0], q[2], q[3]] for q in quads]
    return v, np.array(f, np.int64)


def l_prism():
    """A non-convex L-shaped section extruded along z, triangulated with outward winding."""
    sec = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float)
    n = len(sec)
    v = np.vstack([np.column_stack([sec, np.zeros(n)]), np.column_stack([sec, np.ones(n)])])
    caps = [[0, 1, 2], [0, 2, 3], [0, 3, 5], [3, 4, 5]]  # ccw seen from +z
    f = [[t[0], t[2], t[1]] for t in caps] + [[n + t[0], n + t[1], n + t[2]] for t in caps]
    for i in range(n):
        j = (i + 1) % n
        f += [[i, j, n + j], [i, n + j, n + i]]
    return v, np.array(f, np.int64)


def icosphere(r=0.5, levels=2):
    trimesh = pytest.importorskip("trimesh")
    m = trimesh.creation.icosphere(subdivisions=levels, radius=r)
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def winding_number(v, f, p):
    """Generalised winding number (van Oosterom & Strackee 1983 solid angles / 4 pi), float64."""
    a, b, c = (v[f[:, k]][None] - p[:, None] for k in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
    det = np.einsum("pij,pij->pi", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("pij,pij->pi", a, b) * lc + np.einsum("pij,pij->pi", b, c) * la + \
        np.einsum("pij,pij->pi", c, a) * lb
    return np.sum(2 * np.arctan2(det, den), axis=1) / (4 * np.pi)


def reference_sdf(v, f, p):
    A, B, C = (np.repeat(v[f[:, k]][None], len(p), 0) for k in range(3))
    P = np.repeat(p[:, None], len(f), 1)
    q, _, d = reference_closest(P.reshape(-1, 3), A.reshape(-1, 3), B.reshape(-1, 3), C.reshape(-1, 3))
    d = d.reshape(len(p), len(f))
    best = np.argmin(d, axis=1)
    dist = d[np.arange(len(p)), best]
    inside = winding_number(v, f, p) > 0.5
    return np.where(inside, -dist, dist), q.reshape(len(p), len(f), 3)[np.arange(len(p)), best]


@pytest.mark.parametrize("mesh", ["box", "icosphere", "l_prism"])
def test_mesh_signed_distance_matches_float64(mesh):
    v, f = {"box": box_mesh, "icosphere": icosphere, "l_prism": l_prism}[mesh]()
    rng = np.random.default_rng(7)
    lo, hi = v.min(0), v.max(0)
    pts = [rng.uniform(lo - 0.3, hi + 0.3, (1500, 3))]
    pts.append(v + 1e-3 * rng.normal(size=v.shape))                      # near every vertex
    mids = 0.5 * (v[f[:, 0]] + v[f[:, 1]])
    pts.append(mids + 1e-3 * rng.normal(size=mids.shape))                # near the edges
    w = rng.dirichlet([1, 1, 1], len(f))
    pts.append(np.einsum("fk,fkj->fj", w, v[f]))                         # on the faces
    p = f32(np.vstack(pts))
    r = _testing.mesh_sdf(v, f, p)
    ref, qref = reference_sdf(v, f, p.astype(np.float64))
    tol = 1e-5 * np.abs(v).max()
    np.testing.assert_allclose(np.abs(r["distance"]), np.abs(ref), atol=tol)
    clear = np.abs(ref) > 1e-4
    # the sign: the pseudo-normal test agrees with the winding number off the surface
    assert np.all(np.sign(r["distance"][clear]) == np.sign(ref[clear]))
    # the normal is the unit gradient, pointing out: moving along it increases the distance
    n = r["normal"]
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    step = 1e-3
    after = _testing.mesh_sdf(v, f, f32(p + step * n))["distance"]
    assert np.all(after > r["distance"] + 0.5 * step * (np.abs(r["distance"]) > 2 * step) - 1e-5)
    # off the surface the normal is (p - q) / |p - q| signed
    far = np.abs(ref) > 1e-3
    g = (p - r["closest"])[far] / r["distance"][far, None]
    np.testing.assert_allclose(n[far], g, atol=1e-3)


def test_points_on_sharp_edges_and_corners_get_outward_normals():
    v, f = box_mesh()
    # the 8 corners and 12 edge midpoints of the cube, exactly on the surface
    corners = v
    edges = np.array([0.5 * (v[i] + v[j]) for i in range(8) for j in range(i + 1, 8)
                      if np.sum(np.abs(v[i] - v[j])) == 1])
    p = f32(np.vstack([corners, edges]))
    r = _testing.mesh_sdf(v, f, p)
    assert np.all(np.abs(r["distance"]) < 1e-6)
    out = p - 0.5  # the direction from the centre
    # the pseudo-normal: the corner's diagonal, the edge's bisector
    np.testing.assert_allclose(r["normal"], out / np.linalg.norm(out, axis=1, keepdims=True), atol=1e-6)


def test_open_and_inconsistent_meshes_are_refused():
    v, f = box_mesh()
    with pytest.raises(ValueError, match="has no face on its other side"):
        _testing.mesh_sdf(v, f[:-1], f32(np.zeros((1, 3))))
    flipped = f.copy()
    flipped[3] = flipped[3, ::-1]
    with pytest.raises(ValueError, match="is run the same way by two faces"):
        _testing.mesh_sdf(v, flipped, f32(np.zeros((1, 3))))
    bad = f.copy()
    bad[0, 0] = 99
    with pytest.raises(ValueError, match="face 0 names vertex 99 of 8"):
        _testing.mesh_sdf(v, bad, f32(np.zeros((1, 3))))
