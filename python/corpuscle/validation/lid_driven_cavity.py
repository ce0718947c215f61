"""``corpuscle validate lid-driven-cavity``: the 2-D lid-driven cavity against Ghia, Ghia &
Shin 1982 (J. Comput. Phys. 48, 387-411, Tables I and II; shipped in corpuscle/data/).

A closed square of side L = 1 m whose top wall (DBC particles, `walls.moving = ["top"]`)
slides along x at U = 1 m/s, nu = U L / Re (laminar viscosity), c0 = 10 U, no gravity. At
the end the velocity is sampled by the engine's probes (Shepard-normalised kernel
interpolation over the fluid) at Ghia's points: u along the vertical centre line x = L/2, v
along the horizontal one y = L/2 (the end points, on the walls, left out), and compared.

Re = 100 (default: L/dp = 30 to t = 10 L/U); ``--full`` adds L/dp = 60 at Re = 100 and
Re = 1000 at L/dp = 100 to t = 40 L/U (a GPU run). Checks the rms and the largest error of
each centre line (relative to U).

Tolerance (written beside each check): DBC's no-slip condition lies between the wall's face
and up to one spacing beyond it (see ``validate poiseuille``, where it is measured), so the
flow is that of a cavity up to dp larger on each side; the velocity along a centre line is
then off by up to |du/ds| dp at each point, and the bound on the rms error is
rms(|du/ds|) dp + Ma^2 U, rms(|du/ds|) taken from Ghia's own table (finite differences).
The largest error is at the points next to the lid, where the probe's kernel interpolation
is one-sided (Shepard-normalised over the fluid: the lid's particles are not in it), so its
centroid lies up to hs / 2 from the point; its bound is max(|du/ds|) (dp + hs / 2) + Ma^2 U
(hs = 1.5 dp, the scene's).
"""

from __future__ import annotations

import math
from importlib import resources

import numpy as np

from . import Check, within
from ._canonical import make_sim, particles

L, U = 1.0, 1.0
MACH = 0.1
CASES_CI = ((100, 30, 10.0),)  # (Re, L / dp, t_end in L / U)
CASES_FULL = ((100, 30, 10.0), (100, 60, 15.0), (1000, 100, 40.0))


def add_arguments(parser) -> None:
    from ._common import add_engine

    add_engine(parser)
    parser.add_argument("--full", action="store_true", help="also L/dp = 60 at Re = 100, and Re = 1000 at L/dp = 100 "
                        "(a GPU run)")


def ghia(name: str, re: int) -> tuple[np.ndarray, np.ndarray]:
    """(coordinate, velocity / U) of a Ghia centre line (u_vertical or v_horizontal), sorted."""
    path = resources.files("corpuscle") / "data" / f"ghia1982_{name}_centerline.csv"
    with path.open() as f:
        rows = [ln.strip() for ln in f if ln.strip() and not ln.startswith("#")]
    head = rows[0].split(",")
    data = np.array([[float(x) for x in r.split(",")] for r in rows[1:]])
    col = head.index(f"Re{re}")
    order = np.argsort(data[:, 0])
    return data[order, 0], data[order, col]


def gradient_bound(s: np.ndarray, u: np.ndarray, dp: float, hs: float) -> tuple[float, float]:
    """The bounds on the rms and the largest error: rms|du/ds| dp + Ma^2 and max|du/ds| (dp +
    hs / 2) + Ma^2, |du/ds| by central differences on Ghia's table."""
    g = np.abs(np.gradient(u, s))
    return float(np.sqrt(np.mean(g ** 2)) * dp + MACH ** 2), float(g.max() * (dp + 0.5 * hs) + MACH ** 2)


def run_case(args, re: int, res: int, t_end: float) -> dict:
    yu, uref = ghia("u_vertical", re)
    xv, vref = ghia("v_horizontal", re)
    keep_u = (yu > 0.0) & (yu < L)
    keep_v = (xv > 0.0) & (xv < L)
    yu, uref, xv, vref = yu[keep_u], uref[keep_u], xv[keep_v], vref[keep_v]
    probes = [{"name": f"u{k}", "position": [0.5 * L, float(y)]} for k, y in enumerate(yu)]
    probes += [{"name": f"v{k}", "position": [float(x), 0.5 * L]} for k, x in enumerate(xv)]
    sim = make_sim(args, "lid-driven-cavity", {"fluid.spacing": L / res, "sph.nu": U * L / re,
                                               "run.end_time": t_end * L / U, "probes": probes})
    sim.run(until=t_end * L / U)
    sim.check_health()
    pr = sim.state()["probes"]
    u = np.array([pr[f"u{k}"]["velocity"][0] for k in range(len(yu))]) / U
    v = np.array([pr[f"v{k}"]["velocity"][1] for k in range(len(xv))]) / U
    pos, vel = particles(sim)
    st = sim.state()
    dp = L / res
    return {"re": re, "res": res, "t": t_end, "n": int(sim.info["n_fluid"]), "steps": int(st["step"]),
            "yu": yu, "u": u, "uref": uref, "xv": xv, "v": v, "vref": vref,
            "bound_u": gradient_bound(yu, uref, dp, sim.info["hs"]), "bound_v": gradient_bound(xv, vref, dp, sim.info["hs"]),
            "outside_max": int(st["outside_max"])}


def run(args) -> list[Check]:
    cases = CASES_FULL if args.full else CASES_CI
    checks: list[Check] = []
    for re, res, t_end in cases:
        r = run_case(args, re, res, t_end)
        print(f"\nlid-driven cavity, Re = {re}, L/dp = {res} ({r['n']} fluid particles), t = {t_end:g} L/U "
              f"({r['steps']} steps), Mach {MACH:g}")
        print(f"  {'y':>7} {'u/U':>8} {'Ghia':>8}   {'x':>7} {'v/U':>8} {'Ghia':>8}")
        for k in range(max(len(r["yu"]), len(r["xv"]))):
            a = f"{r['yu'][k]:7.4f} {r['u'][k]:8.4f} {r['uref'][k]:8.4f}" if k < len(r["yu"]) else " " * 25
            b = f"{r['xv'][k]:7.4f} {r['v'][k]:8.4f} {r['vref'][k]:8.4f}" if k < len(r["xv"]) else ""
            print(f"  {a}   {b}")
        for line, m, ref, bound in (("u on x = L/2", r["u"], r["uref"], r["bound_u"]),
                                    ("v on y = L/2", r["v"], r["vref"], r["bound_v"])):
            err = m - ref
            rms = float(np.sqrt(np.mean(err ** 2)))
            big = float(np.abs(err).max())
            checks.append(within(f"Re {re}, L/dp {res}: rms error of {line} (/ U) against Ghia et al.", rms, 0.0,
                                 bound[0], "", f"rms|du/ds| dp + Ma^2 = {bound[0]:.3g}"))
            checks.append(within(f"Re {re}, L/dp {res}: largest error of {line} (/ U)", big, 0.0, bound[1], "",
                                 f"max|du/ds| (dp + hs/2) + Ma^2 = {bound[1]:.3g}"))
        checks.append(Check(f"Re {re}, L/dp {res}: fluid outside the box (any step)", float(r["outside_max"]), 0.0,
                            0.0, r["outside_max"] == 0, "particles"))
    return checks
