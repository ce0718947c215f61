"""The Magic 8-Ball's SPH kernels (MuellerKernels<3> of cpp/include/corpuscle/physics/sph_kernel_families.h), evaluated through
``corpuscle._core.sph_kernels`` and checked against independent float64 NumPy mathematics:
Poly6 normalisation, the Spiky gradient against a finite difference of the Spiky kernel,
zero gradient sum over a symmetric neighbourhood, the viscosity Laplacian, and the Poly6
mass fraction beyond a plane (the die renormalisation) against direct quadrature.

The core computes in float32, so every comparison allows for float32 rounding (relative
~1e-7 per operation); the tolerances below say how much more they allow and why.
"""

import math

import numpy as np
import pytest

core = pytest.importorskip("corpuscle._core")

# smoothing lengths: the scene's 0.05 m and an unrelated value, so a wrong power of h shows
H_VALUES = [0.05, 0.0137]


def kernels(h, d):
    """The core's kernels at displacements d (n, 3) as float64 columns:
    poly6, spiky gradient (3), viscosity Laplacian, Poly6 fraction beyond the plane z = d_z."""
    d = np.ascontiguousarray(np.atleast_2d(d), dtype=np.float32)
    return np.asarray(core.sph_kernels(float(h), d), dtype=np.float64)


def poly6_np(h, r):
    """Poly6 (Mueller et al. 2003, eq. 20) in float64."""
    r = np.asarray(r, dtype=np.float64)
    return np.where(r < h, 315.0 / (64.0 * math.pi * h**9) * np.clip(h * h - r * r, 0, None) ** 3, 0.0)


def spiky_np(h, r):
    """The Spiky kernel W = 15 / (pi h^6) (h - r)^3 (Mueller et al. 2003, eq. 21) in float64."""
    r = np.asarray(r, dtype=np.float64)
    return np.where(r < h, 15.0 / (math.pi * h**6) * np.clip(h - r, 0, None) ** 3, 0.0)


def midpoint_grid(h, n, nz=None):
    """Cell centres of an n x n x nz midpoint grid over the cube [-h, h]^3 (float64) and its cell volume."""
    nz = nz or n
    e = (np.arange(n) + 0.5) / n * 2 * h - h
    ez = (np.arange(nz) + 0.5) / nz * 2 * h - h
    x, y, z = np.meshgrid(e, e, ez, indexing="ij")
    return np.stack([x.ravel(), y.ravel(), z.ravel()], 1), ez, (2 * h / n) ** 2 * (2 * h / nz)


# random displacements inside the support, away from r = 0 and r = h (float32-exact inputs)
def random_inside(h, count, seed, lo=0.05, hi=0.95):
    rng = np.random.default_rng(seed)
    dirs = rng.normal(size=(count, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    r = h * rng.uniform(lo, hi, size=count)
    return (dirs * r[:, None]).astype(np.float32).astype(np.float64)


@pytest.mark.parametrize("h", H_VALUES)
def test_poly6_integrates_to_one(h):
    # midpoint quadrature of the core's Poly6 on a 96^3 grid over [-h, h]^3; Poly6 and its
    # first two derivatives vanish at r = h, so the midpoint rule is very accurate here
    # (float64 on the analytic kernel: |error| ~ 1e-9). The sum runs in float64 over float32
    # values (relative rounding 6e-8 each, random): 1e-4 leaves three orders of margin and
    # still catches any wrong constant (the seed's Poly6 typo was an O(1) error).
    pts, _, dv = midpoint_grid(h, 96)
    w = kernels(h, pts)[:, 0]
    assert abs(w.sum() * dv - 1.0) < 1e-4


@pytest.mark.parametrize("h", H_VALUES)
def test_poly6_matches_formula_and_support(h):
    # pointwise against 315/(64 pi h^9) (h^2 - r^2)^3; float32 evaluation: relative 1e-5
    # (a few float32 roundings of a cubed difference, amplified near r = h where the value
    # vanishes, hence the small absolute floor relative to W(0))
    d = random_inside(h, 2000, seed=1, lo=0.0, hi=0.999)
    r = np.linalg.norm(d, axis=1)
    w = kernels(h, d)[:, 0]
    ref = poly6_np(h, r)
    w0 = 315.0 / (64.0 * math.pi * h**3)
    np.testing.assert_allclose(w, ref, rtol=1e-5, atol=1e-6 * w0)
    # self term W(0) (used for every particle's density)
    np.testing.assert_allclose(kernels(h, [0.0, 0.0, 0.0])[0, 0], w0, rtol=1e-6)
    # compact support: zero at and beyond h
    out = random_inside(h, 200, seed=2, lo=1.0001, hi=3.0)
    assert np.all(kernels(h, out)[:, 0] == 0.0)


@pytest.mark.parametrize("h", H_VALUES)
def test_spiky_gradient_matches_finite_difference(h):
    # central difference of the float64 Spiky kernel with step 1e-6 h: truncation error
    # ~ (step)^2 W''' ~ 1e-12 relative, roundoff ~ 1e-16 / 1e-6 = 1e-10; the core's float32
    # gradient is accurate to a few 1e-7 relative, so rtol 1e-5 with an absolute floor of
    # 1e-6 of the gradient scale 45/(pi h^4) (tiny values near r = h)
    d = random_inside(h, 500, seed=3)
    g = kernels(h, d)[:, 1:4]
    step = 1e-6 * h
    fd = np.empty_like(d)
    for k in range(3):
        e = np.zeros(3)
        e[k] = step
        plus, minus = np.linalg.norm(d + e, axis=1), np.linalg.norm(d - e, axis=1)
        fd[:, k] = (spiky_np(h, plus) - spiky_np(h, minus)) / (2 * step)
    scale = 45.0 / (math.pi * h**4)
    np.testing.assert_allclose(g, fd, rtol=1e-5, atol=1e-6 * scale)
    # it points from j to i's opposite: the gradient w.r.t. x_i of a kernel decreasing in r is -r_hat
    assert np.all(np.einsum("ij,ij->i", g, d) < 0)


@pytest.mark.parametrize("h", H_VALUES)
def test_spiky_gradient_zero_at_origin_and_outside(h):
    # r = 0 (the particle itself) and r >= h give exactly zero (no self force, compact support)
    assert np.all(kernels(h, [0.0, 0.0, 0.0])[0, 1:4] == 0.0)
    out = random_inside(h, 200, seed=4, lo=1.0001, hi=3.0)
    assert np.all(kernels(h, out)[:, 1:4] == 0.0)


@pytest.mark.parametrize("h", H_VALUES)
@pytest.mark.parametrize("spacing", [0.3, 0.45])
def test_spiky_gradient_sums_to_zero_on_symmetric_lattice(h, spacing):
    # a cubic lattice of spacing * h around a particle at the origin: the neighbourhood is
    # point-symmetric, so sum_j grad W(x_0 - x_j) = 0 (SPlisHSPlasH KernelTests). Each
    # gradient pair cancels only up to float32 rounding of its own value, so the sum is
    # compared with sum_j |grad W|: 1e-6 is ~20 float32 ulps of the total
    m = int(math.ceil(1.0 / spacing)) + 1
    ax = np.arange(-m, m + 1) * spacing * h
    x, y, z = np.meshgrid(ax, ax, ax, indexing="ij")
    xj = np.stack([x.ravel(), y.ravel(), z.ravel()], 1)
    xj = xj[np.linalg.norm(xj, axis=1) > 0]
    g = kernels(h, -xj)[:, 1:4]
    total = np.abs(g).sum()
    assert total > 0
    assert np.all(np.abs(g.sum(axis=0)) < 1e-6 * total)
    # the same lattice seen from an off-centre particle is not symmetric: the test can fail
    g_off = kernels(h, np.array([0.2 * spacing * h, 0.0, 0.0]) - xj)[:, 1:4]
    assert abs(g_off.sum(axis=0)[0]) > 1e-3 * np.abs(g_off).sum()


@pytest.mark.parametrize("h", H_VALUES)
def test_viscosity_laplacian(h):
    # positive inside the support and compared with 45/(pi h^6) (h - r): float32, rtol 1e-5
    # with an absolute floor of 1e-6 of the value at r = 0 (values vanish linearly at r = h)
    d = random_inside(h, 1000, seed=5, lo=0.0, hi=0.999)
    r = np.linalg.norm(d, axis=1)
    lap = kernels(h, d)[:, 4]
    assert np.all(lap > 0)
    ref = 45.0 / (math.pi * h**6) * (h - r)
    np.testing.assert_allclose(lap, ref, rtol=1e-5, atol=1e-6 * 45.0 / (math.pi * h**5))
    # zero at and outside the support
    out = random_inside(h, 200, seed=6, lo=1.0, hi=3.0)
    out[0] = [h, 0.0, 0.0]
    assert np.all(kernels(h, out)[:, 4] == 0.0)


@pytest.mark.parametrize("h", H_VALUES)
def test_poly6_fraction_beyond_plane_matches_quadrature(h):
    # the fraction of the core's own Poly6 mass in the half-space z > d, by midpoint
    # quadrature on a 64 x 64 x 256 grid whose z cell faces fall on every d below (d = k h / 8):
    # the z midpoint rule is accurate to ~6e-6 here (measured on the analytic kernel), so an
    # absolute tolerance of 1e-4 leaves a wide margin and still catches a wrong polynomial
    # coefficient (each changes the fraction by > 1e-3 somewhere in (-h, h))
    nz = 256
    pts, ez, dv = midpoint_grid(h, 64, nz)
    w = kernels(h, pts)[:, 0].reshape(64, 64, nz)
    marginal = w.sum(axis=(0, 1)) * dv  # kernel mass per z slab
    ds = np.arange(-8, 9) * h / 8
    ref = np.array([marginal[ez > d].sum() for d in ds])
    got = kernels(h, np.stack([np.zeros_like(ds), np.zeros_like(ds), ds], 1))[:, 5]
    np.testing.assert_allclose(got, ref, atol=1e-4)
    # exact values: half at the particle, all at d = -h, none at d = h (float32: 1e-6)
    assert got[8] == pytest.approx(0.5, abs=1e-6)
    assert got[0] == pytest.approx(1.0, abs=1e-6)
    assert got[-1] == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("h", H_VALUES)
def test_poly6_fraction_beyond_plane_shape(h):
    # Gamma(d) + Gamma(-d) = 1 (the two half-spaces), monotone decreasing in d, clamped
    # outside [-h, h]; only the plane distance d_z matters (x, y of d are ignored);
    # float32 evaluation of a degree-9 polynomial: 1e-6 absolute
    ds = np.linspace(-1.5 * h, 1.5 * h, 301)
    z = np.zeros_like(ds)
    up = kernels(h, np.stack([z, z, ds], 1))[:, 5]
    down = kernels(h, np.stack([z, z, -ds], 1))[:, 5]
    np.testing.assert_allclose(up + down, 1.0, atol=1e-6)
    assert np.all(np.diff(up) <= 1e-7)
    assert np.all(np.abs(up[ds <= -h] - 1.0) < 1e-6)
    assert np.all(np.abs(up[ds >= h]) < 1e-6)
    shifted = kernels(h, np.stack([z + 0.3 * h, z - 0.7 * h, ds], 1))[:, 5]
    np.testing.assert_allclose(shifted, up, atol=1e-6)
