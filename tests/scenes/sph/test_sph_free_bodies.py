"""Free (floating) bodies in the SPH box kinds (issue 29, DualSPHysics's floating bodies): the
force and torque summed from a body's particles against a float64 NumPy reference of the pair
terms; Archimedes (a box of half the water's density floats with half its height submerged); a
neutrally buoyant body stays; a tilted floating box rights itself; the tank's contact holds a
sinking body; serial == OpenMP and a checkpoint resumes bitwise; bad keys are one-line errors;
CUDA against the CPU (gpu)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corpuscle import Simulation
from corpuscle.scene import load_scene

from cli_script import assert_one_line_error, corpuscle

INDEXES = ("grid", "compact", "allpairs", "lists")


def box2d(backend="serial", neighbors="grid", particles=1200, end_time=2.0, body=None, spacing=0.0, **over):
    """floating-box-2d (dp = 1 cm; or `spacing`) with its box's keys overridden by `body`. (A
    spacing that divides the box's and the body's extents keeps the lattice symmetric about the
    body: an asymmetric start turns it.)"""
    sc = load_scene("floating-box-2d")
    b = {"name": "box", "shape": "box", "size": [0.12, 0.06], "position": [0.3, 0.22], "density": 500.0,
         "motion": "free"}  # (the scene's)
    b.update(body or {})
    b = {k: x for k, x in b.items() if not (k == "density" and x == 0.0)}
    ov = {"fluid.particles": particles, "fluid.spacing": spacing, "run.end_time": end_time, "bodies": [b]}
    ov.update(over)
    return Simulation(sc.with_overrides(ov), backend, neighbors=neighbors)


def pose(sim):
    return sim.kind.body_poses(sim)["box"]


def fluid_level(sim, away):
    """The free surface's height (m) over the columns farther than `away` from the body's
    centre: the mean of each column's highest fluid particle, plus half a spacing."""
    x = np.asarray(sim.core.download("position"), np.float64)
    dp = sim.info["spacing"]
    c = pose(sim)["position"][0]
    col = np.floor(x[:, 0] / dp).astype(int)
    tops = []
    for k in np.unique(col):
        sel = col == k
        if abs((k + 0.5) * dp - c) > away:
            tops.append(x[sel, 1].max())
    return float(np.mean(tops)) + 0.5 * dp


# ----- the force and torque against a float64 reference ------------------------------------


def reference_body_force(sim):
    """The fluid's force on the free body's particles and its torque about the centre of mass,
    float64 from the fields (the pair stage's pressure and artificial viscosity terms, Wendland
    C2, as tests/scenes/sph/test_sph_box.py's reference)."""
    p = sim.params
    dim = sim.kind.dim
    nf = sim.info["n_fluid"]
    x = np.asarray(sim.core.download("position"), np.float64)
    v = np.asarray(sim.core.download("velocity"), np.float64)
    rho = np.asarray(sim.core.download("density"), np.float64)
    ids = np.asarray(sim.core.download("wall_id")) - nf
    wx = np.asarray(sim.core.download("wall_position"), np.float64)
    wv = np.asarray(sim.core.download("wall_velocity"), np.float64)
    wr = np.asarray(sim.core.download("wall_density"), np.float64)
    nb = sim.info["n_body_particles"]
    mine = ids >= sim.info["n_wall"] - nb  # the body's particles (the last walls at the build)
    rho0, c0, gamma, m = p["rho0"], p["c0"], p["gamma"], p["mass"]
    B = c0 * c0 * rho0 / gamma
    h, hs = p["h"], p["hs"]
    eta2 = 0.01 * hs * hs
    pr = B * ((rho / rho0) ** gamma - 1)
    c = np.asarray(sim.core.scalars()["free_state"], np.float64)[:dim]
    F, T = np.zeros(3), np.zeros(3)
    kc = 7.0 / math.pi if dim == 2 else 21.0 / (2 * math.pi)
    for i in np.flatnonzero(mine):
        d = wx[i] - x
        r2 = (d * d).sum(1)
        j = np.flatnonzero(r2 < h * h)
        dj, r = d[j], np.sqrt(r2[j])
        q = r / h
        gw = (-20 * kc / h ** (dim + 2) * (1 - q) ** 3)[:, None] * dj
        pi_ = B * ((wr[i] / rho0) ** gamma - 1)
        a = -(gw * (m * (pi_ / wr[i] ** 2 + pr[j] / rho[j] ** 2))[:, None]).sum(0)
        dv = wv[i] - v[j]
        vr = (dv * dj).sum(1)
        mu = hs * vr / (r ** 2 + eta2)
        visc = np.where(vr < 0, (-p["alpha"] * c0 * mu + p["beta"] * mu * mu) / (0.5 * (wr[i] + rho[j])), 0.0)
        a += (-m * visc[:, None] * gw).sum(0)
        f = np.zeros(3)
        f[:dim] = m * a
        arm = np.zeros(3)
        arm[:dim] = wx[i] - c
        F += f
        T += np.cross(arm, f)
    return F, T


@pytest.mark.parametrize("neighbors", INDEXES)
def test_force_and_torque_match_a_float64_reference(neighbors):
    # a box moving and turning through stirred water: pressure and viscous terms both act
    sim = box2d(neighbors=neighbors, particles=800, body={"position": [0.3, 0.17], "velocity": [0.2, -0.1],
                                                         "angular_velocity": 60.0})
    sim.step(30)
    rng = np.random.default_rng(3)
    v = np.asarray(sim.core.download("velocity"), np.float64)
    sim.core.upload("velocity", np.ascontiguousarray(v + rng.normal(0, 0.05, v.shape), dtype=np.float32))
    sim.evaluate()
    F, T = reference_body_force(sim)
    got = np.asarray(sim.core.scalars()["body_force"], np.float64)[:6]
    scale = np.abs(F).max()
    assert scale > 1.0  # the water holds the box up (weight 3.6 kg x 9.81 m/s^2 per metre)
    np.testing.assert_allclose(got[:3], F, rtol=0, atol=1e-4 * scale)
    np.testing.assert_allclose(got[5], T[2], rtol=0, atol=1e-4 * scale * 0.06)


# ----- physics --------------------------------------------------------------------------------


def settle(sim, t0, samples=40):
    """The body's mean height and angle over [t0, end] (samples evenly spaced: the heave's
    period is about 0.7 s, so a window of more than one averages it out)."""
    end = sim.scene.values["run.end_time"]
    ys, ang = [], []
    for t in np.linspace(t0, end, samples):
        sim.run(until=t)
        p = pose(sim)
        ys.append(p["position"][1])
        ang.append(math.degrees(math.atan2(p["rotation"][1, 0], p["rotation"][0, 0])))
    return float(np.mean(ys)), float(np.mean(ang))


def check_archimedes(sim, t0):
    H = 0.06
    y, angle = settle(sim, t0)
    level = fluid_level(sim, away=0.12)
    draft = level - (y - 0.5 * H)
    dp = sim.info["spacing"]
    # half the height submerged to within 3/4 of a spacing: the fluid's pressure reaches the
    # body through the fluid particles beside it, half a spacing outside its surface (so the
    # discrete body floats up to dp / 2 high: the error is first order in dp), and the free
    # surface is located to within a quarter spacing (its top particles plus dp / 2)
    assert abs(draft - 0.5 * H) < 0.75 * dp, (draft, level, y, dp)
    assert abs(angle) < 1.0  # and level


def test_archimedes_half_density_box_floats_half_submerged():
    # released at the draft of theory, the centre at the still water level (0.2 m)
    check_archimedes(box2d("cpu", spacing=0.012, end_time=0.95, body={"position": [0.3, 0.2]}), 0.2)


@pytest.mark.slow
def test_archimedes_finer():
    # released 2 cm above (the scene) at half the spacing
    check_archimedes(box2d("cpu", spacing=0.005, end_time=2.0), 0.6)


def test_neutrally_buoyant_body_stays():
    # a fully submerged box at the water's density at its depth (the weakly compressible
    # water is denser below: its hydrostatic density) barely moves; lighter and heavier ones rise and sink
    from corpuscle.kinds._sph_box import hydrostatic_density
    moves = {}
    for name, f in (("neutral", 1.0), ("light", 0.9), ("heavy", 1.1)):
        # (its faces on the lattice's cell boundaries: 6 and 11 spacings up, 20 and 30 across)
        probe = box2d(end_time=0.2, spacing=0.012, body={"position": [0.3, 0.102], "density": 1000.0})
        p = probe.params
        B = p["c0"] ** 2 * p["rho0"] / p["gamma"]
        rho = float(hydrostatic_density(np.array([0.2 - 0.102]), p["rho0"], B, p["gamma"], 9.81)[0])
        sim = box2d("cpu", end_time=0.15, spacing=0.012, body={"position": [0.3, 0.102], "density": f * rho})
        y0 = pose(sim)["position"][1]
        sim.run(until=0.15)
        moves[name] = pose(sim)["position"][1] - y0
    assert moves["light"] > 0 > moves["heavy"]
    assert abs(moves["neutral"]) < 0.1 * min(abs(moves["light"]), abs(moves["heavy"])), moves


def test_a_tilted_box_rights_itself():
    # a flat box (metacentric height about 0.1 m) floating at 20 degrees turns back towards level
    sim = box2d("cpu", end_time=0.3, spacing=0.012, body={"size": [0.16, 0.04], "position": [0.3, 0.2],
                                                         "rotation": 20.0})
    angles = []
    for t in np.linspace(0.05, 0.3, 6):
        sim.run(until=t)
        R = pose(sim)["rotation"]
        angles.append(math.degrees(math.atan2(R[1, 0], R[0, 0])))
    assert pose(sim)["angular_velocity"] is not None
    assert angles[1] < 20.0  # it turns clockwise: the righting torque
    assert min(angles) < 10.0, angles


@pytest.mark.slow
def test_the_tank_floor_holds_a_heavy_body():
    # a box twice as dense as water sinks and rests on the floor: the contact holds it above
    sim = box2d("cpu", end_time=0.8, body={"position": [0.3, 0.1], "density": 2000.0})
    sim.run(until=0.8)
    y = pose(sim)["position"][1]
    dp = sim.info["spacing"]
    assert 0.03 - 0.5 * dp < y < 0.03 + dp, y  # its bottom (0.03 m below its centre) at the floor
    assert abs(pose(sim)["velocity"][1]) < 0.05


def test_the_3d_scene_runs_and_floats():
    sim = Simulation(load_scene("floating-box").with_overrides({"run.end_time": 0.05, "fluid.spacing": 0.025}),
                     "cpu")
    assert sim.info["free_bodies"] == ["box"]
    z0 = pose(sim)["position"][2]
    sim.run(until=0.05)
    p = pose(sim)
    assert p["position"][2] < z0  # released above its floating position: it falls
    d = sim.kind.body_diagnostics(sim, sim.core.scalars())
    assert "body_box_fz" in d and d["body_box_fz"] > 0.0  # the water pushes it up


# ----- determinism and resume -----------------------------------------------------------------


@pytest.mark.parametrize("neighbors", ("grid", "lists"))
def test_serial_and_openmp_bitwise_with_free_bodies(neighbors):
    a, b = box2d("serial", neighbors, particles=600), box2d("cpu", neighbors, particles=600)
    a.step(80)
    b.step(80)
    for name in ("position", "velocity", "density", "wall_position", "wall_density", "wall_velocity"):
        assert np.array_equal(a.core.download(name), b.core.download(name)), name
    assert np.array_equal(a.core.scalars()["free_state"], b.core.scalars()["free_state"])


@pytest.mark.parametrize("neighbors", ("grid", "lists"))
def test_checkpoint_resumes_bitwise_with_free_bodies(neighbors):
    a = box2d(neighbors=neighbors, particles=600)
    a.step(40)
    ck = a.checkpoint()
    a.step(50)
    b = box2d(neighbors=neighbors, particles=600)
    b.restore(ck)
    b.step(50)
    for name in ("position", "velocity", "density", "wall_density", "wall_position", "wall_velocity", "wall_id"):
        assert np.array_equal(a.core.download(name), b.core.download(name)), name
    assert np.array_equal(a.core.scalars()["free_state"], b.core.scalars()["free_state"])
    assert a.time == b.time


# ----- bad input ------------------------------------------------------------------------------


def write_scene(tmp_path, body: str) -> str:
    p = tmp_path / "s.toml"
    p.write_text('[scene]\nkind = "dam-break-2d"\n[run]\nend_time = 1.0\n[fluid]\nparticles = 200\n'
                 '[[bodies]]\nshape = "circle"\nradius = 0.02\nposition = [0.3, 0.1]\n' + body)
    return str(p)


@pytest.mark.parametrize("body, words", [
    ('motion = "free"\n', "bodies[1].density must be > 0"),
    ('motion = "free"\ndensity = -5.0\n', "bodies[1].density"),
    ('motion = "free"\ndensity = 500.0\nmass = 2.0\n', "bodies[1].mass = 2"),
    ('motion = "fixed"\nmass = 2.0\n', "bodies[1].mass = 2"),
])
def test_bad_free_bodies(tmp_path, body, words):
    assert_one_line_error(corpuscle("run", write_scene(tmp_path, body), "--backend", "serial"), words)


def test_mass_instead_of_density():
    a = box2d(end_time=0.01)
    b = box2d(end_time=0.01, body={"density": 0.0, "mass": 3.6})
    assert a.params["body_free"] == pytest.approx(b.params["body_free"], rel=1e-12)


def test_scene_listed():
    out = corpuscle("scenes")
    assert "floating-box" in out.stdout and "floating-box-2d" in out.stdout


# ----- CUDA against the CPU (the device machine) ------------------------------------------


@pytest.mark.gpu
@pytest.mark.parametrize("neighbors", INDEXES)
def test_cuda_matches_cpu_with_free_bodies(neighbors):
    if not Simulation.cuda_available():
        pytest.skip("no CUDA")
    cpu = box2d("cpu", neighbors, particles=1200, end_time=0.1)
    gpu = box2d("cuda", neighbors, particles=1200, end_time=0.1)
    cpu.evaluate()
    gpu.evaluate()
    fc = np.asarray(cpu.core.scalars()["body_force"])[:6]
    fg = np.asarray(gpu.core.scalars()["body_force"])[:6]
    np.testing.assert_allclose(fg, fc, rtol=0, atol=1e-4 * np.abs(fc).max())
    cpu.run(until=0.1)
    gpu.run(until=0.1)
    pc, pg = pose(cpu), pose(gpu)
    dp = cpu.info["spacing"]
    np.testing.assert_allclose(pg["position"], pc["position"], rtol=0, atol=0.02 * dp)
    np.testing.assert_allclose(pg["rotation"], pc["rotation"], rtol=0, atol=1e-3)


@pytest.mark.gpu
def test_cuda_archimedes():
    if not Simulation.cuda_available():
        pytest.skip("no CUDA")
    check_archimedes(box2d("cuda", particles=4800, end_time=2.5), 1.5)


def test_3d_mass_and_inertia_in_the_body_frame():
    # a turned box: its inertia in its own frame is the box's principal one, its centre of mass
    # its centre, whatever the rotation
    sc = load_scene("floating-box").with_overrides({
        "run.end_time": 0.01, "fluid.spacing": 0.025,
        "bodies": [{"name": "box", "shape": "box", "size": [0.1, 0.05, 0.04], "position": [0.25, 0.25, 0.3],
                    "rotation": [10.0, -20.0, 30.0], "density": 400.0, "motion": "free"}]})
    sim = Simulation(sc, "serial")
    p = sim.params
    m = 400.0 * 0.1 * 0.05 * 0.04
    a, b, c = 0.1, 0.05, 0.04
    want = m / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    assert p["body_free"][0] == pytest.approx(m, rel=1e-12)
    np.testing.assert_allclose(np.reshape(p["body_free"][1:10], (3, 3)), want, rtol=0, atol=1e-12 * want.max())
    np.testing.assert_allclose(p["body_motion"][3:6], [0.25, 0.25, 0.3], rtol=0, atol=1e-12)
    # its particles sit at R r + c at the start, the rotation the entry's
    R = pose(sim)["rotation"]
    from corpuscle.geometry import rotation_matrix
    np.testing.assert_allclose(R, rotation_matrix([10.0, -20.0, 30.0]), rtol=0, atol=1e-6)
