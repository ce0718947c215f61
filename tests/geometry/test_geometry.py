"""corpuscle.geometry: the [[bodies]] schema, meshes and their checks, placement, mass
properties, signed distance and boundary sampling, against closed forms and independent
constructions (trimesh's own primitives, NumPy)."""

import math
import sys

import numpy as np
import pytest

from corpuscle import geometry as g
from corpuscle.scene import _check_array
from corpuscle.schema import SceneError, SceneKind

trimesh = pytest.importorskip("trimesh")


def entries(dim, *items):
    kind = SceneKind("t", "", {}, arrays={"bodies": g.body_keys(dim)})
    out = _check_array("bodies", list(items), kind)
    g.check_bodies({"bodies": out}, dim)
    return out


def body(dim=3, **entry):
    return g.make_body(entries(dim, entry)[0], 1, dim)


def write(mesh, path):
    mesh.export(str(path))
    return str(path)


# ----- placement ---------------------------------------------------------------------------


def test_rotation_order_is_x_then_y_then_z_about_fixed_axes():
    R = g.rotation_matrix([90, 0, 90])
    # x: Rx leaves it, Rz turns it to y
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0])
    # y: Rx turns it to z, Rz leaves z
    assert np.allclose(R @ [0, 1, 0], [0, 0, 1])
    assert np.allclose(g.rotation_matrix([0, 90, 0]) @ [0, 0, 1], [1, 0, 0])
    assert np.allclose(g.rotation_matrix(90) @ [1, 0], [0, 1])


def test_units_scale_position_rotation_of_a_mesh(tmp_path):
    f = write(trimesh.creation.box(extents=[20, 40, 60]), tmp_path / "b.stl")  # in mm
    b = body(shape="mesh", file=f, units="mm", scale=2.0, position=[1, 2, 3], rotation=[0, 0, 90])
    lo, hi = b.bounds()
    # 40 x 80 x 120 mm, turned 90 degrees about z: x and y swap
    assert np.allclose(hi - lo, [0.08, 0.04, 0.12])
    assert np.allclose(0.5 * (lo + hi), [1, 2, 3])


# ----- mass properties ---------------------------------------------------------------------


@pytest.mark.parametrize("rotation", [[0, 0, 0], [30, -20, 75]])
def test_mesh_mass_properties_match_the_primitive(tmp_path, rotation):
    f = write(trimesh.creation.box(extents=[0.2, 0.4, 0.6]), tmp_path / "b.ply")
    m = g.mass_properties(body(shape="mesh", file=f, position=[1, -1, 2], rotation=rotation, density=700.0))
    p = g.mass_properties(body(shape="box", size=[0.2, 0.4, 0.6], position=[1, -1, 2], rotation=rotation,
                               density=700.0))
    # a PLY's vertices are float32: 1e-7 of the size
    assert p["mass"] == pytest.approx(700.0 * 0.048, rel=1e-12)
    assert m["mass"] == pytest.approx(p["mass"], rel=1e-6)
    assert np.allclose(m["center"], [1, -1, 2], atol=1e-7)
    assert np.allclose(m["inertia"], p["inertia"], rtol=1e-6, atol=1e-8)
    # a rotated inertia keeps its eigenvalues: m (b^2 + c^2) / 12, ...
    ev = np.sort(np.linalg.eigvalsh(p["inertia"]))
    mass, (a, b_, c) = 700.0 * 0.048, (0.2, 0.4, 0.6)
    assert np.allclose(ev, np.sort([mass * (b_**2 + c**2) / 12, mass * (a**2 + c**2) / 12, mass * (a**2 + b_**2) / 12]))


def test_sphere_and_cylinder_mass_properties_converge_to_the_fine_mesh(tmp_path):
    f = write(trimesh.creation.icosphere(subdivisions=5, radius=0.3), tmp_path / "s.stl")
    m = g.mass_properties(body(shape="mesh", file=f, density=1000.0))
    p = g.mass_properties(body(shape="sphere", radius=0.3, density=1000.0))
    assert m["mass"] == pytest.approx(p["mass"], rel=2e-3)
    assert np.allclose(m["inertia"], p["inertia"], rtol=4e-3, atol=1e-9)
    f = write(trimesh.creation.cylinder(radius=0.1, height=0.5, sections=256), tmp_path / "c.stl")
    m = g.mass_properties(body(shape="mesh", file=f, density=10.0, rotation=[90, 0, 0]))
    p = g.mass_properties(body(shape="cylinder", radius=0.1, height=0.5, density=10.0, rotation=[90, 0, 0]))
    assert m["mass"] == pytest.approx(p["mass"], rel=1e-3)
    assert np.allclose(m["inertia"], p["inertia"], rtol=1e-3, atol=1e-9)


def test_2d_mass_properties():
    b = g.mass_properties(body(2, shape="box", size=[0.3, 0.1], density=500.0))
    assert b["mass"] == pytest.approx(15.0) and b["inertia"] == pytest.approx(15.0 * 0.1 / 12)
    c = g.mass_properties(body(2, shape="circle", radius=0.2, density=100.0))
    assert c["mass"] == pytest.approx(100 * math.pi * 0.04) and c["inertia"] == pytest.approx(0.5 * c["mass"] * 0.04)


# ----- shipped meshes ----------------------------------------------------------------------


def test_shipped_meshes_are_closed_and_of_their_documented_size():
    meshes = g.shipped_meshes()
    assert set(meshes) >= {"sphere", "wing_naca0012"}
    s = body(shape="mesh", file=meshes["sphere"])
    assert np.allclose(np.linalg.norm(s.vertices, axis=1), 0.05)
    w = body(shape="mesh", file=meshes["wing_naca0012"])
    lo, hi = w.bounds()
    assert np.allclose(hi - lo, [0.1, 0.2, 0.012], atol=2e-4)
    # NACA 0012's area is 0.0822 c^2 (Abbott & von Doenhoff); times the span
    assert g.mass_properties(w, 1.0)["volume"] == pytest.approx(0.0822 * 0.01 * 0.2, rel=0.02)


# ----- bad input ---------------------------------------------------------------------------


def one_line(excinfo):
    msg = str(excinfo.value)
    assert "\n" not in msg
    return msg


def test_bad_mesh_files(tmp_path):
    box = trimesh.creation.box(extents=[1, 1, 1])
    holed = trimesh.Trimesh(box.vertices, box.faces[:-1], process=False)
    flipped_one = box.faces.copy()
    flipped_one[0] = flipped_one[0][::-1]
    cases = {
        "holed.stl": (holed, "not watertight"),
        "winding.ply": (trimesh.Trimesh(box.vertices, flipped_one, process=False), "inconsistent"),
        "inward.obj": (trimesh.Trimesh(box.vertices, box.faces[:, ::-1], process=False), "inward"),
    }
    for name, (mesh, fault) in cases.items():
        f = write(mesh, tmp_path / name)
        with pytest.raises(SceneError) as e:
            body(shape="mesh", file=f)
        msg = one_line(e)
        assert fault in msg and name in msg and "bodies[1].file" in msg
    # a degenerate triangle
    v = np.vstack([box.vertices, [[0.5, 0.5, 0.5]]])
    f = tmp_path / "degenerate.obj"
    f.write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v) + "".join(f"f {a+1} {b+1} {c+1}\n" for a, b, c in box.faces)
                 + "f 1 1 2\n")
    with pytest.raises(SceneError) as e:
        body(shape="mesh", file=str(f))
    assert "degenerate" in one_line(e)
    # not a mesh at all, no triangles, a wrong extension
    (tmp_path / "junk.stl").write_bytes(b"\x00\x01garbage" * 3)
    (tmp_path / "empty.obj").write_text("# nothing\n")
    (tmp_path / "m.xyz").write_text("1 2 3\n")
    for name in ("junk.stl", "empty.obj", "m.xyz"):
        with pytest.raises(SceneError) as e:
            body(shape="mesh", file=str(tmp_path / name))
        assert name in one_line(e)
    # a missing file is the path key's error
    with pytest.raises(SceneError) as e:
        body(shape="mesh", file=str(tmp_path / "nope.stl"))
    assert "bodies[1].file" in one_line(e)


def test_open_mesh_only_as_a_thin_wall(tmp_path):
    sheet = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]], process=False)
    f = write(sheet, tmp_path / "sheet.stl")
    with pytest.raises(SceneError) as e:
        body(shape="mesh", file=f)
    assert "open = true" in one_line(e)
    b = body(shape="mesh", file=f, open=True)
    assert not b.closed
    # its inside is behind its faces (normal +z): below
    sd = g.signed_distance(b, [[0.5, 0.5, 0.1], [0.5, 0.5, -0.1], [1.1, 0.5, -0.1]])
    assert np.allclose(sd, [0.1, -0.1, math.hypot(0.1, 0.1)])  # not behind it past its edge
    # its layers are the plane primitive's: a slab behind the sheet, not wrapping its edges
    plane = body(shape="plane", size=[1, 1, 0], position=[0.5, 0.5, 0])
    assert np.allclose(g.signed_distance(plane, [[1.1, 0.5, -0.1]]), math.hypot(0.1, 0.1))
    cells = lambda p: {tuple(c) for c in np.rint(p / 0.1 - 0.5).astype(int)}
    got = g.sample_boundary(b, 0.1, 2)
    assert cells(got) == cells(g.sample_boundary(plane, 0.1, 2)) and len(got) == 200
    kind = SceneKind("t", "", {}, arrays={"bodies": g.body_keys(3)})
    with pytest.raises(SceneError) as e:
        g.check_bodies({"bodies": _check_array("bodies", [{"shape": "mesh", "file": f, "open": True}], kind)}, 3,
                       open_allowed=False)
    assert "bodies[1].open" in one_line(e)


def test_missing_trimesh_is_one_line(tmp_path, monkeypatch):
    f = write(trimesh.creation.box(), tmp_path / "b.stl")
    monkeypatch.setitem(sys.modules, "trimesh", None)
    with pytest.raises(SceneError) as e:
        body(shape="mesh", file=f)
    msg = one_line(e)
    assert "trimesh" in msg and "bodies[1].file" in msg


@pytest.mark.parametrize("entry, words", [
    ({"shape": "box"}, "bodies[1].size"),
    ({"shape": "mesh"}, "bodies[1].file is missing"),
    ({"shape": "sphere"}, "bodies[1].radius"),
    ({"shape": "cylinder", "radius": 1.0}, "bodies[1].height"),
    ({"shape": "box", "size": [1, 1, 1], "motion": "free"}, "bodies[1].density"),
    ({"shape": "box", "size": [1, 1, 1], "motion": "table"}, "bodies[1].motion_file"),
    ({"shape": "box", "size": [1, 1, 1], "bogus": 1}, "unknown key 'bodies[1].bogus'"),
    ({"shape": "cone"}, "bodies[1].shape"),
    ({"shape": "box", "size": [1, 1]}, "bodies[1].size"),
    ({"shape": "box", "size": [1, 1, 1], "units": "ft"}, "bodies[1].units"),
    ({"shape": "box", "size": [1, 1, 1], "name": "a b"}, "bodies[1].name"),
])
def test_bad_entries(entry, words):
    with pytest.raises(SceneError) as e:
        entries(3, entry)
    assert words in one_line(e)


def test_duplicate_names_and_unsupported_motion():
    with pytest.raises(SceneError) as e:
        entries(3, {"shape": "sphere", "radius": 1, "name": "a"}, {"shape": "sphere", "radius": 1, "name": "a"})
    assert "bodies[2].name" in one_line(e)
    kind = SceneKind("t", "", {}, arrays={"bodies": g.body_keys(3)})
    out = _check_array("bodies", [{"shape": "sphere", "radius": 1, "motion": "free", "density": 1}], kind)
    with pytest.raises(SceneError) as e:
        g.check_bodies({"bodies": out}, 3, motions=("fixed",))
    assert "bodies[1].motion" in one_line(e)


# ----- signed distance ---------------------------------------------------------------------


def test_mesh_signed_distance_matches_the_primitives(tmp_path):
    rng = np.random.default_rng(1)
    pts = rng.uniform(-1.0, 1.0, (400, 3))
    f = write(trimesh.creation.box(extents=[0.6, 0.8, 1.0]), tmp_path / "b.stl")
    args = dict(position=[0.1, 0.0, -0.1], rotation=[10, 20, 30])
    mesh = body(shape="mesh", file=f, **args)
    prim = body(shape="box", size=[0.6, 0.8, 1.0], **args)
    assert np.allclose(g.signed_distance(mesh, pts), g.signed_distance(prim, pts), atol=1e-7)  # float32 STL
    f = write(trimesh.creation.icosphere(subdivisions=4, radius=0.5), tmp_path / "s.stl")
    mesh = body(shape="mesh", file=f)
    exact = np.linalg.norm(pts, axis=1) - 0.5
    sd = g.signed_distance(mesh, pts)
    assert np.allclose(sd, exact, atol=2e-3)  # the facets' sag at 5,120 triangles
    assert np.all(np.abs(exact[(sd < 0) != (exact < 0)]) < 2e-3)  # inside agrees but within the sag


def test_cylinder_and_plane_distance():
    c = body(shape="cylinder", radius=0.5, height=2.0)
    assert np.allclose(g.signed_distance(c, [[0, 0, 0], [1, 0, 0], [0, 0, 1.5], [1.5, 0, 2.0]]),
                       [-0.5, 0.5, 0.5, math.hypot(1.0, 1.0)])
    p = body(shape="plane", size=[1, 1, 0], rotation=[90, 0, 0])  # normal +z turned to -y
    assert np.allclose(g.signed_distance(p, [[0, -0.2, 0], [0, 0.2, 0]]), [0.2, -0.2])


# ----- boundary sampling -------------------------------------------------------------------


def test_lattice_aligned_box_has_whole_layers():
    dp, layers = 0.1, 2
    b = body(shape="box", size=[1.0, 1.0, 1.0], position=[0.5, 0.5, 0.5])
    pts = g.sample_boundary(b, dp, layers)
    assert len(pts) == 10**3 - 6**3  # the outer two shells of 10^3 cells
    depth = -g.signed_distance(b, pts)
    assert depth.min() == pytest.approx(0.05) and depth.max() == pytest.approx(0.15 + 0.0)


@pytest.mark.parametrize("shape", ["sphere", "mesh"])
def test_sampling_has_no_gaps_and_the_right_count(shape):
    dp, layers, r = 0.02, 3, 0.2
    if shape == "sphere":
        b = body(shape="sphere", radius=r, position=[0.013, -0.007, 0.004], rotation=[10, 20, 30])
    else:
        b = body(shape="mesh", file=g.shipped_meshes()["sphere"], scale=r / 0.05, position=[0.013, -0.007, 0.004])
    pts = g.sample_boundary(b, dp, layers)
    sd = g.signed_distance(b, pts)
    assert np.all(sd <= 0) and np.all(sd > -layers * dp)
    # lattice points: spacing dp
    assert np.allclose(np.round(pts / dp - 0.5), pts / dp - 0.5, atol=1e-9)
    # about (shell volume) / dp^3 particles
    shell = 4.0 / 3.0 * math.pi * (r**3 - (r - layers * dp) ** 3)
    assert len(pts) == pytest.approx(shell / dp**3, rel=0.08)
    # no gaps: every point of the surface has a particle within half a lattice diagonal of
    # the point half a spacing below it
    rng = np.random.default_rng(2)
    u = rng.normal(size=(2000, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    probe = b.position + u * (r - 0.5 * dp)
    nearest = np.min(np.linalg.norm(probe[:, None, :] - pts[None, :, :], axis=2), axis=1)
    assert nearest.max() <= 0.5 * math.sqrt(3) * dp + 2e-3


def test_2d_sampling_and_fluid_clear():
    dp, layers = 0.01, 3
    c = body(2, shape="circle", radius=0.1, position=[0.5, 0.3])
    pts = g.sample_boundary(c, dp, layers)
    ring = math.pi * (0.1**2 - (0.1 - layers * dp) ** 2)
    assert len(pts) == pytest.approx(ring / dp**2, rel=0.08)
    xs = (np.arange(100) + 0.5) * dp
    grid = np.column_stack([a.ravel() for a in np.meshgrid(xs, xs, indexing="ij")])
    keep = g.fluid_clear([c], grid, dp, layers)
    d = np.linalg.norm(grid - [0.5, 0.3], axis=1) - 0.1
    assert np.array_equal(keep, d >= 0.5 * dp)


def test_motion_table(tmp_path):
    f = tmp_path / "m.csv"
    f.write_text("t,x,y,z,rx,ry,rz\n0,0,0,0,0,0,0\n1,0.1,0,0,0,0,5\n")
    t = g.read_motion_table(str(f), 3, "bodies[1].motion_file")
    assert t.shape == (2, 7)
    f.write_text("0,0,0,0,0,0,0\n0,0.1,0,0,0,0,5\n")
    with pytest.raises(SceneError) as e:
        g.read_motion_table(str(f), 3, "bodies[1].motion_file")
    assert "increase" in one_line(e)
    f.write_text("0,0,0\n")
    with pytest.raises(SceneError) as e:
        g.read_motion_table(str(f), 3, "bodies[1].motion_file")
    assert "line 1" in one_line(e)


def test_culled_sampling_equals_the_brute_force_one():
    # sample_boundary and fluid_clear take exact distances only near the band (cubes of 4 dp):
    # the same points as evaluating every one
    dp, layers = 0.025, 3
    for b in (body(shape="mesh", file=g.shipped_meshes()["sphere"], scale=2.0, position=[0.01, 0.02, -0.03]),
              body(shape="box", size=[0.2, 0.3, 0.1], rotation=[15, 25, 35]),
              body(shape="plane", size=[0.3, 0.2, 0], rotation=[0, 40, 0])):
        lo, hi = b.bounds()
        axes = [np.arange(np.floor(a / dp) - 6, np.ceil(c / dp) + 6) * dp + 0.5 * dp for a, c in zip(lo, hi)]
        pts = np.column_stack([x.ravel() for x in np.meshgrid(*axes, indexing="ij")])
        sd = g.signed_distance(b, pts)
        got = g.sample_boundary(b, dp, layers)
        want = pts[(sd <= 0) & (sd > -layers * dp)]
        assert {tuple(x) for x in np.rint(got / dp - 0.5).astype(int)} == \
               {tuple(x) for x in np.rint(want / dp - 0.5).astype(int)}, b.shape
        blocked = sd < 0.5 * dp if b.closed else (sd < 0.5 * dp) & (sd > -(layers + 0.5) * dp)
        assert np.array_equal(g.fluid_clear([b], pts, dp, layers), ~blocked), b.shape
