"""[[bodies]] in the SPH box kinds: a body's boundary particles are the lattice points inside
it within the kernel's depth (as the walls), no fluid starts inside a body or within half a
spacing of it and none gets in, a submerged body holds the hydrostatic pressure, serial ==
OpenMP and a checkpoint resumes bitwise with bodies, bad bodies are one-line errors (exit 2),
the SPHERIC test 2 scene builds, and its obstacle reaches the header (render, export)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corpuscle import Simulation, geometry
from corpuscle.scene import load_scene
from corpuscle.schema import SceneError

from cli_script import assert_one_line_error, corpuscle

CIRCLE = {"name": "disc", "shape": "circle", "radius": 0.03, "position": [0.07, 0.08]}
BOX2 = {"name": "block", "shape": "box", "size": [0.04, 0.03], "position": [0.2, 0.02], "rotation": 10.0}


def sim2d(backend="serial", bodies=(CIRCLE, BOX2), particles=600, neighbors="grid", **over):
    ov = {"fluid.particles": particles, "run.end_time": 10.0, "bodies": list(bodies)}
    ov.update({k.replace("__", "."): v for k, v in over.items()})
    return Simulation(load_scene("dam-break-2d").with_overrides(ov), backend, neighbors=neighbors)


def placed(entries, dim):
    from corpuscle.scene import _check_array
    from corpuscle.schema import SceneKind
    kind = SceneKind("t", "", {}, arrays={"bodies": geometry.body_keys(dim)})
    return geometry.make_bodies({"bodies": _check_array("bodies", list(entries), kind)}, dim)


def test_body_particles_join_the_walls_2d():
    plain = sim2d(bodies=())
    sim = sim2d()
    dp, layers = sim.info["spacing"], sim.info["layers"]
    assert plain.info["spacing"] == dp
    bodies = placed([CIRCLE, BOX2], 2)
    expect = np.concatenate([geometry.sample_boundary(b, dp, layers) for b in bodies])
    assert sim.info["n_wall"] - plain.info["n_wall"] == len(expect) == sim.info["n_body_particles"]
    # the walls hold them (as float32), the box's walls unchanged
    walls = np.asarray(sim.core.download("wall_position"), dtype=np.float64)
    got = {tuple(np.rint(p / dp - 0.5).astype(int)) for p in walls}
    assert {tuple(np.rint(p / dp - 0.5).astype(int)) for p in expect} <= got
    assert len(got) == sim.info["n_wall"]  # no particle twice
    # as many as the area of the band inside each body's surface, layers deep, holds
    ring = math.pi * (0.03**2 - (0.03 - layers * dp) ** 2) / dp**2
    n_disc = len(geometry.sample_boundary(bodies[0], dp, layers))
    assert n_disc == pytest.approx(ring, rel=0.15)
    # no fluid inside a body or within half a spacing of it, and the fluid that is left is
    # the plain scene's less exactly those
    pos = np.asarray(sim.core.download("position"), dtype=np.float64)
    for b in bodies:
        assert geometry.signed_distance(b, pos).min() >= 0.5 * dp - 1e-6
    p0 = np.asarray(plain.core.download("position"), dtype=np.float64)
    keep = geometry.fluid_clear(bodies, p0, dp, layers)
    assert sim.info["n_fluid"] == int(keep.sum()) < plain.info["n_fluid"]


def test_mesh_body_in_3d(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    f = tmp_path / "ball.stl"
    trimesh.creation.icosphere(subdivisions=3, radius=0.04).export(str(f))
    body = {"name": "ball", "shape": "mesh", "file": str(f), "position": [0.07, 0.07, 0.1]}
    sim = Simulation(load_scene("dam-break").with_overrides({"fluid.particles": 3000, "dam.depth": 1.0,
                                                             "bodies": [body]}), "serial")
    dp, layers = sim.info["spacing"], sim.info["layers"]
    b = placed([body], 3)[0]
    assert sim.info["n_body_particles"] == len(geometry.sample_boundary(b, dp, layers))
    pos = np.asarray(sim.core.download("position"), dtype=np.float64)
    assert geometry.signed_distance(b, pos).min() >= 0.5 * dp - 1e-6
    ob = sim.header()["obstacles"][0]
    assert ob["type"] == "mesh" and ob["name"] == "ball" and len(ob["faces"]) == 1280


def test_fluid_stays_out_and_the_submerged_body_feels_hydrostatic_pressure():
    # a column as wide as the tank with a disc in it: the water stays still, the pressure of
    # the fluid around the disc is rho g (depth) (DBC: within a few spacings' head), and no
    # fluid particle enters the disc
    disc = {"name": "disc", "shape": "circle", "radius": 0.025, "position": [0.073, 0.1]}
    sim = sim2d(bodies=[disc], particles=900, dam__tank_length=1.0, run__end_time=0.25, probes=[])
    sim.run()
    dp, rho0, g = sim.info["spacing"], sim.info["rho0"], sim.info["gravity"]
    b = placed([disc], 2)[0]
    pos = np.asarray(sim.core.download("position"), dtype=np.float64)
    p = np.asarray(sim.core.download("pressure"), dtype=np.float64)
    sd = geometry.signed_distance(b, pos)
    assert sd.min() > 0.0
    near = sd < 2.0 * dp
    top = pos[:, 1].max() + 0.5 * dp
    hydro = rho0 * g * (top - pos[near, 1])
    # DBC's pressure lags the hydrostatic one by about a spacing's head next to a wall
    err = np.abs(p[near] - hydro)
    assert np.median(err) < rho0 * g * 1.5 * dp, (np.median(err), rho0 * g * dp)
    # above the disc less than below it, by about the disc's height in head
    x = pos[near, 0] - disc["position"][0]
    above = p[near][(pos[near, 1] > disc["position"][1]) & (np.abs(x) < 0.01)].mean()
    below = p[near][(pos[near, 1] < disc["position"][1]) & (np.abs(x) < 0.01)].mean()
    assert below - above == pytest.approx(rho0 * g * 2 * (disc["radius"] + dp), rel=0.35)


def test_serial_and_openmp_bitwise_with_bodies():
    a, b = sim2d("serial"), sim2d("cpu")
    a.step(30)
    b.step(30)
    for name in ("position", "velocity", "density", "wall_density"):
        assert np.array_equal(a.core.download(name), b.core.download(name)), name


def test_checkpoint_resumes_bitwise_with_bodies():
    a = sim2d()
    a.step(10)
    ck = a.checkpoint()
    a.step(20)
    b = sim2d()
    b.restore(ck)
    b.step(20)
    for name in ("position", "velocity", "density", "wall_density", "wall_position"):
        assert np.array_equal(a.core.download(name), b.core.download(name)), name
    assert a.time == b.time


def test_spheric_obstacle_scene_builds():
    scene = load_scene("dam-break-obstacle").with_overrides({"fluid.particles": 4000})
    sim = Simulation(scene, "serial")
    h = sim.header()
    ob = h["obstacles"][0]
    assert ob["type"] == "box" and ob["name"] == "obstacle"
    np.testing.assert_allclose(ob["min"], [2.3955, 0.2985, 0.0], atol=1e-9)
    np.testing.assert_allclose(ob["max"], [2.5565, 0.7015, 0.161], atol=1e-9)
    assert sim.info["n_body_particles"] > 0
    names = {"P1", "P2", "P3", "P4", "H1", "H2", "H3", "H4"}
    assert set(h["probes"]) == names
    sim.step(5)
    st = sim.state()["probes"]
    assert set(st) == names
    # the gauges: H4 in the reservoir reads the column's 0.55 m, H1 to H3 are dry at release
    assert st["H4"]["level"] == pytest.approx(0.55, abs=0.1 * sim.info["spacing"])
    for g in ("H1", "H2", "H3"):
        assert st[g]["level"] < 0.05 * sim.info["spacing"]


def test_render_and_export_draw_a_mesh_obstacle(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    pytest.importorskip("PIL")
    f = tmp_path / "ball.stl"
    trimesh.creation.icosphere(subdivisions=2, radius=0.03).export(str(f))
    scene = tmp_path / "s.toml"
    scene.write_text('[scene]\nkind = "dam-break"\n[fluid]\nparticles = 1500\n[run]\nend_time = 0.002\n'
                     'record_every = 5\n[dam]\ndepth = 1.0\n[[bodies]]\nname = "ball"\nshape = "mesh"\n'
                     'file = "ball.stl"\nposition = [0.3, 0.073, 0.05]\n')
    out = tmp_path / "r.cps"
    proc = corpuscle("run", str(scene), "--backend", "serial", "--out", out, timeout=300)
    assert proc.returncode == 0, proc.stderr
    proc = corpuscle("export", out, "--format", "vtk", tmp_path / "vtk", timeout=300)
    assert proc.returncode == 0, proc.stderr
    meshio = pytest.importorskip("meshio")
    m = meshio.read(tmp_path / "vtk" / "obstacle_ball.vtu")
    tri = m.cells_dict["triangle"]
    assert len(tri) == 320
    # the ball's triangles where the scene put them
    np.testing.assert_allclose(np.linalg.norm(m.points - [0.3, 0.073, 0.05], axis=1), 0.03, atol=1e-6)
    proc = corpuscle("render", out, "--out", tmp_path / "f.png", timeout=300)
    assert proc.returncode == 0, proc.stderr


# ----- bad input ---------------------------------------------------------------------------


def write_scene(tmp_path, body: str) -> str:
    p = tmp_path / "s.toml"
    p.write_text('[scene]\nkind = "dam-break-2d"\n[fluid]\nparticles = 200\n[[bodies]]\n' + body)
    return str(p)


@pytest.mark.parametrize("body, words", [
    ('shape = "circle"\nradius = 0.05\nposition = [5.0, 0.1]\n', "bodies[1] ('body1') reaches outside the tank"),
    ('shape = "box"\nsize = [0.1, 0.1]\nposition = [0.1, 0.1]\nbogus = 3\n', "bodies[1].bogus"),
    ('shape = "circle"\nradius = 0.05\nposition = [0.3, 0.1]\nmotion = "floating"\ndensity = 500.0\n',
     "bodies[1].motion"),
    ('shape = "sphere"\nradius = 0.05\n', "bodies[1].shape"),
])
def test_bad_bodies_2d(tmp_path, body, words):
    assert_one_line_error(corpuscle("run", write_scene(tmp_path, body), "--backend", "serial"), words)


def test_bad_mesh_bodies(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    box = trimesh.creation.box(extents=[0.02, 0.02, 0.02])
    trimesh.Trimesh(box.vertices, box.faces[:-1], process=False).export(str(tmp_path / "holed.stl"))
    (tmp_path / "junk.obj").write_text("v 1 2\nf 1 2 3 4 5\nnonsense\n")

    def scene(file):
        p = tmp_path / "m.toml"
        p.write_text(f'[scene]\nkind = "dam-break"\n[fluid]\nparticles = 300\n[[bodies]]\nshape = "mesh"\n'
                     f'file = "{file}"\nposition = [0.1, 0.03, 0.05]\n')
        return str(p)

    assert_one_line_error(corpuscle("run", scene("holed.stl"), "--backend", "serial"), "not watertight")
    assert_one_line_error(corpuscle("run", scene("junk.obj"), "--backend", "serial"), "junk.obj")
    assert_one_line_error(corpuscle("run", scene("missing.stl"), "--backend", "serial"), "bodies[1].file")


def test_bodies_outside_are_refused_in_3d():
    with pytest.raises(SceneError, match=r"bodies\[1\] \('b'\) reaches outside the tank"):
        load_scene("fluid-box").with_overrides({"bodies": [{"name": "b", "shape": "sphere", "radius": 0.1,
                                                            "position": [0.05, 0.5, 0.5]}]})


# ----- CUDA against the CPU (the device machine) ------------------------------------------


@pytest.mark.gpu
def test_cuda_matches_cpu_with_bodies():
    if not Simulation.cuda_available():
        pytest.skip("no CUDA")
    cpu, gpu = sim2d("cpu", particles=2000), sim2d("cuda", particles=2000)
    assert gpu.info["n_wall"] == cpu.info["n_wall"]
    cpu.step(50)
    gpu.step(50)
    assert gpu.time == pytest.approx(cpu.time, rel=1e-4)

    def by_id(sim, name):
        ids = np.asarray(sim.core.download("id"))
        out = np.empty_like(np.asarray(sim.core.download(name)))
        out[ids] = np.asarray(sim.core.download(name))
        return out

    np.testing.assert_allclose(by_id(gpu, "position"), by_id(cpu, "position"), rtol=0, atol=1e-3 * cpu.info["spacing"])
    np.testing.assert_allclose(by_id(gpu, "density"), by_id(cpu, "density"), rtol=1e-4)


def test_a_plane_is_a_thin_wall_with_its_layers_behind_it():
    # a baffle across the fluid block at x = 0.25, its normal turned from +z to -x: its layers
    # lie behind it (x > 0.25), and no fluid within half a spacing in front or in the layers
    baffle = {"name": "baffle", "shape": "plane", "size": [0.3, 0.6, 0.0], "position": [0.25, 0.5, 0.15],
              "rotation": [0, -90, 0]}
    sim = Simulation(load_scene("fluid-box").with_overrides({"fluid.particles": 4000, "bodies": [baffle]}), "serial")
    dp, layers = sim.info["spacing"], sim.info["layers"]
    b = placed([baffle], 3)[0]
    assert np.allclose(b.rotation @ [0, 0, 1], [-1, 0, 0])
    walls = np.asarray(sim.core.download("wall_position"), dtype=np.float64)
    body = geometry.sample_boundary(b, dp, layers)
    assert len(body) == sim.info["n_body_particles"]
    cells = lambda p: {tuple(c) for c in np.rint(p / dp - 0.5).astype(int)}
    assert cells(body) <= cells(walls)  # (the walls come back in the sorted order)
    assert np.all(body[:, 0] > 0.25) and np.all(body[:, 0] < 0.25 + layers * dp)
    # a rectangle of lattice points, layers deep
    inside = lambda x, lo, hi: np.sum(((np.arange(200) + 0.5) * dp >= lo) & ((np.arange(200) + 0.5) * dp <= hi))
    assert len(body) == layers * inside(0, 0.2, 0.8) * inside(0, 0.0, 0.3)
    pos = np.asarray(sim.core.download("position"), dtype=np.float64)
    sd = geometry.signed_distance(b, pos)
    assert not np.any((sd < 0.5 * dp) & (sd > -(layers + 0.5) * dp))
    assert np.any(pos[:, 0] > 0.25 + layers * dp)  # the fluid behind the baffle's layers stays
