"""``corpuscle validate dam-break``: the surge front of the dam break against Martin & Moyce
(1952) / Koshizuka & Oka (1996) (``corpuscle/data/dam_break_martin_moyce.csv``).

The column (width a, height 2a) collapses against the back wall; the front Z = x_front / a is
measured at every tabulated T = t sqrt(2 g / a) <= 3 and compared with the data. Tolerance:
0.3 in Z, the issue's figure; it is about twice the spread between published experimental sets
(0.1 - 0.2, noted in the data file), which is the measurement's own uncertainty (gate removal,
how the thin front tip was read), so a correct model can be expected inside it and a broken
one (a front at the wrong speed by ~10 %, a leaking or sticking wall) falls outside by T = 2.
A second check per run: the column is in balance at release (the fluid's mean vertical
acceleration at t = 0 is 0 within BALANCE_TOLERANCE g): a core applying another gravity than
the one the start and T assume fails it, though its front may stay within the data's scatter.

Default (CI): 2-D at a / dp = 20 (800 fluid particles), well under a minute on 2 cores.
``--full``: 2-D and 3-D at the scenes' default resolutions (a / dp = 40 and 20) and at twice
them (a / dp = 80 and 40), with a check for each dimension that the finer run is closer (by the
rms difference); the 3-D a / dp = 40 run (64,000 fluid particles) takes seconds on a GPU and
about half an hour on two CPU cores. ``--particles N`` sets the 2-D fluid particle count of the
default run instead (3-D: ``--dim 3``).
"""

from __future__ import annotations

import math
import pathlib
import sys

import numpy as np

from . import Check, within
from ._common import add_engine, positive_int

TOLERANCE = 0.3
T_MAX = 3.0
# The column at release is the start's hydrostatic lattice (its density from the scene's
# gravity, the gravity the time scale T uses): the fluid's mean vertical acceleration there is
# the walls' support less the gravity the core applies, 0 but for the discretisation of the
# wall's pressure force on the start lattice, measured -0.0125 g in 2-D at a/dp = 20 and 40
# alike (so not a resolution error: the kernel's moments on the lattice) and -0.0151 g in 3-D at a/dp = 10.
# The tolerance is four times that: a core applying a gravity 5 % off the one the start and
# the time scale assume (which moves the front by less than the data's scatter by T = 3, and
# so passes the front checks) fails here.
BALANCE_TOLERANCE = 0.05


def reference() -> np.ndarray:
    """(T, Z) rows of the shipped data."""
    path = pathlib.Path(__file__).resolve().parent.parent / "data" / "dam_break_martin_moyce.csv"
    rows = [line.split(",") for line in path.read_text().splitlines()
            if line and not line.startswith("#") and not line.startswith("T")]
    return np.array([[float(a), float(b)] for a, b in rows])


def add_arguments(parser) -> None:
    add_engine(parser)
    parser.add_argument("--particles", metavar="N", help="fluid particles of the run (2-D default: 800, a / dp = 20)")
    parser.add_argument("--dim", choices=("2", "3", "both"), default="2", help="2-D, 3-D or both (default: 2)")
    parser.add_argument("--full", action="store_true",
                        help="2-D at a/dp = 40 and 80 and 3-D at a/dp = 20 and 40 (the scenes' defaults and "
                        "twice as fine; the 3-D a/dp = 40 run is for a GPU: about half an hour on 2 CPU cores)")
    parser.add_argument("--plot", metavar="FILE.png", default="dam-break-front.png",
                        help="where the front plot goes (default: dam-break-front.png; 'none': no plot)")
    from .impact import add_reference_arguments

    add_reference_arguments(parser)  # --reference lobovsky|buchner: wall pressure (validation/impact.py)


def _run(dim: int, particles: int, args) -> dict:
    from ..kinds import get
    from ..scene import load_scene
    from ..simulation import Simulation

    name = "dam-break-2d" if dim == 2 else "dam-break"
    scene = load_scene(name).with_overrides({"fluid.particles": particles, "probes": []})
    sim = Simulation(scene, args.backend, neighbors=args.neighbors, device=args.device)
    kind = get(name)
    ts = sim.info["time_scale"]
    sim.evaluate()  # the start's accelerations: the balance at release
    g = float(sim.info["gravity"])
    balance = float(np.mean(np.asarray(sim.field("acceleration", copy=True), dtype=np.float64)[:, -1])) / g
    ref = reference()
    ref = ref[ref[:, 0] <= T_MAX + 1e-9]
    zs = []
    for T in ref[:, 0]:
        sim.run(until=float(T) / ts)
        sim.check_health()
        zs.append(kind.front_and_column(sim)[0])
    st = sim.state()
    return {"dim": dim, "particles": int(sim.info["n_fluid"]), "a_dp": sim.info["a"] / sim.info["spacing"],
            "T": ref[:, 0], "Z": np.array(zs), "Zref": ref[:, 1], "outside": int(st["outside_max"]),
            "balance": balance}


def run(args) -> list[Check]:
    if getattr(args, "reference", "martin-moyce") != "martin-moyce":
        from . import impact

        return impact.run(args)
    n = positive_int("--particles", args.particles)
    if args.plot and args.plot != "none":  # (before the runs: a bad path is not found after them)
        from .._viz_common import check_file_output

        check_file_output(args.plot, ValueError)
    plan: list[tuple[int, int]] = []
    if args.full:
        plan = [(2, 3200), (2, 12800), (3, 8000), (3, 64000)]
    else:
        dims = (2, 3) if args.dim == "both" else (int(args.dim),)
        for d in dims:
            plan.append((d, n or (800 if d == 2 else 1000)))
    runs = []
    for d, p in plan:
        if len(plan) > 1:  # (stderr: --json keeps stdout for the checks)
            print(f"validate dam-break: {d}-D, {p} fluid particles ({len(runs) + 1} of {len(plan)})",
                  file=sys.stderr, flush=True)
        runs.append(_run(d, p, args))
    checks: list[Check] = []
    for r in runs:
        tag = f"{r['dim']}-D a/dp={r['a_dp']:.0f}"
        print(f"\n{tag} ({r['particles']} fluid particles): surge front Z = x/a")
        print(f"  {'T':>5} {'Z':>7} {'Z ref':>7} {'diff':>7}")
        for T, z, zr in zip(r["T"], r["Z"], r["Zref"]):
            print(f"  {T:5.2f} {z:7.3f} {zr:7.3f} {z - zr:+7.3f}")
            checks.append(within(f"front {tag} T={T:.2f}", z, zr, TOLERANCE, "a"))
        r["rms"] = float(np.sqrt(np.mean((r["Z"] - r["Zref"]) ** 2)))
        print(f"  rms difference {r['rms']:.3f}")
        checks.append(within(f"balance at release {tag}: mean a_vertical / g", r["balance"], 0.0,
                             BALANCE_TOLERANCE, "g", "the hydrostatic column before it collapses: walls' support "
                             "- applied gravity, against the scene's g (dam_break.BALANCE_TOLERANCE)"))
        checks.append(Check(f"fluid outside the tank {tag}", float(r["outside"]), 0.0, 0.0, r["outside"] == 0,
                            "particles"))
    # the issue's "closer at a finer resolution": each finer run of a dimension against the coarser
    # one before it, by the rms difference over the tabulated T (a FAIL says it is not: the
    # converged model's front leads the data, docs/benchmarks.md)
    for coarse, fine in zip(runs, runs[1:]):
        if coarse["dim"] == fine["dim"] and fine["a_dp"] > coarse["a_dp"]:
            checks.append(Check(f"finer closer {fine['dim']}-D rms a/dp={coarse['a_dp']:.0f} -> {fine['a_dp']:.0f}",
                                fine["rms"], coarse["rms"], 0.0, fine["rms"] < coarse["rms"], "a"))
    if args.plot and args.plot != "none":
        _plot(runs, args.plot)
    return checks


def _plot(runs, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ref = reference()
    fig, ax = plt.subplots(figsize=(6, 4.2))
    ax.plot(ref[:, 0], ref[:, 1], "ko", label="Martin & Moyce / Koshizuka & Oka")
    ax.fill_between(ref[:, 0], ref[:, 1] - TOLERANCE, ref[:, 1] + TOLERANCE, color="0.9", label=f"±{TOLERANCE}")
    for r in runs:
        ax.plot(r["T"], r["Z"], "-s", ms=3, label=f"corpuscle {r['dim']}-D, a/dp = {r['a_dp']:.0f}")
    ax.set_xlabel("T = t sqrt(2g/a)")
    ax.set_ylabel("Z = x_front / a")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=120)
    except OSError as exc:
        raise ValueError(f"--plot {path}: {exc.strerror or exc}") from None
    finally:
        plt.close(fig)
    print(f"\nplot: {path}")
