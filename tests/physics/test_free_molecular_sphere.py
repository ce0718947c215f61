"""corpuscle.free_molecular.sphere: the closed-form drag of a frictionless sphere in a collisionless
gas against the surface integral of the element pressure coefficient (Gauss-Legendre in cos theta,
float64), and its limits (Newtonian cold beam, the specular sphere's known values)."""

import functools
import math

import numpy as np
import pytest

from corpuscle import free_molecular as fm


@functools.lru_cache
def _nodes(n):
    return np.polynomial.legendre.leggauss(n)  # seconds on a loaded machine: once


def integrated(S, e, n=160):
    """C_D = 2 int_{-1}^{1} C_p(mu) mu dmu, by Gauss-Legendre quadrature (the integrand is
    entire: 160 nodes reach roundoff)."""
    mu, w = _nodes(n)
    return 2.0 * float(np.sum(w * fm.pressure_coefficient(mu, S, e) * mu))


@pytest.mark.parametrize("S", [0.3, 1.0, 2.0, 5.0, 12.0])
@pytest.mark.parametrize("e", [1.0, 0.6, 0.0])
def test_closed_form_is_the_surface_integral(S, e):
    assert fm.sphere(S, e) == pytest.approx(integrated(S, e), rel=1e-10)


def test_limits():
    # the cold beam: Newtonian, 2 for a specular sphere, 1 + e in general
    assert fm.sphere(math.inf, 1.0) == 2.0 and fm.sphere(math.inf, 0.5) == 1.5
    assert fm.sphere(1e4, 1.0) == pytest.approx(2.0, rel=1e-6)
    # a slow stream: the drag grows as 1 / S (the thermal particles' momentum over q)
    assert fm.sphere(0.01, 1.0) * 0.01 == pytest.approx(fm.sphere(0.005, 1.0) * 0.005, rel=1e-3)
    with pytest.raises(ValueError, match="speed_ratio must be positive"):
        fm.sphere(0.0)
