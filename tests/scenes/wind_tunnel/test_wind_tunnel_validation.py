"""The wind tunnel's free-molecular validation: the closed forms (corpuscle.free_molecular)
against independent float64 integrations, the flux-weighted re-entry (the gas upstream is the
free stream's Maxwellian), the per-particle number density, the validation's checks at a
CI-sized resolution (and that they fail against a wrong theory), the CLI, and the full
validation (slow)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from corpuscle import Simulation, airfoils
from corpuscle import free_molecular as fm
from corpuscle.scene import load_scene
from corpuscle.validation import Check, VALIDATIONS, load
from corpuscle.validation import wind_tunnel as vwt

from cli_script import corpuscle


# ---- the theory -------------------------------------------------------------------------


def _mc_pressure(cos_in, S, e, n=400_000, seed=0):
    """Monte Carlo float64: the normal momentum flux (1 + e) m <w^2; w > 0> of a drifting
    Maxwellian on a wall, over q = rho U^2 / 2 (U = 1, c_m = 1 / S)."""
    rng = np.random.default_rng(seed)
    cm = 1.0 / S
    w = cos_in + rng.normal(0.0, cm / math.sqrt(2.0), n)  # velocity component into the wall
    return (1.0 + e) * float(np.mean(np.where(w > 0, w * w, 0.0))) / 0.5


@pytest.mark.parametrize("cos_in,S,e", [(1.0, 2.0, 1.0), (0.3, 2.0, 1.0), (-0.2, 1.5, 1.0), (0.5, 3.0, 0.5),
                                        (0.0, 2.0, 1.0)])
def test_pressure_coefficient_is_the_maxwellian_momentum_flux(cos_in, S, e):
    cp = float(fm.pressure_coefficient(cos_in, S, e))
    mc = _mc_pressure(cos_in, S, e)
    assert cp == pytest.approx(mc, rel=0.01, abs=2e-3)


def test_cold_limit_and_thin_plate_closed_forms():
    a = np.array([5.0, 10.0, 30.0, 60.0])
    cold = fm.thin_plate(a, math.inf, 0.5)
    assert np.allclose(cold["cn"], 3.0 * np.sin(np.radians(a)) ** 2)  # 2 (1 + e) sin^2
    hot = fm.thin_plate(a, 200.0, 0.5)  # a very fast Maxwellian is the cold beam
    assert np.allclose(hot["cn"], cold["cn"], rtol=1e-3, atol=1e-4)  # + O(1 / S^2) thermal pressure
    # the thin-plate formula is the two faces' pressure difference
    S = 2.0
    for ad in a:
        s = math.sin(math.radians(ad))
        diff = fm.pressure_coefficient(s, S, 1.0) - fm.pressure_coefficient(-s, S, 1.0)
        assert float(fm.thin_plate(ad, S, 1.0)["cn"]) == pytest.approx(float(diff), rel=1e-12)


@pytest.mark.parametrize("S", [math.inf, 2.0])
def test_offset_body_tends_to_the_thin_plate(S):
    for ad in (0.0, 10.0, 40.0):
        poly = airfoils.place(airfoils.flat_plate(1e-9), 1.0, ad, (0.0, 0.0))
        b = fm.convex_body(poly, 0.0, 1.0, S, 1.0)
        cn, ca = fm.body_axes(b["cl"], b["cd"], ad)
        assert cn == pytest.approx(float(fm.thin_plate(ad, S, 1.0)["cn"]), abs=1e-7)
        assert abs(ca) < 1e-6


def test_cylinder_drag_of_the_arcs():
    # a point offset by r is a cylinder: the cold specular free-molecular C_D = 8/3 per diameter
    tri = np.array([[0.0, 0.0], [1e-12, 0.0], [1e-12, 1e-12]])
    b = fm.convex_body(tri, 0.5, 1.0, math.inf, 1.0)
    assert b["cd"] == pytest.approx(8.0 / 3.0, rel=1e-6) and abs(b["cl"]) < 1e-5  # 64-point quadrature of arcs with a kink


def test_convex_body_rejects_a_concave_polygon():
    concave = np.array([[0, 0], [2, 0], [2, 2], [1, 0.5], [0, 2]], dtype=float)
    with pytest.raises(ValueError, match="convex"):
        fm.convex_body(concave, 0.1, 1.0)


def test_discrete_restitution():
    assert vwt.discrete_restitution(1.0, 0.5) == 1.0
    assert vwt.discrete_restitution(0.5, 0.01) == pytest.approx(0.5, abs=1e-3)
    # a coarser step damps more (the discrete contact's e is what the theory is given)
    assert vwt.discrete_restitution(0.5, 0.2) < vwt.discrete_restitution(0.5, 0.05) < 0.5


# ---- the simulation's free stream -----------------------------------------------------


def test_reentry_keeps_the_maxwellian_upstream():
    """Particles re-enter with flux-weighted velocities: the unscattered gas stays a
    drifting Maxwellian (mean U, variance c_m^2 / 2 per component). Re-entering with the
    Maxwellian itself would give a mean of about U / (1 + 1 / (2 S^2)) = 0.89 U at S = 2."""
    S = 2.0
    ov, num = vwt.scene_overrides("flat-plate", 0.0, S, 1.0, 4000, 0.2, stiffness=10.0)
    ov.update({"airfoil.chord": 0.05, "airfoil.leading_edge": [0.3, 0.0], "run.end_time": 10.0})
    sim = Simulation.from_scene(load_scene("wind-tunnel"), backend="serial", overrides=ov)
    sim.step(int(1.0 / num["dt"]))  # more than one transit: the start's gas has been replaced
    assert sim.state()["recycled"] > 4000
    us, vs = [], []
    for _ in range(10):
        sim.step(int(0.1 / num["dt"]))
        x, v = sim.positions[:, 0], sim.velocities
        sel = (x < 0.2) & (sim.field("scattered") == 0)
        us.append(v[sel, 0].astype(np.float64))
        vs.append(v[sel, 1].astype(np.float64))
    u, w = np.concatenate(us), np.concatenate(vs)
    var = 0.5 / S ** 2
    se = math.sqrt(var / (len(u) / 10))  # the snapshots are 0.1 s apart: about a tenth independent
    assert abs(u.mean() - 1.0) < 4 * se
    assert u.var() == pytest.approx(var, rel=0.06)
    assert w.var() == pytest.approx(var, rel=0.06)


def _random_gas(sim, n, rng):
    """Uniform random positions in the channel, a radius clear of the airfoil."""
    lo, hi = np.asarray(sim.params["channel_lo"]), np.asarray(sim.params["channel_hi"])
    poly = sim.info["airfoil"]
    from corpuscle.kinds import wind_tunnel as wt

    pts = np.empty((0, 2))
    while len(pts) < n:
        p = rng.uniform(lo + sim.radius, hi - sim.radius, (n, 2))
        pts = np.concatenate([pts, p[wt.signed_distance(poly, p) > sim.radius]])
    return pts[:n].astype(np.float32)


def test_number_density_field_is_the_local_density():
    """The 3x3-cell count around each particle, itself excluded, over the block's area: for a
    uniform random gas its mean is the density (it reads the positions of the step)."""
    rng = np.random.default_rng(5)
    means = []
    for n in (4000, 8000):
        sim = Simulation.from_scene(load_scene("wind-tunnel"), backend="serial", particles=n,
                                    overrides={"inflow.speed": 1.0, "gas.radius": 0.0075, "timestep.dt_max": 1e-6})
        sim.set_particles(_random_gas(sim, n, rng), np.zeros((n, 2), np.float32))
        sim.step(1)
        nd = sim.field("number_density").astype(np.float64)
        assert nd.shape == (n,) and np.all(nd >= 0)
        expect = n / sim.info["free_area"]
        assert nd.mean() == pytest.approx(expect, rel=0.05)
        means.append(nd.mean())
    assert means[1] == pytest.approx(2 * means[0], rel=0.07)  # a denser gas reads denser


def test_scattered_particles_are_flagged_and_leave_at_the_walls():
    ov, num = vwt.scene_overrides("flat-plate", 30.0, math.inf, 1.0, 3000, 0.2, stiffness=10.0)
    sim = Simulation.from_scene(load_scene("wind-tunnel"), backend="serial", overrides=ov)
    sim.step(int(0.15 / num["dt"]))
    flagged = sim.field("scattered") == 1
    assert flagged.any()
    y = sim.positions[flagged, 1]
    r = sim.radius
    lo, hi = sim.params["channel_lo"][1], sim.params["channel_hi"][1]
    assert np.all((y - lo >= r * 0.999) & (hi - y >= r * 0.999))  # none is kept at a wall


# ---- the validation --------------------------------------------------------------------


def test_interface():
    assert VALIDATIONS["wind-tunnel"] == "wind_tunnel" and load("wind-tunnel") is vwt
    with pytest.raises(ValueError, match="validations: dam-break, hydrostatic, wind-tunnel"):
        load("nope")
    c = Check("x", 1.5, 1.0, 0.1, False)
    assert c.difference == 0.5


@pytest.fixture(scope="module")
def cold45():
    return vwt.measure("flat-plate", 45.0, math.inf, 0.5, 10000, "serial", 0.2, seed=3)


def test_cold_beam_plate_matches_newtonian_theory(cold45):
    m = cold45
    th = vwt.theory(m["polygon"], m["radius"], 45.0, math.inf, m["restitution"])
    assert m["pushouts"] == 0
    assert abs(m["cn"] - th["cn"]) <= vwt.Z * m["cn_se"]
    assert abs(m["ca"] - th["ca"]) <= vwt.Z * m["ca_se"]
    # the check can fail: an elastic plate's theory (e = 1), 33 % more normal force, is rejected
    wrong = vwt.theory(m["polygon"], m["radius"], 45.0, math.inf, 1.0)
    assert abs(m["cn"] - wrong["cn"]) > vwt.Z * m["cn_se"]
    assert m["cn_se"] < 0.06 * m["cn"]  # the sampling error at this size


def test_maxwellian_plate_matches_free_molecular_theory():
    m = vwt.measure("flat-plate", 20.0, 2.0, 1.0, 6000, "serial", 0.2, seed=4)
    th = vwt.theory(m["polygon"], m["radius"], 20.0, 2.0, 1.0)
    assert abs(m["cn"] - th["cn"]) <= vwt.Z * m["cn_se"]
    assert abs(m["ca"] - th["ca"]) <= vwt.Z * m["ca_se"]
    cold = vwt.theory(m["polygon"], m["radius"], 20.0, math.inf, 1.0)  # Newtonian: half the normal force
    assert abs(m["cn"] - cold["cn"]) > vwt.Z * m["cn_se"]


def test_cli_validate_json_and_bad_input():
    r = corpuscle("validate", "wind-tunnel", "--backend", "serial", "--case", "cold", "--alpha", "45",
                  "--particles", "3000", "--time", "0.1", "--json")
    assert r.returncode in (0, 1), r.stderr
    rows = json.loads(r.stdout)
    assert [row["name"] for row in rows] == ["cold e=0.5 C_N(alpha=45)", "cold e=0.5 C_A(alpha=45)"]
    assert all({"measured", "reference", "difference", "tolerance", "passed"} <= set(row) for row in rows)
    for args, word in ((["nope"], "unknown validation"), (["wind-tunnel", "--alpha", "100"], "--alpha"),
                       (["wind-tunnel", "--case", "hot"], "--case"), (["wind-tunnel", "--particles", "x"], "--particles"),
                       (["wind-tunnel", "--speed-ratio", "1"], "--speed-ratio")):
        r = corpuscle("validate", *args, "--backend", "serial", "--time", "0.01") if args[0] != "nope" else \
            corpuscle("validate", *args)
        assert r.returncode == 2, (args, r.stdout, r.stderr)
        assert word in r.stderr and "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_full_default_validation_passes():
    r = corpuscle("validate", "wind-tunnel", "--backend", "cpu")
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stdout.strip().splitlines()[-1] == "PASS"
