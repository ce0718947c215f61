"""The selectable SPH kernels of cpp/include/corpuscle/physics/sph_kernel_families.h (Poly6,
Spiky and the viscosity kernel of Mueller et al. 2003, the cubic spline of Monaghan 1992,
Wendland C2 with the Dehnen & Aly 2012 constants), in 2-D and 3-D, evaluated through
``corpuscle._testing.sph_kernel`` and checked against float64 NumPy: normalisation by
quadrature, gradient against finite differences, zero gradient sum on a symmetric lattice,
positivity and compact support, continuity, the published closed forms, and bit-identity of
the 3-D Poly6 / Spiky / viscosity Laplacian chosen at run time with the Magic 8-Ball's
MuellerKernels<3> (chosen at compile time).

Convention under test: h is the support radius for every kernel (W = 0 for r >= h); the
closed forms below are written in each paper's own variables (Monaghan's smoothing length
s = h / 2 for the cubic spline) so a wrong conversion shows.

The core computes in float32 (relative rounding ~6e-8 per operation); each tolerance says
what it allows for.
"""

import math

import numpy as np
import pytest

testing = pytest.importorskip("corpuscle._testing")
core = pytest.importorskip("corpuscle._core")

KERNELS = ["poly6", "spiky", "viscosity", "cubic_spline", "wendland_c2"]
SMOOTH = ["poly6", "spiky", "cubic_spline", "wendland_c2"]  # finite at r = 0
DIMS = [2, 3]
H_VALUES = [0.05, 0.0137]  # a wrong power of h shows with two unrelated values


def evaluate(kernel, dim, h, d, compile_time=False, from_r2=False):
    """The core's kernel at displacements d (n, dim): (W, grad W (n, dim), lap W) as float64."""
    d = np.ascontiguousarray(np.atleast_2d(d), dtype=np.float32)
    out = np.asarray(testing.sph_kernel(kernel, dim, float(h), d, compile_time, from_r2), dtype=np.float64)
    return out[:, 0], out[:, 1 : 1 + dim], out[:, 1 + dim]


# ---- the published closed forms, float64, as functions of r ----


def w_ref(kernel, dim, h, r):
    r = np.asarray(r, dtype=np.float64)
    inside = r < h
    if kernel == "poly6":  # Mueller 2003 eq. 20; 2-D normalised over the disc
        c = 315.0 / (64.0 * math.pi * h**9) if dim == 3 else 4.0 / (math.pi * h**8)
        w = c * np.clip(h * h - r * r, 0, None) ** 3
    elif kernel == "spiky":  # Mueller 2003 eq. 21
        c = 15.0 / (math.pi * h**6) if dim == 3 else 10.0 / (math.pi * h**5)
        w = c * np.clip(h - r, 0, None) ** 3
    elif kernel == "viscosity":
        rs = np.where(r > 0, r, 1.0)
        if dim == 3:  # Mueller 2003 eq. 22
            w = 15.0 / (2 * math.pi * h**3) * (-(rs**3) / (2 * h**3) + rs**2 / h**2 + h / (2 * rs) - 1)
        else:  # the 2-D kernel with lap W = 40 / (pi h^5) (h - r), W(h) = W'(h) = 0
            k = 40.0 / (math.pi * h**5)
            w = k * (h * rs**2 / 4 - rs**3 / 9 - 5 * h**3 / 36 - h**3 / 6 * np.log(rs / h))
        w = np.where(r > 0, w, 0.0)
    elif kernel == "cubic_spline":  # Monaghan 1992 (M4 spline), smoothing length s = h / 2, support 2 s
        s = h / 2
        sigma = (1.0 / math.pi if dim == 3 else 10.0 / (7.0 * math.pi)) / s**dim
        x = r / s
        w = sigma * np.where(x < 1, 1 - 1.5 * x**2 + 0.75 * x**3, 0.25 * np.clip(2 - x, 0, None) ** 3)
    elif kernel == "wendland_c2":  # Dehnen & Aly 2012 Table 1, support H = h
        C = 21.0 / (2 * math.pi) if dim == 3 else 7.0 / math.pi
        q = r / h
        w = C / h**dim * np.clip(1 - q, 0, None) ** 4 * (1 + 4 * q)
    else:
        raise ValueError(kernel)
    return np.where(inside, w, 0.0)


def grad_scale(kernel, dim, h):
    """A typical |grad W| (W's normalisation / h), for absolute tolerance floors."""
    return w_ref("wendland_c2", dim, h, 0.0) / h * 10


def random_inside(dim, h, count, seed, lo=0.05, hi=0.95):
    rng = np.random.default_rng(seed)
    dirs = rng.normal(size=(count, dim))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    r = h * rng.uniform(lo, hi, size=count)
    return (dirs * r[:, None]).astype(np.float32).astype(np.float64)


def midpoint_grid(dim, h, n):
    e = (np.arange(n) + 0.5) / n * 2 * h - h
    g = np.meshgrid(*([e] * dim), indexing="ij")
    return np.stack([x.ravel() for x in g], 1), (2 * h / n) ** dim


# ---- normalisation ----


@pytest.mark.parametrize("h", H_VALUES)
@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("kernel", SMOOTH)
def test_kernel_integrates_to_one_on_a_grid(kernel, dim, h):
    # midpoint quadrature of the core's W over [-h, h]^D (400^2 cells in 2-D, 80^3 in 3-D).
    # On the float64 closed forms this grid's error is below 4e-7 for every kernel here
    # (largest for Spiky, whose cusp at r = 0 the midpoint rule sees; measured when the test
    # was written); the float64 sum of float32 values adds ~1e-7. 1e-4 leaves a wide margin
    # and catches any wrong constant or power of h (the seed's Poly6 typo was O(1)).
    pts, dv = midpoint_grid(dim, h, 400 if dim == 2 else 80)
    w, _, _ = evaluate(kernel, dim, h, pts)
    assert abs(w.sum() * dv - 1.0) < 1e-4


@pytest.mark.parametrize("h", H_VALUES)
@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("kernel", KERNELS)
def test_kernel_integrates_to_one_radially(kernel, dim, h):
    # int_0^h W(r) S_D r^(D-1) dr (S_2 = 2 pi, S_3 = 4 pi) with r = h u^2 (which smooths the
    # viscosity kernel's 1/r and log r singularities at 0) and 200-point Gauss-Legendre in u,
    # split at u^2 = 1/2 for the cubic spline's junction. The core's W is taken along a fixed
    # oblique direction. Quadrature error on the float64 closed forms is < 1e-9 (checked below
    # as well); float32 values add ~1e-7: tolerance 1e-5.
    nodes, weights = np.polynomial.legendre.leggauss(200)
    pieces = [(0.0, math.sqrt(0.5)), (math.sqrt(0.5), 1.0)]
    direction = np.ones(dim) / math.sqrt(dim)
    sphere = 2 * math.pi if dim == 2 else 4 * math.pi
    total, total_ref = 0.0, 0.0
    for a, b in pieces:
        u = 0.5 * (b - a) * nodes + 0.5 * (b + a)
        wq = 0.5 * (b - a) * weights
        r = h * u * u
        jac = sphere * r ** (dim - 1) * 2 * h * u
        w, _, _ = evaluate(kernel, dim, h, r[:, None] * direction)
        total += np.sum(wq * jac * w)
        total_ref += np.sum(wq * jac * w_ref(kernel, dim, h, r))
    assert abs(total_ref - 1.0) < 1e-9
    assert abs(total - 1.0) < 1e-5


# ---- values ----


@pytest.mark.parametrize("h", H_VALUES)
@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("kernel", KERNELS)
def test_kernel_matches_published_closed_form(kernel, dim, h):
    # at fixed r/h (including the cubic spline's junction 1/2 and points either side of it)
    # and at 2000 random points: float32 evaluation, rtol 1e-5 with an absolute floor of 1e-6
    # of the kernel's scale (values vanish near r = h, where relative rounding grows)
    qs = np.array([0.1, 0.25, 0.4999, 0.5, 0.5001, 0.75, 0.9, 0.99])
    d = np.zeros((qs.size, dim))
    d[:, 0] = qs * h
    d = np.vstack([d, random_inside(dim, h, 2000, seed=11, lo=0.01, hi=0.999)])
    r = np.linalg.norm(d, axis=1)
    w, _, _ = evaluate(kernel, dim, h, d)
    scale = w_ref("wendland_c2", dim, h, 0.0)
    np.testing.assert_allclose(w, w_ref(kernel, dim, h, r), rtol=1e-5, atol=1e-6 * scale)


@pytest.mark.parametrize("dim", DIMS)
def test_kernel_values_at_the_origin(dim):
    # W(0) in closed form (h = 1): the self term of every density sum
    h = 1.0
    expect = {
        "poly6": 315.0 / (64 * math.pi) if dim == 3 else 4.0 / math.pi,
        "spiky": 15.0 / math.pi if dim == 3 else 10.0 / math.pi,
        "cubic_spline": 8.0 / math.pi if dim == 3 else 40.0 / (7 * math.pi),
        "wendland_c2": 21.0 / (2 * math.pi) if dim == 3 else 7.0 / math.pi,
    }
    for kernel, value in expect.items():
        w, g, _ = evaluate(kernel, dim, h, np.zeros(dim))
        assert w[0] == pytest.approx(value, rel=1e-6), kernel
        assert np.all(g == 0.0), kernel


# ---- gradient ----


def radial_fd_grad(kernel, dim, h, d, step):
    """Central difference of the float64 closed form along each axis."""
    fd = np.empty_like(d)
    for k in range(dim):
        e = np.zeros(dim)
        e[k] = step
        fd[:, k] = (w_ref(kernel, dim, h, np.linalg.norm(d + e, axis=1)) -
                    w_ref(kernel, dim, h, np.linalg.norm(d - e, axis=1))) / (2 * step)
    return fd


@pytest.mark.parametrize("h", H_VALUES)
@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("kernel", KERNELS)
def test_gradient_matches_finite_difference_of_closed_form(kernel, dim, h):
    # central difference of the float64 W with step 1e-6 h (truncation ~1e-12, roundoff
    # ~1e-10 relative); the core's float32 gradient is good to a few 1e-7: rtol 1e-5 with an
    # absolute floor of 1e-6 of the gradient scale. Points avoid r < 0.05 h (the viscosity
    # kernel's singularity) and the last 5% before h.
    d = random_inside(dim, h, 500, seed=3)
    _, g, _ = evaluate(kernel, dim, h, d)
    fd = radial_fd_grad(kernel, dim, h, d, 1e-6 * h)
    np.testing.assert_allclose(g, fd, rtol=1e-5, atol=1e-6 * grad_scale(kernel, dim, h))
    # every kernel decreases with r: grad_i W points from x_i towards x_j (against d)
    assert np.all(np.einsum("ij,ij->i", g, d) < 0)


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("kernel", KERNELS)
def test_gradient_matches_finite_difference_of_core_w(kernel, dim):
    # the core's own W and grad W agree (independent of the NumPy closed forms): central
    # difference of the float32 W with step 1e-3 h; roundoff 6e-8 W / 1e-3 ~ 1e-4 of the
    # gradient scale, truncation ~ step^2 W''' ~ 1e-6: atol 2e-3 of the scale, rtol 2e-3
    h = 1.0
    d = random_inside(dim, h, 300, seed=4, lo=0.1, hi=0.9)
    _, g, _ = evaluate(kernel, dim, h, d)
    step = 1e-3 * h
    fd = np.empty_like(d)
    for k in range(dim):
        e = np.zeros(dim)
        e[k] = step
        fd[:, k] = (evaluate(kernel, dim, h, d + e)[0] - evaluate(kernel, dim, h, d - e)[0]) / (2 * step)
    np.testing.assert_allclose(g, fd, rtol=2e-3, atol=2e-3 * grad_scale(kernel, dim, h))


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("spacing", [0.3, 0.45])
def test_gradient_sums_to_zero_on_symmetric_lattice(kernel, dim, spacing):
    # a square / cubic lattice around a particle at the origin is point-symmetric, so
    # sum_j grad W(x_0 - x_j) = 0; each pair cancels only to float32 rounding of its own
    # value: 1e-6 of sum_j |grad W| (~20 ulps); off-centre the sum must not vanish
    h = 0.05
    m = int(math.ceil(1.0 / spacing)) + 1
    ax = np.arange(-m, m + 1) * spacing * h
    xj = np.stack([x.ravel() for x in np.meshgrid(*([ax] * dim), indexing="ij")], 1)
    xj = xj[np.linalg.norm(xj, axis=1) > 0]
    _, g, _ = evaluate(kernel, dim, h, -xj)
    total = np.abs(g).sum()
    assert total > 0
    assert np.all(np.abs(g.sum(axis=0)) < 1e-6 * total)
    shift = np.zeros(dim)
    shift[0] = 0.2 * spacing * h
    _, g_off, _ = evaluate(kernel, dim, h, shift - xj)
    assert abs(g_off.sum(axis=0)[0]) > 1e-3 * np.abs(g_off).sum()


# ---- sign, support, continuity ----


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("kernel", KERNELS)
def test_kernel_nonnegative_and_zero_beyond_support(kernel, dim):
    h = 0.05
    inside = random_inside(dim, h, 2000, seed=5, lo=0.001, hi=0.9999)
    w, _, _ = evaluate(kernel, dim, h, inside)
    assert np.all(w >= 0.0)
    assert np.all(w[np.linalg.norm(inside, axis=1) < 0.99 * h] > 0.0)
    out = random_inside(dim, h, 500, seed=6, lo=1.0001, hi=3.0)
    at = np.zeros((1, dim))
    at[0, 0] = h
    w_out, g_out, _ = evaluate(kernel, dim, h, np.vstack([at, out]))
    assert np.all(w_out == 0.0)
    assert np.all(g_out == 0.0)


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("kernel", KERNELS)
def test_kernel_continuous_at_support(kernel, dim):
    # W and grad W fall to zero at r = h: at r = (1 - 1e-3) h both are below 1e-5 of their
    # scale (each kernel vanishes there at least as (h - r)^2: <= ~1e-6 times its constant)
    h = 0.05
    d = np.zeros((1, dim))
    d[0, 0] = (1 - 1e-3) * h
    w, g, _ = evaluate(kernel, dim, h, d)
    scale = w_ref("wendland_c2", dim, h, 0.0)
    assert 0.0 <= w[0] < 1e-5 * scale
    assert np.abs(g).max() < 1e-5 * grad_scale(kernel, dim, h)


@pytest.mark.parametrize("dim", DIMS)
def test_cubic_spline_continuous_at_its_junction(dim):
    # the two pieces meet at r = h / 2 with equal W and grad W (the spline is C^2): at the
    # float32 just below 1/2 (inner piece) and at 1/2 (outer piece) the values differ by the
    # slope times one ulp (3e-8 h): relative ~2e-7 for W (W' / W = -6 / h there) and ~1e-7
    # for grad W; rel 1e-6. A wrong piece constant would differ by O(1).
    h = 1.0
    d = np.zeros((2, dim), dtype=np.float32)
    d[:, 0] = [np.nextafter(np.float32(0.5), np.float32(0)), np.float32(0.5)]
    w, g, _ = evaluate("cubic_spline", dim, h, d)
    assert w[0] == pytest.approx(w[1], rel=1e-6)
    assert g[0, 0] == pytest.approx(g[1, 0], rel=1e-6)


# ---- the viscosity kernel's Laplacian ----


@pytest.mark.parametrize("dim", DIMS)
def test_viscosity_laplacian_is_the_laplacian_of_w(dim):
    # lap W = W'' + (D - 1) W' / r of the float64 closed form by central differences (step
    # 1e-4 h: truncation ~1e-8, roundoff ~1e-16 / 1e-8 = 1e-8 relative) against the core's
    # lap = 45 / (pi h^6) (h - r) (3-D) or 40 / (pi h^5) (h - r) (2-D): float32, rtol 1e-5
    h = 1.0
    r = np.linspace(0.1, 0.95, 40) * h
    s = 1e-4 * h
    wr = lambda x: w_ref("viscosity", dim, h, x)
    lap_fd = (wr(r + s) - 2 * wr(r) + wr(r - s)) / s**2 + (dim - 1) * (wr(r + s) - wr(r - s)) / (2 * s * r)
    d = np.zeros((r.size, dim))
    d[:, 0] = r
    _, _, lap = evaluate("viscosity", dim, h, d)
    c = 45.0 / (math.pi * h**6) if dim == 3 else 40.0 / (math.pi * h**5)
    np.testing.assert_allclose(lap, c * (h - r), rtol=1e-5)
    np.testing.assert_allclose(lap_fd, c * (h - r), rtol=1e-5, atol=1e-5 * c * h)


# ---- selection and the 8-ball's kernels ----


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("kernel", KERNELS)
def test_compile_time_and_run_time_selection_agree_bitwise(kernel, dim):
    # Kernel<D, K> and SphKernel<D> (the kind code) run the same formulas, W(r) and W(r^2)
    d = random_inside(dim, 0.05, 500, seed=7, lo=0.0, hi=1.2)
    for from_r2 in (False, True):
        a = evaluate(kernel, dim, 0.05, d, compile_time=False, from_r2=from_r2)
        b = evaluate(kernel, dim, 0.05, d, compile_time=True, from_r2=from_r2)
        for x, y in zip(a[:2], b[:2]):
            np.testing.assert_array_equal(x, y)
    # W(r^2) agrees with W(r) up to the rounding of r = sqrt(r^2) (a few float32 ulps; the
    # relative effect grows as (h - r)^-k near the support, hence the absolute floor)
    w_r, _, _ = evaluate(kernel, dim, 0.05, d)
    w_r2, _, _ = evaluate(kernel, dim, 0.05, d, from_r2=True)
    np.testing.assert_allclose(w_r2, w_r, rtol=1e-5, atol=1e-6 * w_ref("wendland_c2", dim, 0.05, 0.0))


@pytest.mark.parametrize("h", H_VALUES)
def test_3d_muller_set_bitwise_equal_to_magic8ball_kernels(h):
    # the run-time selected Poly6 (from r^2), Spiky gradient and viscosity Laplacian equal the
    # 8-ball's compile-time set MuellerKernels<3> (corpuscle._core.sph_kernels) bit for bit
    d = random_inside(3, h, 2000, seed=8, lo=0.0, hi=1.1).astype(np.float32)
    old = np.asarray(core.sph_kernels(float(h), d), dtype=np.float64)
    w, _, _ = evaluate("poly6", 3, h, d, from_r2=True)
    _, g, _ = evaluate("spiky", 3, h, d)
    _, _, lap = evaluate("viscosity", 3, h, d)
    np.testing.assert_array_equal(w, old[:, 0])
    np.testing.assert_array_equal(g, old[:, 1:4])
    np.testing.assert_array_equal(lap, old[:, 4])


def test_unknown_kernel_and_dimension_are_refused():
    with pytest.raises(ValueError):
        testing.sph_kernel("gaussian", 3, 1.0, np.zeros((1, 3), np.float32))
    with pytest.raises(ValueError):
        testing.sph_kernel("wendland_c2", 4, 1.0, np.zeros((1, 4), np.float32))
    with pytest.raises(ValueError):
        testing.sph_kernel("wendland_c2", 2, 1.0, np.zeros((1, 3), np.float32))
