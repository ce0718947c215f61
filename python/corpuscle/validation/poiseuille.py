"""``corpuscle validate poiseuille``: 2-D Poiseuille flow started from rest.

A channel of width W = 1 m between DBC walls at y = 0 and y = W, periodic in x (a period of
0.5 m), driven by a body force F = 0.8 m/s^2 along x, nu = 0.1 m^2/s (laminar viscosity),
c0 = 10 u_max. The velocity (Morris, Fox & Zhu 1997, eq. 22) is

    u(y, t) = F y (W - y) / (2 nu)
              - sum_n 4 F W^2 / (nu pi^3 (2n+1)^3) sin((2n+1) pi y / W) exp(-(2n+1)^2 pi^2 nu t / W^2)

with the steady peak u_max = F W^2 / (8 nu) = 1 m/s (Re = u_max W / nu = 10). The particles'
x-velocities are averaged in layers of one spacing across the channel and compared with it at
t = 0.1, 0.2 and 0.4 s (the transient) and at t = 3 s (three viscous times W^2 / (pi^2 nu):
within 5 % of steady; the series carries what is left of the transient). Runs W / dp = 20 (``--full``: 20 and 40, and the profile error's order).

Tolerances (relative to u_max, each written beside its check): DBC walls put the no-slip
condition not at the wall's face but between it and the first layer of wall particles, up to
one spacing beyond the face (Crespo et al. 2007; English et al. 2022 move it back with their
modified DBC, which is not made here): a channel widened by dp on each side carries a profile
higher by up to u'(wall) dp = 4 u_max dp / W, 20 % at W / dp = 20 (10 % at 40); weak
compressibility adds O(Ma^2) = 1 %. (Measured: the profile is that of a wall about 0.6 dp
beyond the face, a near-uniform excess of 0.13 u_max at W / dp = 20.)
"""

from __future__ import annotations

import math

import numpy as np

from . import Check, within
from ._canonical import make_sim, observed_order, particles

W, F, NU = 1.0, 0.8, 0.1
UMAX = F * W ** 2 / (8.0 * NU)
TIMES = (0.1, 0.2, 0.4, 3.0)
RES_CI = (20,)
RES_FULL = (20, 40)
MACH = 0.1


def add_arguments(parser) -> None:
    from ._common import add_engine

    add_engine(parser)
    parser.add_argument("--full", action="store_true", help="W / dp = 20 and 40 (default: 20)")


def series(y: np.ndarray, t: float, terms: int = 200) -> np.ndarray:
    """The start-up Poiseuille profile u(y, t) (Morris et al. 1997, eq. 22), float64."""
    y = np.asarray(y, dtype=np.float64)
    u = F * y * (W - y) / (2.0 * NU)
    for n in range(terms):
        m = 2 * n + 1
        u -= 4.0 * F * W ** 2 / (NU * math.pi ** 3 * m ** 3) * np.sin(m * math.pi * y / W) * \
            math.exp(-(m ** 2) * math.pi ** 2 * NU * t / W ** 2)
    return u


def tolerance(res: int) -> float:
    """DBC's wall within dp beyond the face: 4 u_max dp / W, plus Ma^2 (relative to u_max)."""
    return 4.0 / res + MACH ** 2


def run_resolution(args, res: int) -> dict:
    dp = W / res
    sim = make_sim(args, "poiseuille", {"fluid.spacing": dp, "run.end_time": TIMES[-1]})
    rows = []
    for t in TIMES:
        sim.run(until=t)
        sim.check_health()
        pos, vel = particles(sim)
        layer = np.clip(np.floor(pos[:, 1] / dp).astype(int), 0, res - 1)
        count = np.bincount(layer, minlength=res)
        u = np.bincount(layer, weights=vel[:, 0], minlength=res) / np.maximum(count, 1)
        y = np.bincount(layer, weights=pos[:, 1], minlength=res) / np.maximum(count, 1)
        ref = series(y, t)
        err = np.abs(u - ref) / UMAX
        k = int(np.argmax(err))
        rows.append({"t": t, "err": float(err[k]), "y": float(y[k]), "peak": float(u.max()),
                     "peak_ref": float(ref.max()), "vy": float(np.abs(vel[:, 1]).max())})
    st = sim.state()
    return {"res": res, "n": int(sim.info["n_fluid"]), "rows": rows, "outside_max": int(st["outside_max"]),
            "steps": int(st["step"])}


def run(args) -> list[Check]:
    runs = [run_resolution(args, r) for r in (RES_FULL if args.full else RES_CI)]
    print(f"\nPoiseuille flow, W = {W:g} m, F = {F:g} m/s^2, nu = {NU:g} m^2/s: u_max = {UMAX:g} m/s, "
          f"Re = {UMAX * W / NU:g}, Mach {MACH:g}")
    print(f"  {'W/dp':>5} {'t (s)':>6} {'peak':>8} {'series':>8} {'max |u - u_ref| / u_max':>24} {'at y':>7}")
    checks: list[Check] = []
    for r in runs:
        tol = tolerance(r["res"])
        for row in r["rows"]:
            print(f"  {r['res']:5d} {row['t']:6.2f} {row['peak']:8.4f} {row['peak_ref']:8.4f} {row['err']:24.4f} "
                  f"{row['y']:7.3f}")
            what = "steady profile" if row["t"] == TIMES[-1] else "transient profile"
            checks.append(within(f"{what} at t = {row['t']:g} s, W/dp = {r['res']} (largest layer error / u_max)",
                                 row["err"], 0.0, tol, "", f"DBC wall within dp of the face (4 dp/W) + Ma^2 = {tol:.3g}"))
        steady = r["rows"][-1]
        checks.append(within(f"peak / u_max at t = {steady['t']:g} s, W/dp = {r['res']}", steady["peak"] / UMAX,
                             steady["peak_ref"] / UMAX, tol, "", "as the profile (the series' peak at that time)"))
        checks.append(within(f"largest |v| / u_max at steady state, W/dp = {r['res']}", steady["vy"] / UMAX, 0.0,
                             0.05, "", "a straight channel: v = 0; the lattice's noise at Ma = 0.1"))
        checks.append(Check(f"fluid outside the box (any step), W/dp = {r['res']}", float(r["outside_max"]), 0.0,
                            0.0, r["outside_max"] == 0, "particles"))
    if len(runs) > 1:
        order = observed_order([1.0 / r["res"] for r in runs], [r["rows"][-1]["err"] for r in runs])
        print(f"  observed order of the steady profile error: {order:.2f}")
        checks.append(Check("observed order of the steady profile error", order, 0.5, 0.0, bool(order >= 0.5), "",
                            "at least half order (the DBC wall's offset converges as dp)"))
    return checks
