"""Each formula once (issue 26): the closed forms Python needs a value of are the core's
(physics/tait.h, physics/dem.h, bound in cpp/bindings/physics_bindings.cpp, evaluated in double),
checked here against independent references of the formulas, round trips, and the values the
core itself reports for a scene."""
import math

import numpy as np
import pytest

_core = pytest.importorskip("corpuscle._core")

from corpuscle import Simulation  # noqa: E402
from corpuscle.kinds import _sph_box, magic8ball  # noqa: E402
from corpuscle.kinds import wind_tunnel as wt  # noqa: E402
from corpuscle.scene import load_scene  # noqa: E402

RHO0, GAMMA = 1000.0, 7.0


def ref_tait_pressure(rho, rho0, B, gamma):
    return B * (math.pow(rho / rho0, gamma) - 1.0)


def ref_tait_density(p, rho0, B, gamma):
    return rho0 * math.pow(1.0 + p / B, 1.0 / gamma)


def ref_restitution(k, c, m):
    z = c / (2.0 * math.sqrt(k * m))
    return 0.0 if z >= 1.0 else math.exp(-math.pi * z / math.sqrt(1.0 - z * z))


def ref_damping(k, e, m):
    le = math.log(e)
    return 2.0 * (-le / math.sqrt(math.pi ** 2 + le * le)) * math.sqrt(k * m)


def test_tait_equals_the_formula_and_its_inverse_round_trips():
    c0 = 24.3
    B = _core.tait_stiffness(c0, RHO0, GAMMA)
    assert B == c0 * c0 * RHO0 / GAMMA  # the same operations in double: the same bits
    assert _core.tait_sound_speed(B, RHO0, GAMMA) == pytest.approx(c0, rel=1e-15)
    rho = np.linspace(980.0, 1060.0, 81)
    p = _core.tait_pressure(rho, RHO0, B, GAMMA)
    assert p.dtype == np.float64 and p.shape == rho.shape
    assert p.tolist() == [ref_tait_pressure(r, RHO0, B, GAMMA) for r in rho]
    assert p[rho < RHO0].max() < 0.0 < p[rho > RHO0].min()  # not clamped: the box's form
    assert _core.tait_pressure(1020.0, RHO0, B, GAMMA) == p[40]  # scalar and array agree
    back = _core.tait_density(p, RHO0, B, GAMMA)
    assert back.tolist() == [ref_tait_density(x, RHO0, B, GAMMA) for x in p]
    np.testing.assert_allclose(back, rho, rtol=1e-14)
    # a wrong exponent or stiffness would be far off: 1 % over rest density is ~7 % of B
    assert _core.tait_pressure(1010.0, RHO0, B, GAMMA) == pytest.approx(B * (1.01 ** 7 - 1.0), rel=1e-12)


def test_the_sph_box_starts_from_the_cores_hydrostatic_tait_density():
    depth = np.array([[-0.1, 0.0], [0.25, 0.5]])
    B = _core.tait_stiffness(20.0, RHO0, GAMMA)
    rho = _sph_box.hydrostatic_density(depth, RHO0, B, GAMMA, 9.81)
    assert rho.shape == depth.shape and rho[0, 0] == rho[0, 1] == RHO0
    # the pressure of the column above is rho0 g d
    np.testing.assert_allclose(_core.tait_pressure(rho.ravel(), RHO0, B, GAMMA),
                               RHO0 * 9.81 * np.maximum(depth, 0.0).ravel(), rtol=1e-12, atol=1e-9)


def test_restitution_and_damping_equal_the_formula_and_round_trip():
    k, m = 2.5e4, 3e-4
    for e in (0.05, 0.3, 0.5, 0.8, 0.95, 1.0):
        c = _core.dem_damping_for_restitution(k, e, m)
        assert c == ref_damping(k, e, m)
        assert wt.damping(k, e, m) == c
        assert _core.dem_restitution_for_damping(k, c, m) == pytest.approx(e, rel=1e-13, abs=1e-15)
        assert wt.restitution(k, c, m) == ref_restitution(k, c, m)
    # overdamped (zeta >= 1): no rebound
    assert _core.dem_restitution_for_damping(k, 2.0 * math.sqrt(k * m), m) == 0.0
    # the array form (over the first argument, the stiffness) is the scalar form element by element
    ks = np.array([1e3, 2.5e4, 7e6])
    assert _core.dem_damping_for_restitution(ks, 0.6, m).tolist() == [ref_damping(x, 0.6, m) for x in ks]
    assert _core.dem_restitution_for_damping(ks, 0.01, m).tolist() == [ref_restitution(x, 0.01, m) for x in ks]


def test_the_wind_tunnels_python_restitution_is_the_cores():
    # the core reports the restitution of the damping it was given (in float); Python's (in
    # double) is the same law: within float precision, for a damping Python derived from e
    scene = load_scene("wind-tunnel", {"gas.particles": 500, "contact.restitution": 0.7, "wing.restitution": 0.4})
    sim = Simulation.from_scene(scene, backend="serial")
    s = sim.scalars()
    assert sim.info["restitution_pp"] == pytest.approx(0.7, rel=1e-12)
    assert sim.info["restitution_wing"] == pytest.approx(0.4, rel=1e-12)
    assert s["restitution_pp"] == pytest.approx(sim.info["restitution_pp"], rel=2e-6)
    assert s["restitution_wing"] == pytest.approx(sim.info["restitution_wing"], rel=2e-6)
    assert s["restitution_wall"] == pytest.approx(sim.info["restitution_wall"], rel=2e-6)


def test_the_8balls_particle_mass_and_die_inertia_are_one_function_for_one_scene_and_a_batch():
    mass, inertia = magic8ball.die_mass_inertia(1200.0, 0.02)
    assert mass == 1200.0 * 0.02 ** 3 and inertia == pytest.approx(mass * 0.02 ** 2 / 6.0, rel=1e-15)
    v = load_scene("magic8ball").values
    n = 1000
    m = magic8ball.particle_mass(float(v["fluid.rest_density"]), float(v["container.radius"]),
                                 float(v["die.side"]), n)
    r, a = float(v["container.radius"]), float(v["die.side"])
    assert m * n == pytest.approx(float(v["fluid.rest_density"]) * (4.0 / 3.0 * math.pi * r ** 3 - a ** 3), rel=1e-14)
    # arrays (the batch) give each scene its value
    sides = np.array([0.02, 0.025])
    masses, inertias = magic8ball.die_mass_inertia(np.array([1200.0, 900.0]), sides)
    assert masses.tolist() == pytest.approx([1200.0 * 0.02 ** 3, 900.0 * 0.025 ** 3], rel=1e-15)
    assert inertias.tolist() == pytest.approx((masses * sides ** 2 / 6.0).tolist(), rel=1e-15)
    # the built scene's parameters are these
    sim = Simulation.from_scene("magic8ball", backend="serial", particles=400)
    side, density = float(sim.scene["die.side"]), float(sim.scene["die.density"])
    mass, inertia = magic8ball.die_mass_inertia(density, side)
    assert sim.params["die_mass"] == mass and sim.params["die_inertia"] == [inertia] * 3
    assert sim.params["mass"] == magic8ball.particle_mass(float(sim.scene["fluid.rest_density"]),
                                                          float(sim.scene["container.radius"]), side, 400)
