"""physics/dem.h (through corpuscle._testing): the linear spring-dashpot contact law, its
restitution and contact time against the closed forms, an integrated head-on collision,
Newton's third law, the per-particle "pressure" contribution, and the polygon contact."""

import math

import numpy as np
import pytest

from corpuscle import airfoils

_testing = pytest.importorskip("corpuscle._testing")


def e_closed_form(k, c, m_eff):
    z = c / (2 * math.sqrt(k * m_eff))
    return math.exp(-math.pi * z / math.sqrt(1 - z * z))


def f32(x):
    return np.ascontiguousarray(x, dtype=np.float32)


@pytest.mark.parametrize("k, c, m1, m2", [(1e4, 50, 1, 1), (1e4, 5, 0.01, 0.03), (5e4, 50, 1, 0), (1e6, 300, 2, 5)])
def test_restitution_and_contact_time_closed_forms(k, c, m1, m2):
    me = m1 * m2 / (m1 + m2) if m2 > 0 else m1  # m2 = 0: a wall
    law = _testing.dem_law(k, c, m1, m2)
    assert law["m_eff"] == pytest.approx(me, rel=1e-6)
    assert law["zeta"] == pytest.approx(c / (2 * math.sqrt(k * me)), rel=1e-6)
    assert law["restitution"] == pytest.approx(e_closed_form(k, c, me), rel=1e-5)
    assert law["contact_time"] == pytest.approx(math.pi / math.sqrt(k / me - (c / (2 * me)) ** 2), rel=1e-5)


def test_undamped_and_overdamped_limits():
    assert _testing.dem_law(1e4, 0.0, 1, 1)["restitution"] == 1.0
    assert _testing.dem_law(1e4, 0.0, 1, 1)["contact_time"] == pytest.approx(math.pi / math.sqrt(1e4 / 0.5), rel=1e-6)
    over = _testing.dem_law(1e4, 2 * math.sqrt(1e4 * 0.5) * 1.01, 1, 1)
    assert over["restitution"] == 0.0 and over["contact_time"] > 1e29


@pytest.mark.parametrize("e", [0.05, 0.3, 0.7, 0.95, 1.0])
@pytest.mark.parametrize("m1, m2", [(1.0, 1.0), (1.0, 3.0), (0.2, 0.0)])
def test_damping_from_restitution_round_trips(e, m1, m2):
    k = 1e4
    c = _testing.dem_damping(k, e, m1, m2)
    assert c >= 0
    assert _testing.dem_law(k, c, m1, m2)["restitution"] == pytest.approx(e, rel=2e-5, abs=1e-6)
    e2 = _testing.dem_law(k, 50.0, m1, m2)["restitution"]
    assert _testing.dem_damping(k, e2, m1, m2) == pytest.approx(50.0, rel=2e-5)


def collide(k, c, m1, m2, r, v1, v2, steps_per_contact=4000):
    """Head-on collision along x, integrated with symplectic Euler in float64 using the
    C++ forces; returns (restitution, contact time) measured from the trajectory."""
    tc = _testing.dem_law(k, c, m1, m2)["contact_time"]
    dt = tc / steps_per_contact
    x = np.array([[0.0, 0.0], [2 * r + 1e-9, 0.0]])  # just apart: the contact starts on approach
    v = np.array([[v1, 0.0], [v2, 0.0]])
    m = np.array([m1, m2])[:, None]
    rr = f32([r])
    u0 = v[0, 0] - v[1, 0]
    touching, steps, t = False, 0, 0
    for _ in range(20 * steps_per_contact):
        fi, fj, _, _, touch = _testing.dem_pair_forces(k, c, f32(x[:1]), f32(v[:1]), rr, f32(x[1:]), f32(v[1:]), rr)
        if touch[0]:
            touching = True
            steps += 1
        elif touching:
            break
        f = np.vstack([fi, fj]).astype(np.float64)
        v = v + dt * f / m
        x = x + dt * v
    assert touching and not touch[0]
    return (v[1, 0] - v[0, 0]) / u0, steps * dt, tc, dt


@pytest.mark.parametrize("e", [0.3, 0.7, 0.95])
@pytest.mark.parametrize("m1, m2", [(1.0, 1.0), (1.0, 3.0)])
def test_integrated_head_on_collision_gives_predicted_restitution_and_contact_time(e, m1, m2):
    k, r = 1e6, 0.01
    c = _testing.dem_damping(k, e, m1, m2)
    e_meas, tc_meas, tc, dt = collide(k, c, m1, m2, r, 1.0, -0.5)
    assert e_meas == pytest.approx(e, abs=1e-3)  # symplectic Euler: O(dt / t_c) plus float32 forces
    assert abs(tc_meas - tc) <= 3 * dt


def test_undamped_collision_conserves_energy():
    e_meas, tc_meas, tc, dt = collide(1e6, 0.0, 1.0, 2.0, 0.01, 0.8, -0.1)
    assert e_meas == pytest.approx(1.0, abs=2e-3)
    assert abs(tc_meas - tc) <= 3 * dt


@pytest.mark.parametrize("dim", [2, 3])
def test_pair_force_obeys_newtons_third_law_and_pressure_is_the_magnitude(dim):
    rng = np.random.default_rng(11)
    m = 500
    ri = rng.uniform(0.5, 1.5, m)
    rj = rng.uniform(0.5, 1.5, m)
    xi = rng.normal(size=(m, dim))
    u = rng.normal(size=(m, dim))
    u /= np.linalg.norm(u, axis=1)[:, None]
    gap = rng.uniform(0.5, 1.2, m) * (ri + rj)  # most overlap, some do not
    xj = xi + gap[:, None] * u
    vi, vj = rng.normal(size=(m, dim)), rng.normal(size=(m, dim))
    k, c = 1e3, 30.0
    fi, fj, mi, mj, touch = _testing.dem_pair_forces(k, c, f32(xi), f32(vi), f32(ri), f32(xj), f32(vj), f32(rj))
    np.testing.assert_array_equal(fi, -fj)  # exactly, whichever particle computes it
    np.testing.assert_array_equal(mi, mj)
    np.testing.assert_array_equal(touch == 3, gap < ri + rj)  # both calls agree
    np.testing.assert_allclose(np.linalg.norm(fi, axis=1), mi, rtol=1e-5, atol=1e-6)
    assert np.all(fi[gap >= ri + rj] == 0) and np.all(mi[gap >= ri + rj] == 0)
    # the reference law in float64
    x32, y32 = f32(xi).astype(float), f32(xj).astype(float)
    d = y32 - x32
    dist = np.linalg.norm(d, axis=1)
    n = d / dist[:, None]
    F = k * (f32(ri).astype(float) + f32(rj).astype(float) - dist) + c * np.sum(
        (f32(vi).astype(float) - f32(vj).astype(float)) * n, axis=1
    )
    t = touch == 3
    np.testing.assert_allclose(fi[t], -(F[t, None] * n[t]), rtol=1e-4, atol=1e-3)
    # damping while separating fast makes some forces attractive; |F| is still the magnitude
    assert np.any(F[t] < 0)
    np.testing.assert_allclose(mi[t], np.abs(F[t]), rtol=1e-4, atol=1e-3)


def test_coincident_centres_give_no_force():
    x = f32([[0.3, 0.2]])
    fi, fj, mi, _, touch = _testing.dem_pair_forces(1e4, 50, x, f32([[1, 0]]), f32([0.1]), x, f32([[0, 0]]), f32([0.1]))
    assert touch[0] == 0 and np.all(fi == 0) and mi[0] == 0


def test_polygon_contact_force_follows_the_law_and_pushes_out():
    square = f32([[0, 0], [1, 0], [1, 1], [0, 1]])
    k, c, r = 5e4, 50.0, 0.05
    x = f32([[0.5, 1.03], [0.5, 0.98], [0.5, 1.2], [1.02, 1.02]])  # above, just inside, apart, near a corner
    v = f32([[0.3, -2.0], [0.0, 0.0], [0.0, -1.0], [-1.0, -1.0]])
    f, mag, touch, sd = _testing.dem_polygon_forces(k, c, square, x, v, r)
    np.testing.assert_array_equal(touch.astype(bool), [True, True, False, True])
    np.testing.assert_allclose(f[0], [0.0, k * (r - 0.03) + c * 2.0], rtol=1e-5)
    np.testing.assert_allclose(f[1], [0.0, k * (r + 0.02)], rtol=1e-5)  # inside: out through the top
    assert sd[1] == pytest.approx(-0.02, abs=1e-6)
    np.testing.assert_array_equal(f[2], [0.0, 0.0])
    n = np.array([1.0, 1.0]) / math.sqrt(2)  # from the corner vertex
    d = 0.02 * math.sqrt(2)
    np.testing.assert_allclose(f[3], (k * (r - d) + c * math.sqrt(2)) * n, rtol=1e-4)
    np.testing.assert_allclose(mag, np.linalg.norm(f, axis=1), rtol=1e-6)


def test_particles_around_the_sharp_trailing_edge_are_pushed_away():
    wing = airfoils.place(airfoils.load("e398"), 0.5, 10.0, (-1.2, 0.0))
    te = wing[0]
    rng = np.random.default_rng(5)
    r = 0.002
    phi = rng.uniform(0, 2 * np.pi, 400)
    rho = rng.uniform(0, r, 400)
    x = te + rho[:, None] * np.column_stack([np.cos(phi), np.sin(phi)])
    f, mag, touch, sd = _testing.dem_polygon_forces(5e4, 0.0, f32(wing), f32(x), f32(np.zeros_like(x)), r)
    assert touch.all()
    # with c = 0 the force is k (r - sd) along the outward normal: a step along it leaves the body
    got = _testing.polygon_sdf(f32(wing), f32(x))
    np.testing.assert_allclose(f, (5e4 * (r - got["distance"]))[:, None] * got["normal"], rtol=1e-5, atol=1e-6)
    moved = _testing.polygon_sdf(f32(wing), f32(x + 2 * r * f / np.linalg.norm(f, axis=1)[:, None]))
    assert np.all(moved["distance"] > got["distance"])
