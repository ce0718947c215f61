"""The dam-break surge front as a convergence study: runs at three or more resolutions, the
observed order, a Richardson estimate of the converged front with its uncertainty, and that
front against both Martin & Moyce (1952) series and Koshizuka & Oka (1996), unshifted and with
one gate-opening delay fitted once.

Why a study and not "a finer run is closer": the fronts converge (at about first order) to one
that leads Martin & Moyce's. Their gate took a finite time to open, which the released column
of a simulation does not; codes that compare with them either shift the data by a delay in T
or report the lead unshifted. Here both are reported, the delay is fitted once over both
Martin & Moyce series together (the one free number, printed beside the literature's 0.175 in
T), and the checks are on what a correct solver must show: convergence (monotone, with an
order in a sane range) and a residual after the fit within the data's own scatter and the
study's numerical uncertainty.

The pure functions (:func:`observed_order`, :func:`richardson`, :func:`fit_delay`,
:func:`series_scatter`) take arrays and are tested on synthetic data with known answers.
"""

from __future__ import annotations

import math
import pathlib

import numpy as np

DATA = pathlib.Path(__file__).resolve().parent.parent / "data"
# Martin & Moyce's two n^2 = 2 series and Koshizuka & Oka's set (T = t sqrt(2g/a), Z = x/a)
REFERENCES = {
    "Martin & Moyce a = 1.125 in": "martin_moyce1952_a1125.csv",
    "Martin & Moyce a = 2.25 in": "martin_moyce1952_a225.csv",
    "Koshizuka & Oka": "dam_break_martin_moyce.csv",
}
MARTIN_MOYCE = tuple(k for k in REFERENCES if k.startswith("Martin"))
# the delay in T one widely used CFD code adds to the simulated time before comparing with
# Martin & Moyce (their gate's opening); the fitted delay is printed beside it
LITERATURE_DELAY = 0.175
GCI_SAFETY = 1.25  # Roache's factor of safety for a three-grid study
ORDER_RANGE = (0.5, 3.0)  # observed orders a convergent front of a WCSPH solver may show


def read_series(name: str) -> np.ndarray:
    """(T, Z) rows of one shipped reference file."""
    rows = []
    for line in (DATA / name).read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#") or line[0].isalpha():
            continue
        t, z = line.split(",")[:2]
        rows.append((float(t), float(z)))
    return np.array(rows, dtype=float)


def observed_order(coarse: np.ndarray, medium: np.ndarray, fine: np.ndarray, ratio: float = 2.0) -> tuple[float, float]:
    """(p, R): the observed order from the rms differences of three solutions on a common T grid
    at spacings ratio^2 h, ratio h, h, and the convergence ratio R = |e_fine| / |e_coarse| (0 < R <
    1: monotone convergence; R >= 1: not converging; p is NaN then)."""
    e12 = float(np.sqrt(np.mean((np.asarray(medium) - np.asarray(coarse)) ** 2)))
    e23 = float(np.sqrt(np.mean((np.asarray(fine) - np.asarray(medium)) ** 2)))
    if e12 == 0.0:
        return math.nan, math.nan
    R = e23 / e12
    if not 0.0 < R < 1.0:
        return math.nan, R
    return math.log(1.0 / R) / math.log(ratio), R


def richardson(medium: np.ndarray, fine: np.ndarray, p: float, ratio: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """(the extrapolated solution, its uncertainty): Z_inf = Z_f + (Z_f - Z_m) / (r^p - 1) and
    Roache's grid convergence index of the fine solution, 1.25 |Z_f - Z_m| / (r^p - 1), as an
    absolute band around Z_inf."""
    medium, fine = np.asarray(medium, float), np.asarray(fine, float)
    d = (fine - medium) / (ratio ** p - 1.0)
    return fine + d, GCI_SAFETY * np.abs(d)


def shifted(T: np.ndarray, Z: np.ndarray, ref: np.ndarray, delay: float) -> tuple[np.ndarray, np.ndarray]:
    """(reference Z, model Z) at the reference's T where the model, delayed by `delay` (the model
    at T - delay against the data at T), is known."""
    Tq = ref[:, 0] - delay
    ok = (Tq >= T[0]) & (Tq <= T[-1])
    return ref[ok, 1], np.interp(Tq[ok], T, Z)


def rms_against(T: np.ndarray, Z: np.ndarray, ref: np.ndarray, delay: float = 0.0) -> tuple[float, int]:
    """(rms of data - model, points compared) with the model delayed by `delay` in T."""
    zr, zm = shifted(T, Z, ref, delay)
    if zr.size == 0:
        return math.nan, 0
    return float(np.sqrt(np.mean((zr - zm) ** 2))), int(zr.size)


def fit_delay(T: np.ndarray, Z: np.ndarray, refs: list[np.ndarray], lo: float = -0.5, hi: float = 1.0) -> float:
    """The one delay in T that minimises the rms difference over every point of every series in
    `refs` together (least squares, by a fine scan then a golden-section refinement); points the
    delayed model does not reach are left out at every candidate alike (the comparison range is
    the same for all candidates: the model's T range shortened by `hi` at the end and `lo` at the
    start)."""
    keep = [r[(r[:, 0] - hi >= T[0]) & (r[:, 0] - lo <= T[-1])] for r in refs]
    pts = np.concatenate([k for k in keep if k.size]) if any(k.size for k in keep) else np.empty((0, 2))
    if pts.shape[0] < 2:
        raise ValueError("the fronts do not overlap the data enough to fit a delay")

    def cost(d: float) -> float:
        return float(np.mean((pts[:, 1] - np.interp(pts[:, 0] - d, T, Z)) ** 2))

    grid = np.linspace(lo, hi, 301)
    k = int(np.argmin([cost(d) for d in grid]))
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    g = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(60):
        c, d = b - g * (b - a), a + g * (b - a)
        if cost(c) < cost(d):
            b = d
        else:
            a = c
    return 0.5 * (a + b)


def series_scatter(a: np.ndarray, b: np.ndarray) -> float:
    """The experiment's own scatter: the rms difference between two series of the same
    experiment (each interpolated where the other has points, within the common T range),
    divided by sqrt(2), the scatter of one series about their common truth."""
    diffs = []
    for x, y in ((a, b), (b, a)):
        ok = (x[:, 0] >= y[0, 0]) & (x[:, 0] <= y[-1, 0])
        diffs.append(x[ok, 1] - np.interp(x[ok, 0], y[:, 0], y[:, 1]))
    d = np.concatenate(diffs)
    return float(np.sqrt(np.mean(d ** 2)) / math.sqrt(2.0))


def analyse(T: np.ndarray, fronts: list[np.ndarray], spacings: list[float]) -> dict:
    """The study of one dimension: fronts (on the common grid T) at spacings ratio 2 apart,
    coarse to fine; the finest three make the estimate."""
    if len(fronts) < 3:
        raise ValueError("a convergence study needs three or more resolutions")
    ratio = spacings[-2] / spacings[-1]
    p, R = observed_order(fronts[-3], fronts[-2], fronts[-1], ratio)
    out = {"T": T, "p": p, "R": R, "ratio": ratio}
    if math.isnan(p):
        out.update(Zinf=fronts[-1], U=np.full_like(fronts[-1], math.nan))
        return out
    Zinf, U = richardson(fronts[-2], fronts[-1], p, ratio)
    out.update(Zinf=Zinf, U=U)
    refs = {k: read_series(v) for k, v in REFERENCES.items()}
    delay = fit_delay(T, Zinf, [refs[k] for k in MARTIN_MOYCE])
    out["delay"] = delay
    out["scatter"] = series_scatter(*(refs[k] for k in MARTIN_MOYCE))
    out["u_rms"] = float(np.sqrt(np.mean(U ** 2)))
    out["refs"] = {}
    for k, ref in refs.items():
        raw, n0 = rms_against(T, Zinf, ref, 0.0)
        fit, n1 = rms_against(T, Zinf, ref, delay)
        # the lead of the converged front over the data at equal T (unshifted), mean over the points
        zr, zm = shifted(T, Zinf, ref, 0.0)
        out["refs"][k] = {"rms_unshifted": raw, "rms_delayed": fit, "points": n1,
                          "lead": float(np.mean(zm - zr)) if zr.size else math.nan}
    return out


def residual_tolerance(study: dict) -> float:
    """What the residual after the fit may be: twice (a 95 % band) the root sum of squares of the
    experiment's scatter (from its two series) and the study's numerical uncertainty (the rms of
    the grid convergence index)."""
    return 2.0 * math.hypot(study["scatter"], study["u_rms"])
