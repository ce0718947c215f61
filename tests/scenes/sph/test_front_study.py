"""The dam-break convergence study's arithmetic on synthetic fronts with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corpuscle.validation import front_study as fs

T = np.round(np.arange(0.25, 5.0 + 1e-9, 0.125), 6)


def exact(t):
    return 1.0 + 0.25 * t * t / (1.0 + 0.1 * t)  # a smooth front, Z(0) = 1, accelerating


@pytest.mark.parametrize("p", [0.8, 1.0, 2.0])
def test_order_and_richardson_recover_a_power_law(p):
    h = np.array([4.0, 2.0, 1.0]) * 0.01
    err = np.sin(T) + 2.0  # a T-dependent error coefficient
    fronts = [exact(T) + 3.0 * err * hk ** p for hk in h]
    got, R = fs.observed_order(*fronts)
    assert got == pytest.approx(p, abs=1e-9) and R == pytest.approx(2.0 ** -p)
    zinf, u = fs.richardson(fronts[1], fronts[2], got)
    np.testing.assert_allclose(zinf, exact(T), atol=1e-12)
    # the GCI band is 1.25 times the (here exact) error of the finest run
    np.testing.assert_allclose(u, 1.25 * np.abs(fronts[2] - exact(T)), rtol=1e-9)


def test_divergent_or_oscillating_runs_have_no_order():
    a = exact(T)
    p, R = fs.observed_order(a, a + 0.1, a + 0.3)  # the change grows: not converging
    assert math.isnan(p) and R == pytest.approx(2.0)
    p, R = fs.observed_order(a, a + 0.1, a + 0.05)  # the change flips sign but shrinks: R < 1, monotone in norm
    assert R == pytest.approx(0.5) and p == pytest.approx(1.0)


@pytest.mark.parametrize("delay", [0.0, 0.175, 0.4, -0.1])
def test_fit_delay_recovers_a_shift(delay):
    refs = []
    for t0 in (0.8, 0.85):
        tr = np.arange(t0, 4.6, 0.4)
        refs.append(np.c_[tr, exact(tr - delay)])  # the data lag the model by `delay`
    got = fs.fit_delay(T, exact(T), refs)
    assert got == pytest.approx(delay, abs=2e-3)
    rms, n = fs.rms_against(T, exact(T), refs[0], got)
    assert rms < 2e-3 and n >= 8


def test_series_scatter():
    a = np.c_[np.linspace(0.8, 5, 9), np.linspace(1, 7, 9)]
    b = a.copy()
    b[:, 1] += 0.1
    assert fs.series_scatter(a, b) == pytest.approx(0.1 / math.sqrt(2), rel=1e-9)


def test_shipped_series():
    for name, file in fs.REFERENCES.items():
        ref = fs.read_series(file)
        assert ref.shape[1] == 2 and ref.shape[0] >= 10, name
        assert np.all(np.diff(ref[:, 0]) > 0) and np.all(np.diff(ref[:, 1]) > 0), name  # a front only advances
        assert 0.3 < ref[0, 0] < 1.0 and 1.0 < ref[0, 1] < 1.3, name


def test_analyse_of_a_study_that_leads_the_data():
    # three runs converging at first order to a front that is the data's, 0.2 earlier in T:
    # the fitted delay is 0.2 and the residual after it is the data's own (zero here) plus rounding
    data = {k: fs.read_series(v) for k, v in fs.REFERENCES.items()}
    mm = np.vstack([data[k] for k in fs.MARTIN_MOYCE])
    mm = mm[np.argsort(mm[:, 0])]
    truth = np.interp(T + 0.2, mm[:, 0], mm[:, 1])  # the model runs 0.2 ahead of the data
    fronts = [truth + 0.5 * h for h in (0.04, 0.02, 0.01)]
    st = fs.analyse(T, fronts, [0.04, 0.02, 0.01])
    assert st["p"] == pytest.approx(1.0) and st["delay"] == pytest.approx(0.2, abs=0.02)
    for k in fs.MARTIN_MOYCE:
        assert st["refs"][k]["rms_delayed"] < st["refs"][k]["rms_unshifted"]
        assert st["refs"][k]["lead"] > 0
    assert fs.residual_tolerance(st) == pytest.approx(2 * math.hypot(st["scatter"], st["u_rms"]))
