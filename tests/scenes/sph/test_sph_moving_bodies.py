"""Moving bodies in the SPH box kinds (issue 29, prescribed motion): a body's particles follow
its pose (a constant velocity and angular velocity, or a table of positions and angles
interpolated linearly) against a float64 NumPy reference, in every index; the moving plate
pushes the fluid; serial == OpenMP and a checkpoint resumes bitwise; bad motions are one-line
errors; CUDA against the CPU (gpu)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corpuscle import Simulation
from corpuscle.scene import load_scene

from cli_script import assert_one_line_error, corpuscle

INDEXES = ("grid", "compact", "allpairs", "lists")


def rot_euler(a):
    """R = Rz Ry Rx of angles a (degrees): geometry.rotation_matrix's convention, in NumPy."""
    x, y, z = np.radians(a)
    Rx = np.array([[1, 0, 0], [0, math.cos(x), -math.sin(x)], [0, math.sin(x), math.cos(x)]])
    Ry = np.array([[math.cos(y), 0, math.sin(y)], [0, 1, 0], [-math.sin(y), 0, math.cos(y)]])
    Rz = np.array([[math.cos(z), -math.sin(z), 0], [math.sin(z), math.cos(z), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def table_pose(table, t):
    """The reference pose of a table (rows t, x, y, z, rx, ry, rz; float64 of the float32 rows):
    np.interp per column, the slope of the segment as the velocity; w from the angle rates."""
    T = table[:, 0]
    p = np.array([np.interp(t, T, table[:, c]) for c in range(1, 7)])
    if t <= T[0] or t >= T[-1]:
        rate = np.zeros(6)
    else:
        k = np.searchsorted(T, t, side="right") - 1
        rate = (table[k + 1, 1:] - table[k, 1:]) / (T[k + 1] - T[k])
    R = rot_euler(p[3:])
    az = math.radians(p[5])
    r = np.radians(rate[3:])
    w = r[2] * np.array([0, 0, 1.0]) + r[1] * np.array([-math.sin(az), math.cos(az), 0]) + r[0] * R[:, 0]
    return p[:3], R, rate[:3], w


def body_state(sim):
    """(build index of each wall particle, positions, velocities) of the walls now."""
    nf = sim.info["n_fluid"]
    ids = np.asarray(sim.core.download("wall_id")) - nf
    return ids, np.asarray(sim.core.download("wall_position"), np.float64), \
        np.asarray(sim.core.download("wall_velocity"), np.float64)


def by_build(sim):
    ids, x, v = body_state(sim)
    X, V = np.empty_like(x), np.empty_like(v)
    X[ids], V[ids] = x, v
    return X, V


PADDLE = {"name": "paddle", "shape": "box", "size": [0.012, 0.06], "position": [0.25, 0.08], "rotation": 5.0,
          "motion": "velocity", "velocity": [0.3, 0.1], "angular_velocity": 40.0}


def sim2d(backend="serial", bodies=(PADDLE,), neighbors="grid", particles=600, end_time=0.3, **over):
    ov = {"fluid.particles": particles, "run.end_time": end_time, "bodies": list(bodies)}
    ov.update(over)
    return Simulation(load_scene("dam-break-2d").with_overrides(ov), backend, neighbors=neighbors)


def moving_mask(sim):
    n = sim.info["n_body_particles"]
    m = np.zeros(sim.info["n_wall"], bool)
    m[sim.info["n_wall"] - n:] = True
    return m


@pytest.mark.parametrize("neighbors", INDEXES)
def test_velocity_motion_is_rigid_about_the_reference_point(neighbors):
    sim = sim2d(neighbors=neighbors)
    X0, V0 = by_build(sim)
    body = moving_mask(sim)
    c0 = np.array(PADDLE["position"])
    th0 = math.radians(PADDLE["rotation"])
    R0 = np.array([[math.cos(th0), -math.sin(th0)], [math.sin(th0), math.cos(th0)]])
    local = (X0[body] - c0) @ R0  # R0^T (x - c0)
    for _ in range(3):
        sim.step(40)
        t = sim.time
        w = math.radians(PADDLE["angular_velocity"])
        th = th0 + w * t
        R = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
        c = c0 + np.array(PADDLE["velocity"]) * t
        q = local @ R.T
        X, V = by_build(sim)
        np.testing.assert_allclose(X[body], c + q, rtol=0, atol=2e-6)
        np.testing.assert_allclose(V[body], np.array(PADDLE["velocity"]) + w * np.column_stack([-q[:, 1], q[:, 0]]),
                                   rtol=0, atol=2e-6)
        # the tank's walls stay where they are, at rest
        np.testing.assert_array_equal(X[~body], X0[~body])
        assert not np.any(V[~body])
    st = sim.kind.body_poses(sim)["paddle"]
    np.testing.assert_allclose(st["position"][:2], c, atol=1e-6)


def write_table(path, rows):
    path.write_text("# t, x, y, z, rx, ry, rz\n" + "\n".join(",".join(f"{v:.9g}" for v in r) for r in rows) + "\n")
    return str(path)


@pytest.mark.parametrize("neighbors", ("grid", "compact", "lists"))  # (all pairs: in 2-D above; 30 s here)
def test_table_motion_follows_its_table_in_3d(tmp_path, neighbors):
    rng = np.random.default_rng(3)
    t = np.array([0.0, 0.004, 0.011, 0.02, 0.03])
    rows = np.column_stack([t, 0.5 + 0.01 * rng.standard_normal(5), 0.5 + 0.01 * rng.standard_normal(5),
                            0.35 + 0.01 * rng.standard_normal(5), 20 * rng.standard_normal((5, 3))])
    f = write_table(tmp_path / "m.csv", rows)
    body = {"name": "bar", "shape": "box", "size": [0.06, 0.1, 0.05], "motion": "table", "motion_file": f}
    sim = Simulation(load_scene("fluid-box").with_overrides({"fluid.particles": 2000, "run.end_time": 0.05,
                                                             "bodies": [body]}), "serial", neighbors=neighbors)
    table = rows.astype(np.float32).astype(np.float64)
    X0, _ = by_build(sim)
    m = moving_mask(sim)
    c0, R0, _, _ = table_pose(table, 0.0)
    np.testing.assert_allclose(sim.kind.body_poses(sim)["bar"]["position"], c0, atol=1e-6)
    local = (X0[m] - c0) @ R0
    seen = 0
    while sim.time < 0.04:
        sim.step(7)
        c, R, v, w = table_pose(table, sim.time)
        q = local @ R.T
        X, V = by_build(sim)
        np.testing.assert_allclose(X[m], c + q, rtol=0, atol=3e-6)
        np.testing.assert_allclose(V[m], v + np.cross(w, q), rtol=0, atol=1e-4 * (1 + np.abs(V[m]).max()))
        seen += 1
    assert seen >= 3 and sim.time > t[-1]  # (past the table's end: held at its last row, at rest)
    X, V = by_build(sim)
    assert not np.any(V[m])
    # the header's obstacle: its triangles at t = 0 and its pose, drawn at a frame's pose
    from corpuscle._viz_common import posed_vertices
    ob = sim.header()["obstacles"][0]
    assert ob["type"] == "mesh" and ob["pose"]["diagnostic"] == "body_bar"
    v0 = np.asarray(ob["vertices"])
    c, R, _, _ = table_pose(table, sim.time)
    np.testing.assert_allclose(posed_vertices(ob, sim.diagnostics()), c + (v0 - c0) @ R0 @ R.T, atol=1e-5)


def test_velocity_motion_turns_about_a_3d_axis():
    w = np.array([30.0, -50.0, 80.0])  # deg/s about the fixed axes
    body = {"name": "blade", "shape": "box", "size": [0.08, 0.03, 0.05], "position": [0.5, 0.5, 0.4],
            "rotation": [10.0, 20.0, 30.0], "motion": "velocity", "velocity": [0.2, -0.1, 0.05],
            "angular_velocity": w.tolist()}
    sim = Simulation(load_scene("fluid-box").with_overrides({"fluid.particles": 2000, "run.end_time": 0.5,
                                                             "bodies": [body]}), "serial")
    X0, _ = by_build(sim)
    m = moving_mask(sim)
    c0, R0 = np.array(body["position"]), rot_euler(body["rotation"])
    local = (X0[m] - c0) @ R0
    sim.step(60)
    t = sim.time
    wr = np.radians(w)
    th = np.linalg.norm(wr) * t
    k = wr / np.linalg.norm(wr)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    Rw = np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K  # Rodrigues
    q = local @ (Rw @ R0).T
    X, V = by_build(sim)
    np.testing.assert_allclose(X[m], c0 + np.array(body["velocity"]) * t + q, rtol=0, atol=3e-6)
    np.testing.assert_allclose(V[m], np.array(body["velocity"]) + np.cross(wr, q), rtol=0, atol=3e-6)


def test_the_moving_plate_pushes_the_fluid():
    # a piston: a plate at the left end of a 2-D flume, started at 0.4 m/s into still water
    plate = {"name": "plate", "shape": "box", "size": [0.03, 0.25], "position": [0.03, 0.13], "motion": "velocity",
             "velocity": [0.4, 0.0]}

    def flume(body):
        ov = {"box.size": [0.5, 0.3], "fluid.lo": [0.05, 0.0], "fluid.hi": [0.5, 0.15], "fluid.particles": 800,
              "run.end_time": 0.2, "bodies": [body], "probes": []}
        return Simulation(load_scene("piston-wave-maker").with_overrides(ov), "serial", neighbors="lists")

    sim, still = flume(plate), flume(dict(plate, motion="fixed", velocity=[0.0, 0.0]))
    sim.step(200)
    still.step(200)
    vx = np.asarray(sim.core.download("velocity"))[:, 0]
    vs = np.asarray(still.core.download("velocity"))[:, 0]
    pos = np.asarray(sim.core.download("position"))
    face = 0.045 + 0.4 * sim.time
    # the fluid just ahead of the plate moves with it; none is behind it
    ahead = (pos[:, 0] > face) & (pos[:, 0] < face + 0.03)
    assert ahead.sum() > 5 and vx[ahead].mean() > 0.5 * 0.4
    assert not np.any(pos[:, 0] < face - 0.03)
    assert vx.mean() > vs.mean() + 0.05


@pytest.mark.parametrize("neighbors", ("grid", "lists"))
def test_serial_and_openmp_bitwise_with_moving_bodies(neighbors):
    a, b = sim2d("serial", neighbors=neighbors), sim2d("cpu", neighbors=neighbors)
    a.step(60)
    b.step(60)
    for name in ("position", "velocity", "density", "wall_position", "wall_density", "wall_velocity"):
        assert np.array_equal(a.core.download(name), b.core.download(name)), name


@pytest.mark.parametrize("neighbors", ("grid", "lists"))
def test_checkpoint_resumes_bitwise_with_moving_bodies(neighbors):
    a = sim2d(neighbors=neighbors)
    a.step(25)
    ck = a.checkpoint()
    a.step(35)
    b = sim2d(neighbors=neighbors)
    b.restore(ck)
    b.step(35)
    for name in ("position", "velocity", "density", "wall_density", "wall_position", "wall_velocity", "wall_id"):
        assert np.array_equal(a.core.download(name), b.core.download(name)), name
    assert a.time == b.time


def test_a_checkpoint_with_a_bad_wall_order_is_refused():
    a = sim2d()
    a.step(5)
    ck = a.checkpoint()
    ck["wall_id"] = np.zeros_like(np.asarray(ck["wall_id"]))
    with pytest.raises(Exception, match="wall_id must be a permutation"):
        sim2d().restore(ck)


def test_piston_wave_maker_scene_builds_and_moves():
    sim = Simulation(load_scene("piston-wave-maker").with_overrides({"fluid.particles": 1500}), "serial")
    assert sim.info["moving_bodies"] == ["piston"]
    sim.step(20)
    d = sim.kind.body_diagnostics(sim, sim.core.scalars())
    ramp = 0.5 * (1 - math.cos(math.pi * sim.time))
    assert d["body_piston_x"] == pytest.approx(0.1 + 0.02 * ramp * math.sin(2 * math.pi * sim.time), abs=2e-5)


# ----- bad input ---------------------------------------------------------------------------


def write_scene(tmp_path, body: str, extra: str = "") -> str:
    p = tmp_path / "s.toml"
    p.write_text('[scene]\nkind = "dam-break-2d"\n[run]\nend_time = 1.0\n[fluid]\nparticles = 200\n' + extra +
                 '[[bodies]]\n' + body)
    return str(p)


@pytest.mark.parametrize("body, extra, words", [
    ('shape = "circle"\nradius = 0.02\nposition = [0.3, 0.1]\nmotion = "velocity"\nvelocity = [1.0, 0.0]\n', "",
     "bodies[1] ('body1') leaves the tank at t = "),
    ('shape = "circle"\nradius = 0.02\nposition = [0.3, 0.1]\nmotion = "velocity"\n',
     '[walls]\nmoving = ["top"]\nvelocity = [1.0, 0.0]\n', "walls.moving"),
    ('shape = "circle"\nradius = 0.02\nposition = [0.3, 0.1]\nmotion = "table"\nmotion_file = "no.csv"\n', "",
     "bodies[1].motion_file"),
])
def test_bad_motions(tmp_path, body, extra, words):
    assert_one_line_error(corpuscle("run", write_scene(tmp_path, body, extra), "--backend", "serial"), words)


def test_a_table_leaving_the_tank_is_refused(tmp_path):
    (tmp_path / "m.csv").write_text("0, 0.3, 0.1, 0\n0.5, 0.3, 0.1, 0\n0.6, 5.0, 0.1, 0\n")
    body = 'shape = "circle"\nradius = 0.02\nposition = [0.3, 0.1]\nmotion = "table"\nmotion_file = "m.csv"\n'
    assert_one_line_error(corpuscle("run", write_scene(tmp_path, body), "--backend", "serial"),
                          "bodies[1] ('body1') leaves the tank at t = 0.5")


# ----- CUDA against the CPU (the device machine) ------------------------------------------


@pytest.mark.gpu
@pytest.mark.parametrize("neighbors", INDEXES)
def test_cuda_matches_cpu_with_moving_bodies(neighbors):
    if not Simulation.cuda_available():
        pytest.skip("no CUDA")
    cpu = sim2d("cpu", neighbors=neighbors, particles=2000)
    gpu = sim2d("cuda", neighbors=neighbors, particles=2000)
    cpu.step(60)
    gpu.step(60)
    assert gpu.time == pytest.approx(cpu.time, rel=1e-4)

    def fluid_by_id(sim, name):
        ids = np.asarray(sim.core.download("id"))
        out = np.empty_like(np.asarray(sim.core.download(name)))
        out[ids] = np.asarray(sim.core.download(name))
        return out

    dp = cpu.info["spacing"]
    np.testing.assert_allclose(fluid_by_id(gpu, "position"), fluid_by_id(cpu, "position"), rtol=0, atol=1e-3 * dp)
    Xc, Vc = by_build(cpu)
    Xg, Vg = by_build(gpu)
    # the bodies' particles: the same pose at (almost) the same time
    np.testing.assert_allclose(Xg, Xc, rtol=0, atol=1e-3 * dp)
    np.testing.assert_allclose(Vg, Vc, rtol=0, atol=1e-3)


def test_frames_draw_a_moving_body_at_its_pose(tmp_path):
    import corpuscle as cps
    from corpuscle._viz_common import scene_info, turned_points
    out = tmp_path / "p.cps"
    proc = corpuscle_cli_run(out)
    assert proc.returncode == 0, proc.stderr
    with cps.open(out) as run:
        ob = scene_info(run.header)["obstacles"][0]
        assert ob["pose"]["diagnostic"] == "body_piston"
        frames = list(run)
        assert len(frames) >= 3
        for fr in frames:
            pts = turned_points(ob, fr.diagnostics)
            # the plate's outline centred on the recorded reference point, unrotated
            np.testing.assert_allclose(pts.mean(axis=0), [fr.diagnostics["body_piston_x"], 0.18], atol=1e-6)
        assert frames[-1].diagnostics["body_piston_x"] != frames[0].diagnostics["body_piston_x"]
    pytest.importorskip("PIL")
    proc = corpuscle("render", out, "--out", tmp_path / "f.png", timeout=300)
    assert proc.returncode == 0, proc.stderr


def corpuscle_cli_run(out):
    return corpuscle("run", "piston-wave-maker", "--backend", "serial", "--set", "fluid.particles=600",
                     "--set", "run.end_time=0.3", "--set", "run.record_every=200", "--out", out, timeout=300)
