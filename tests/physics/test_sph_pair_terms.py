"""The SPH pair terms of cpp/include/corpuscle/physics/sph_pair_terms.h, through
``corpuscle._testing`` (which sums each term over all pairs within the support, evaluating
(i, j) and (j, i) as separate calls, as a pipeline's gather does), against float64 NumPy and
the conservation laws they must keep:

- Monaghan's artificial viscosity (Monaghan 1992): zero for receding pairs, positive for
  approaching ones, a dissipative central pair force, total momentum conserved;
- the laminar viscosity (Morris, Fox & Zhu 1997 / Lo & Shao 2002, DualSPHysics "laminar"):
  antisymmetric (momentum), dissipative, zero for a uniform velocity;
- delta-SPH density diffusion (Molteni & Colagrossi 2009; Fourtakas et al. 2019):
  sum_i V_i drho_i/dt = 0 (mass/volume), zero for a uniform density (Molteni), and with the
  Fourtakas hydrostatic correction zero for a hydrostatic density field (not without it);
- the DualSPHysics CFL step (physics/timestep.h, choose_dt_cfl).

Inputs are float32; the core computes in float32. Each tolerance says what it allows for.
"""

import math

import numpy as np
import pytest

testing = pytest.importorskip("corpuscle._testing")

DIMS = [2, 3]
F32 = np.float32


def f32(a):
    return np.ascontiguousarray(a, dtype=F32)


# ---- a particle set and float64 references ----


def particle_block(dim, n_side, dp, seed, jitter=0.2):
    """A jittered lattice of n_side^dim particles, spacing dp, with random velocities,
    densities near 1000, sound speeds near 20 and unequal masses (float32-exact values)."""
    rng = np.random.default_rng(seed)
    ax = np.arange(n_side) * dp
    x = np.stack([g.ravel() for g in np.meshgrid(*([ax] * dim), indexing="ij")], 1)
    x = x + rng.uniform(-jitter, jitter, size=x.shape) * dp
    n = len(x)
    v = rng.normal(scale=0.5, size=(n, dim))
    rho = 1000.0 * (1 + 0.01 * rng.uniform(-1, 1, n))
    c = 20.0 * (1 + 0.05 * rng.uniform(-1, 1, n))
    m = 1000.0 * dp**dim * (1 + 0.2 * rng.uniform(-1, 1, n))
    return tuple(np.asarray(a, F32).astype(np.float64) for a in (x, v, rho, c, m))


def wendland_grad(dim, h, d):
    """grad_i W for Wendland C2 with support h (Dehnen & Aly 2012): -20 C / h^(D+2) (1 - q)^3 d."""
    C = 21.0 / (2 * math.pi) if dim == 3 else 7.0 / math.pi
    r = np.linalg.norm(d, axis=-1)
    q = r / h
    f = np.where(q < 1, -20.0 * C / h ** (dim + 2) * np.clip(1 - q, 0, None) ** 3, 0.0)
    return f[..., None] * d


def pairs(x, v, h):
    """All ordered pairs (i, j), i != j, within the support: d, dv, r2, mask (float64)."""
    d = x[:, None, :] - x[None, :, :]
    dv = v[:, None, :] - v[None, :, :]
    r2 = np.sum(d * d, axis=-1)
    mask = (r2 < h * h) & ~np.eye(len(x), dtype=bool)
    return d, dv, r2, mask


def art_visc_ref(dim, h, alpha, beta, hs, x, v, rho, c, m):
    d, dv, r2, mask = pairs(x, v, h)
    eta2 = 0.01 * hs * hs
    vr = np.sum(dv * d, axis=-1)
    mu = hs * vr / (r2 + eta2)
    cbar = 0.5 * (c[:, None] + c[None, :])
    rbar = 0.5 * (rho[:, None] + rho[None, :])
    pi = np.where((vr < 0) & mask, (-alpha * cbar * mu + beta * mu * mu) / rbar, 0.0)
    return np.sum(-(m[None, :] * pi)[..., None] * wendland_grad(dim, h, d), axis=1)


def laminar_ref(dim, h, nu0, hs, x, v, rho, m):
    d, dv, r2, mask = pairs(x, v, h)
    g = wendland_grad(dim, h, d)
    s = m[None, :] * 4 * nu0 * np.sum(d * g, axis=-1) / ((rho[:, None] + rho[None, :]) * (r2 + 0.01 * hs * hs))
    return np.sum(np.where(mask, s, 0.0)[..., None] * dv, axis=1)


def rho_h_odd(z, c0, rho0, gamma, g):
    kz = gamma * g / c0**2
    return 0.5 * rho0 * (np.clip(1 + kz * z, 0, None) ** (1 / gamma) - np.clip(1 - kz * z, 0, None) ** (1 / gamma))


def diffusion_ref(dim, h, kind, delta, hs, c0, rho0, gamma, g, x, rho, m):
    d, _, r2, mask = pairs(x, x, h)
    drho = rho[None, :] - rho[:, None]
    if kind == "fourtakas":
        drho = drho - rho_h_odd(d[..., -1], c0, rho0, gamma, g)
    rg = -np.sum(d * wendland_grad(dim, h, d), axis=-1)
    t = 2 * delta * hs * c0 * drho * rg / (r2 + 0.01 * hs * hs) * (m / rho)[None, :]
    return np.sum(np.where(mask, t, 0.0), axis=1)


# ---- Monaghan artificial viscosity ----

DP = 0.01
HS = 1.2 * DP  # smoothing length (Monaghan's / DualSPHysics's h)
H = 2 * HS  # support radius of the kernel


@pytest.mark.parametrize("dim", DIMS)
def test_monaghan_pi_zero_receding_positive_approaching(dim):
    # per pair: Pi_ij = 0 when v_ij . r_ij >= 0, > 0 when < 0, and equal to
    # (-alpha cbar mu + beta mu^2) / rhobar in float64 (float32: rtol 1e-5)
    rng = np.random.default_rng(1)
    n = 4000
    d = f32(rng.normal(size=(n, dim)) * DP)
    dv = f32(rng.normal(size=(n, dim)))
    cbar = f32(rng.uniform(10, 30, n))
    rbar = f32(rng.uniform(990, 1010, n))
    for alpha, beta in [(0.01, 0.0), (0.1, 2.0)]:
        pi = np.asarray(testing.sph_monaghan_pi(dim, alpha, beta, HS, d, dv, cbar, rbar), np.float64)
        dd, vv = d.astype(np.float64), dv.astype(np.float64)
        vr = np.sum(dd * vv, axis=1)
        assert np.all(pi[vr >= 0] == 0.0)
        assert np.all(pi[vr < 0] > 0.0)
        mu = HS * vr / (np.sum(dd * dd, axis=1) + 0.01 * HS * HS)
        ref = np.where(vr < 0, (-alpha * cbar * mu + beta * mu * mu) / rbar, 0.0)
        np.testing.assert_allclose(pi, ref, rtol=1e-5, atol=1e-7 * np.abs(ref).max())
    # the mu of the CFL limit is the same mu_ij, with its sign
    mu_core = np.asarray(testing.sph_mu(dim, HS, d, dv), np.float64)
    np.testing.assert_allclose(mu_core, mu, rtol=1e-5, atol=1e-7 * np.abs(mu).max())


def two_particles(dim, approaching, seed):
    rng = np.random.default_rng(seed)
    x = np.zeros((2, dim))
    u = rng.normal(size=dim)
    u /= np.linalg.norm(u)
    x[1] = 0.6 * H * u
    v = rng.normal(size=(2, dim))
    # make v_01 . r_01 negative (approaching) or positive (receding)
    vr = np.dot(v[0] - v[1], x[0] - x[1])
    if (vr < 0) != approaching:
        v = v[::-1].copy()
    rho = np.array([1001.0, 998.0])
    c = np.array([19.0, 21.0])
    m = np.array([0.1, 0.13])
    return tuple(a.astype(F32).astype(np.float64) for a in (x, v, rho, c, m))


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("approaching", [True, False])
def test_artificial_viscosity_pair_force(dim, approaching):
    # one pair evaluated as (0, 1) and (1, 0): zero when receding; when approaching the
    # forces are equal and opposite (m_0 a_0 = -m_1 a_1 to float32 rounding: rtol 1e-6),
    # central (along r_01, pushing the pair apart) and dissipative (power < 0)
    x, v, rho, c, m = two_particles(dim, approaching, seed=2 + dim)
    a = np.asarray(testing.sph_artificial_viscosity("wendland_c2", dim, H, 0.1, 1.0, HS, f32(x), f32(v), f32(rho),
                                                    f32(c), f32(m)), np.float64)
    if not approaching:
        assert np.all(a == 0.0)
        return
    f0, f1 = m[0] * a[0], m[1] * a[1]
    assert np.linalg.norm(f0) > 0
    np.testing.assert_allclose(f0, -f1, rtol=1e-6, atol=1e-6 * np.linalg.norm(f0))
    r01 = x[0] - x[1]
    assert np.dot(f0, r01) > 0  # repulsive
    np.testing.assert_allclose(np.linalg.norm(f0), abs(np.dot(f0, r01)) / np.linalg.norm(r01), rtol=1e-6)
    power = np.dot(f0, v[0]) + np.dot(f1, v[1])
    assert power < 0
    ref = art_visc_ref(dim, H, 0.1, 1.0, HS, x, v, rho, c, m)
    np.testing.assert_allclose(a, ref, rtol=1e-5)


@pytest.mark.parametrize("dim", DIMS)
def test_artificial_viscosity_conserves_momentum_and_dissipates(dim):
    # a random block: sum_i m_i a_i = 0 to float32 rounding of the pair forces (1e-6 of
    # sum_i |m_i a_i|), total power sum_i m_i v_i . a_i < 0, and per particle the float64
    # reference (float32 sums of ~30-100 terms with some cancellation: rtol 1e-4 with an
    # absolute floor of 1e-5 of the largest)
    x, v, rho, c, m = particle_block(dim, 8 if dim == 2 else 5, DP, seed=10 + dim)
    a = np.asarray(testing.sph_artificial_viscosity("wendland_c2", dim, H, 0.1, 0.5, HS, f32(x), f32(v), f32(rho),
                                                    f32(c), f32(m)), np.float64)
    f = m[:, None] * a
    scale = np.abs(f).sum()
    assert scale > 0
    assert np.all(np.abs(f.sum(axis=0)) < 1e-6 * scale)
    assert np.sum(f * v) < 0
    ref = art_visc_ref(dim, H, 0.1, 0.5, HS, x, v, rho, c, m)
    np.testing.assert_allclose(a, ref, rtol=1e-4, atol=1e-5 * np.abs(ref).max())


# ---- laminar viscosity ----


@pytest.mark.parametrize("dim", DIMS)
def test_laminar_viscosity_antisymmetric_and_dissipative(dim):
    nu0 = 1e-6
    x, v, rho, c, m = particle_block(dim, 8 if dim == 2 else 5, DP, seed=20 + dim)
    a = np.asarray(testing.sph_laminar_viscosity("wendland_c2", dim, H, nu0, HS, f32(x), f32(v), f32(rho), f32(m)),
                   np.float64)
    f = m[:, None] * a
    scale = np.abs(f).sum()
    assert scale > 0
    # momentum: pairs cancel to float32 rounding (1e-6 of the total)
    assert np.all(np.abs(f.sum(axis=0)) < 1e-6 * scale)
    # dissipative: sum_i m_i v_i . a_i = -sum_pairs |K| |v_ij|^2 / 2 < 0
    assert np.sum(f * v) < 0
    ref = laminar_ref(dim, H, nu0, HS, x, v, rho, m)
    np.testing.assert_allclose(a, ref, rtol=1e-4, atol=1e-5 * np.abs(ref).max())
    # the single pair: m_0 a_0 = -m_1 a_1, along v_01 (rtol 1e-6)
    x2, v2, rho2, _, m2 = two_particles(dim, True, seed=30 + dim)
    a2 = np.asarray(testing.sph_laminar_viscosity("wendland_c2", dim, H, nu0, HS, f32(x2), f32(v2), f32(rho2),
                                                  f32(m2)), np.float64)
    np.testing.assert_allclose(m2[0] * a2[0], -m2[1] * a2[1], rtol=1e-6, atol=1e-6 * np.abs(m2[0] * a2[0]).max())
    v01 = v2[0] - v2[1]
    assert np.dot(a2[0], v01) < 0
    cos = np.dot(a2[0], v01) / (np.linalg.norm(a2[0]) * np.linalg.norm(v01))
    assert cos == pytest.approx(-1.0, abs=1e-6)


@pytest.mark.parametrize("dim", DIMS)
def test_laminar_viscosity_zero_for_uniform_velocity(dim):
    x, v, rho, c, m = particle_block(dim, 6 if dim == 2 else 4, DP, seed=40 + dim)
    v[:] = F32(0.75)
    a = np.asarray(testing.sph_laminar_viscosity("wendland_c2", dim, H, 1e-3, HS, f32(x), f32(v), f32(rho), f32(m)))
    assert np.all(a == 0.0)


# ---- density diffusion ----

C0 = 10.0  # sound speed of the diffusion tests (a dam break with H ~ 0.1 m uses 10 sqrt(g H))
RHO0, GAMMA, G = 1000.0, 7.0, 9.81


def diffusion(kind, dim, x, rho, m, delta=0.1, kernel="wendland_c2"):
    return np.asarray(testing.sph_density_diffusion(kernel, dim, H, kind, delta, HS, C0, RHO0, GAMMA, G, f32(x),
                                                    f32(rho), f32(m)), np.float64)


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("kind", ["molteni", "fourtakas"])
def test_density_diffusion_conserves_mass(dim, kind):
    # V_i D_ij = -V_j D_ji pair by pair, so sum_i V_i drho_i/dt = 0 (V = m / rho) to float32
    # rounding of the pair terms: 1e-6 of sum_i |V_i drho_i/dt|; and the float64 reference
    # per particle (rtol 1e-4, absolute floor 1e-5 of the largest: float32 sums with
    # cancellation). The Fourtakas term is tested on a random (non-hydrostatic) field, where
    # its correction is not small.
    x, _, rho, _, m = particle_block(dim, 8 if dim == 2 else 5, DP, seed=50 + dim)
    rate = diffusion(kind, dim, x, rho, m)
    vol = m / rho
    total = np.abs(vol * rate).sum()
    assert total > 0
    assert abs(np.sum(vol * rate)) < 1e-6 * total
    ref = diffusion_ref(dim, H, kind, 0.1, HS, C0, RHO0, GAMMA, G, x, rho, m)
    np.testing.assert_allclose(rate, ref, rtol=1e-4, atol=1e-5 * np.abs(ref).max())


@pytest.mark.parametrize("dim", DIMS)
def test_density_diffusion_smooths_and_vanishes_for_uniform_density(dim):
    # uniform density: Molteni's term is exactly zero; one denser particle loses density and
    # its neighbours gain it (diffusion runs down the gradient)
    x, _, rho, _, m = particle_block(dim, 6 if dim == 2 else 4, DP, seed=60 + dim)
    rho[:] = 1000.0
    assert np.all(diffusion("molteni", dim, x, rho, m) == 0.0)
    centre = int(np.argmin(np.linalg.norm(x - x.mean(axis=0), axis=1)))
    rho[centre] = 1010.0
    rate = diffusion("molteni", dim, x, rho, m)
    assert rate[centre] < 0
    near = (np.linalg.norm(x - x[centre], axis=1) < H) & (np.arange(len(x)) != centre)
    assert np.all(rate[near] > 0)
    assert np.all(rate[~near & (np.arange(len(x)) != centre)] == 0.0)


def hydrostatic_block(dim, tait, seed):
    """A jittered water block (depth from its top particle) with the hydrostatic density:
    tait: rho = rho0 (1 + kz d)^(1/gamma) (Tait, B = c0^2 rho0 / gamma); else the linearised
    equation of state p = c0^2 (rho - rho0): rho = rho0 (1 + g d / c0^2)."""
    x, _, _, _, m = particle_block(dim, 10 if dim == 2 else 6, DP, seed=seed, jitter=0.1)
    depth = x[:, -1].max() - x[:, -1]
    if tait:
        rho = RHO0 * (1 + GAMMA * G / C0**2 * depth) ** (1 / GAMMA)
    else:
        rho = RHO0 * (1 + G * depth / C0**2)
    return x, rho.astype(F32).astype(np.float64), m


@pytest.mark.parametrize("dim", DIMS)
def test_fourtakas_correction_vanishes_for_hydrostatic_field(dim):
    # linearised hydrostatic field: rho_j - rho_i = rho0 g z_ij / c0^2, which the (odd)
    # Fourtakas rho^H_ji matches up to O((kz z)^3) ~ 1e-6 relative (kz = gamma g / c0^2 =
    # 0.69 / m, |z| < 2.4 cm). What remains is float32 rounding of the densities: an ulp of
    # 1000 is 6e-5 against a difference of ~1 kg/m^3 per spacing, so ~1e-4 of the uncorrected
    # term; bound 2e-3. Without the correction (Molteni) the particles at the block's top and
    # bottom, whose supports are cut, see an O(1) rate.
    x, rho, m = hydrostatic_block(dim, tait=False, seed=70 + dim)
    plain = diffusion("molteni", dim, x, rho, m)
    corrected = diffusion("fourtakas", dim, x, rho, m)
    scale = np.abs(plain).max()
    assert scale > 0
    assert np.abs(corrected).max() < 2e-3 * scale
    # the float64 reference of the corrected term on the same float32 field is small too
    ref = diffusion_ref(dim, H, "fourtakas", 0.1, HS, C0, RHO0, GAMMA, G, x, rho, m)
    assert np.abs(ref).max() < 2e-3 * scale


@pytest.mark.parametrize("dim", DIMS)
def test_fourtakas_correction_on_tait_hydrostatic_field(dim):
    # the Tait hydrostatic field: rho_j - rho_i = rho0 (1 + kz d_i)^(1/gamma - 1) kz z / gamma
    # + ..., while rho^H_ji is referred to rho0 (Fourtakas et al. 2019, as DualSPHysics): the
    # residual is first order in kz d_i, relative (1 - 1/gamma) kz d_max ~ 0.06 for this 9 cm
    # block (bound 1.5 times that), against O(1) without the correction
    x, rho, m = hydrostatic_block(dim, tait=True, seed=80 + dim)
    plain = diffusion("molteni", dim, x, rho, m)
    corrected = diffusion("fourtakas", dim, x, rho, m)
    kz = GAMMA * G / C0**2
    d_max = x[:, -1].max() - x[:, -1].min()
    bound = 1.5 * (1 - 1 / GAMMA) * kz * d_max
    assert bound < 0.2
    assert np.abs(corrected).max() < bound * np.abs(plain).max()


def test_fourtakas_rho_h_odd_form_matches_published_to_second_order():
    # rho^H_ji = rho0 / 2 ((1 + kz z)^(1/gamma) - (1 - kz z)^(1/gamma)) is odd in z exactly
    # (what mass conservation needs) and differs from the published rho0 ((1 + kz z)^(1/gamma)
    # - 1) by its even part, rho0 (1/gamma)(1/gamma - 1)/2 (kz z)^2 + O(z^4); float32 powf
    # of numbers near 1: absolute ~1e-7 rho0 = 1e-4
    z = np.linspace(-0.03, 0.03, 61)
    odd = np.asarray(testing.sph_fourtakas_rho_h(C0, RHO0, GAMMA, G, f32(z), False), np.float64)
    pub = np.asarray(testing.sph_fourtakas_rho_h(C0, RHO0, GAMMA, G, f32(z), True), np.float64)
    np.testing.assert_allclose(odd, -odd[::-1], atol=2e-4)
    np.testing.assert_allclose(odd, rho_h_odd(z, C0, RHO0, GAMMA, G), atol=2e-4)
    kz = GAMMA * G / C0**2
    even = RHO0 * (1 / GAMMA) * (1 / GAMMA - 1) / 2 * (kz * z) ** 2
    np.testing.assert_allclose(pub - odd, even, atol=2e-4 + 0.05 * np.abs(even).max())
    # both are the hydrostatic difference to first order: rho0 kz z / gamma = rho0 g z / c0^2
    np.testing.assert_allclose(odd, RHO0 * G * z / C0**2, rtol=0, atol=2e-4 + 1e-3 * np.abs(odd).max())
    assert np.abs(even).max() > 1e-2  # the forms do differ: the test can tell them apart


@pytest.mark.parametrize("gamma", [1.0, 1.4, 7.0, 20.0])
def test_fourtakas_odd_part_series_and_powers_match_float64(gamma):
    # the odd part is summed from its series for |kz z| <= 0.1 and from the powers past it;
    # both must give the float64 odd part to float32 accuracy (relative, and near zero absolute
    # against its slope rho0 kz / gamma), on both sides of the switch and past |kz z| = 1
    # (where a power's argument clamps at 0)
    kz = gamma * G / C0**2
    x = np.concatenate([np.linspace(-1.5, 1.5, 301), np.linspace(0.09, 0.11, 41), -np.linspace(0.09, 0.11, 41),
                        np.geomspace(1e-7, 1e-2, 30)])
    x = x[np.abs(np.abs(x) - 1.0) > 1e-2]  # (at |kz z| = 1 a power's slope is infinite: ill-conditioned)
    z = f32(x / kz).astype(np.float64)
    got = np.asarray(testing.sph_fourtakas_rho_h(C0, RHO0, gamma, G, f32(z), False), np.float64)
    ref = rho_h_odd(z, C0, RHO0, gamma, G)
    # the series: float32 rounding of the sum; the powers: of two numbers near 1, then their
    # difference (absolute, a few 1e-7 of rho0)
    series = np.abs(kz * z) < 0.0999  # (at the switch itself float32 rounding may take either)
    assert series.sum() > 50 and (~series).sum() > 50
    np.testing.assert_allclose(got[series], ref[series], rtol=1e-6, atol=0)
    np.testing.assert_allclose(got[~series], ref[~series], rtol=1e-6, atol=3e-7 * RHO0)
    # the first-order slope: a broken series (a wrong coefficient) is off by far more
    small = np.abs(kz * z) < 1e-3
    np.testing.assert_allclose(got[small], RHO0 * kz * z[small] / gamma, rtol=1e-5)


def test_unknown_diffusion_kind_is_refused():
    x = np.zeros((2, 2), F32)
    with pytest.raises(ValueError):
        testing.sph_density_diffusion("wendland_c2", 2, H, "antuono", 0.1, HS, C0, RHO0, GAMMA, G, x,
                                      np.ones(2, F32), np.ones(2, F32))


# ---- CFL step ----


def test_choose_dt_cfl_is_the_dualsphysics_form():
    # dt = C min(sqrt(hs / amax), hs / (c0 + mu_max)), clamped to [dt_min, dt_max] (float32)
    cfl, hs, c0 = 0.2, HS, 20.0
    for amax, mu_max in [(9.81, 0.0), (9.81, 3.0), (1e6, 0.5), (0.0, 1.0)]:
        expect = hs / (c0 + mu_max)
        if amax > 0:
            expect = min(expect, math.sqrt(hs / amax))
        expect *= cfl
        got = testing.sph_choose_dt_cfl(cfl, hs, amax, c0, mu_max, 1e-9, 1.0)
        assert got == pytest.approx(expect, rel=1e-6)
    # the force limit takes over for a large acceleration, the clamp for extremes
    assert testing.sph_choose_dt_cfl(cfl, hs, 1e6, c0, 0.0, 1e-9, 1.0) == pytest.approx(cfl * math.sqrt(hs / 1e6),
                                                                                          rel=1e-6)
    assert testing.sph_choose_dt_cfl(cfl, hs, 9.81, c0, 0.0, 1e-9, 1e-6) == pytest.approx(1e-6)
    assert testing.sph_choose_dt_cfl(cfl, hs, 9.81, c0, 0.0, 1e-3, 1.0) == pytest.approx(1e-3)
    assert testing.sph_choose_dt_cfl(cfl, hs, float("nan"), c0, float("nan"), 1e-5, 1.0) == pytest.approx(1e-5)


def test_choose_dt_cfl_viscous_limit():
    # a laminar nu adds Morris et al.'s (1997) diffusion limit 0.125 hs^2 / nu, not scaled by the
    # CFL number: it takes over exactly when it is the smallest, and nu = 0 leaves the CFL form
    cfl, hs, c0 = 0.2, HS, 20.0
    cfl_dt = cfl * min(hs / c0, math.sqrt(hs / 9.81))
    nu_cross = 0.125 * hs * hs / cfl_dt  # the viscosity at which both limits are equal
    for nu in (0.0, 0.5 * nu_cross, 2.0 * nu_cross, 50.0 * nu_cross):
        expect = cfl_dt if nu == 0.0 else min(cfl_dt, 0.125 * hs * hs / nu)
        got = testing.sph_choose_dt_cfl(cfl, hs, 9.81, c0, 0.0, 1e-12, 1.0, nu)
        assert got == pytest.approx(expect, rel=1e-6), nu
    assert testing.sph_choose_dt_cfl(cfl, hs, 9.81, c0, 0.0, 1e-12, 1.0, 2.0 * nu_cross) < cfl_dt


@pytest.mark.parametrize("dim", DIMS)
def test_cfl_mu_max_from_pairs(dim):
    # dt_cv takes max_j |mu_ij| over pairs: for a block, from sph_mu against float64
    x, v, _, _, _ = particle_block(dim, 6 if dim == 2 else 4, DP, seed=90 + dim)
    d, dv, r2, mask = pairs(x, v, H)
    dd, vv = d[mask], dv[mask]
    mu = np.asarray(testing.sph_mu(dim, HS, f32(dd), f32(vv)), np.float64)
    ref = HS * np.sum(dd * vv, axis=1) / (np.sum(dd * dd, axis=1) + 0.01 * HS * HS)
    assert np.abs(mu).max() == pytest.approx(np.abs(ref).max(), rel=1e-5)
    dt = testing.sph_choose_dt_cfl(0.2, HS, 0.0, 20.0, float(np.abs(mu).max()), 1e-9, 1.0)
    assert dt == pytest.approx(0.2 * HS / (20.0 + np.abs(ref).max()), rel=1e-5)


# ---- the transport-velocity formulation (Adami, Hu & Adams 2013) ----


def tvf_ref(dim, h, p_b, x, v, dvt, rho, m):
    """float64: the extra stress's acceleration (1/m_i) sum_j (V_i^2 + V_j^2) 1/2 (A_i + A_j) . grad W,
    A = rho v (v~ - v)^T, and the background push -(p_b / m_i) sum_j (V_i^2 + V_j^2) grad W."""
    d, _, _, mask = pairs(x, v, h)
    g = np.where(mask[..., None], wendland_grad(dim, h, d), 0.0)
    vol = m / rho
    s = (vol[:, None] ** 2 + vol[None, :] ** 2) / m[:, None]
    ai = rho[:, None, None] * v[:, None, :] * np.sum(dvt[:, None, :] * g, axis=-1)[..., None]
    aj = rho[None, :, None] * v[None, :, :] * np.sum(dvt[None, :, :] * g, axis=-1)[..., None]
    stress = np.sum(0.5 * s[..., None] * (ai + aj), axis=1)
    push = -p_b * np.sum(s[..., None] * g, axis=1)
    return stress, push


def tvf(dim, x, v, dvt, rho, m, p_b):
    out = np.asarray(testing.sph_tvf_terms("wendland_c2", dim, H, p_b, f32(x), f32(v), f32(dvt), f32(rho), f32(m)),
                     np.float64)
    return out[:, :dim], out[:, dim:]


@pytest.mark.parametrize("dim", DIMS)
def test_tvf_terms_match_reference_and_conserve_momentum(dim):
    # both terms against float64 per particle (rtol 1e-4, floor 1e-5 of the largest: float32 sums
    # with cancellation), and m_i a_ij = -m_j a_ji pair by pair: the sums of m a over the block
    # vanish to float32 rounding (1e-6 of sum |m a|); unequal masses and densities
    x, v, rho, c, m = particle_block(dim, 7 if dim == 2 else 4, DP, seed=60 + dim)
    rng = np.random.default_rng(70 + dim)
    dvt = np.asarray(rng.normal(scale=0.05, size=v.shape), F32).astype(np.float64)
    p_b = 1000.0 * 20.0**2
    stress, push = tvf(dim, x, v, dvt, rho, m, p_b)
    rs, rp = tvf_ref(dim, H, p_b, x, v, dvt, rho, m)
    np.testing.assert_allclose(stress, rs, rtol=1e-4, atol=1e-5 * np.abs(rs).max())
    np.testing.assert_allclose(push, rp, rtol=1e-4, atol=1e-5 * np.abs(rp).max())
    for a in (stress, push):
        f = m[:, None] * a
        assert np.abs(f).sum() > 0
        assert np.all(np.abs(f.sum(axis=0)) < 1e-6 * np.abs(f).sum())
    # no transport difference, no extra stress
    s0, _ = tvf(dim, x, v, np.zeros_like(dvt), rho, m, p_b)
    assert np.all(s0 == 0.0)


@pytest.mark.parametrize("dim", DIMS)
def test_tvf_push_restores_a_uniform_lattice(dim):
    # on a uniform lattice the push of every particle a support away from the block's edge
    # vanishes (sum_j grad W = 0 by symmetry, to float32 rounding); a particle moved off its
    # site is pushed back towards it, along the displacement (the restoring force that keeps
    # the particles evenly spread)
    n_side = 9 if dim == 2 else 7
    x, v, rho, c, m = particle_block(dim, n_side, DP, seed=80, jitter=0.0)
    rho[:] = 1000.0
    m[:] = 1000.0 * DP**dim
    p_b = 1000.0 * 20.0**2
    centre = np.all(np.abs(x - x.mean(0)) < 1e-9 + 0.5 * DP, axis=1)
    k = int(np.flatnonzero(centre)[0])
    _, push = tvf(dim, x, v, np.zeros_like(v), rho, m, p_b)
    inner = np.all((x >= x.min(0) + H) & (x <= x.max(0) - H), axis=1)
    assert inner.sum() >= 1 and inner[k]
    # the size of the terms that cancel: sum_j (p_b / m) (V_i^2 + V_j^2) |grad W|; float32 rounding
    # of their sum is ~1e-7 of it per term
    d, _, _, mask = pairs(x, v, H)
    g = np.where(mask[..., None], wendland_grad(dim, H, d), 0.0)
    scale = (p_b * 2.0 * (m / rho)[:, None] ** 2 / m[:, None] * np.linalg.norm(g, axis=-1)).sum(1)
    assert np.all(np.abs(push[inner]).max(1) < 1e-6 * scale[inner])
    shift = np.zeros(dim)
    shift[0], shift[-1] = 0.15 * DP, -0.1 * DP
    x2 = x.copy()
    x2[k] += shift
    _, push2 = tvf(dim, x2, v, np.zeros_like(v), rho, m, p_b)
    cos = np.dot(push2[k], shift) / (np.linalg.norm(push2[k]) * np.linalg.norm(shift))
    assert cos < -0.999 and np.linalg.norm(push2[k]) > 0.01 * scale[k]
