"""`corpuscle polar SCENE --aoa START:STOP:STEP`: a sweep over the angle of attack.

Each angle is one run of the scene (a wind-tunnel scene: every key of it, ``--set`` and
``--particles`` apply) to its end time; the steady-part means of C_L, C_D, C_M with their
standard errors (the kind's block means) go into a CSV, and a PNG shows C_L and C_D against
the angle with error bars, beside the free-molecular flat-plate theory for the scene's
airfoil restitution and free stream (corpuscle.free_molecular: the Newtonian
2 (1 + e) sin^2 alpha for the cold beam, the Maxwellian closed form at the scene's speed
ratio). The theory is the collisionless limit: with particle-particle contacts on (the
default scene) the measured points depart from it, which is what the polar shows.
"""

from __future__ import annotations

import argparse
import csv
import math
import pathlib
import sys
import time

import numpy as np

HELP = "sweep the angle of attack of a wind-tunnel scene: CSV and PNG of C_L, C_D (with theory)"
DESCRIPTION = __doc__.strip().splitlines()[0]

COLUMNS = ("angle_of_attack", "cl", "cl_se", "cd", "cd_se", "cm", "cm_se", "lift", "drag", "moment", "blocks",
           "steps", "particles", "theory_cl", "theory_cd")


def parse_aoa(text: str) -> list[float]:
    """START:STOP:STEP (STOP included when the steps reach it) or a comma-separated list."""
    t = (text or "").strip()
    try:
        if ":" in t:
            parts = [float(p) for p in t.split(":")]
            if len(parts) != 3:
                raise ValueError
            a, b, s = parts
            if not all(math.isfinite(x) for x in parts) or s == 0 or (b - a) / s < 0:
                raise ValueError
            n = int(math.floor((b - a) / s + 1e-9)) + 1
            if n > 1000:
                raise ValueError
            vals = [round(a + k * s, 10) for k in range(n)]
        else:
            vals = [float(p) for p in t.split(",") if p.strip()]
    except ValueError:
        raise ValueError(f"--aoa {text!r}: give START:STOP:STEP (e.g. -10:20:2) or a comma-separated list") from None
    if not vals or any(not (math.isfinite(v) and -90.0 <= v <= 90.0) for v in vals):
        raise ValueError(f"--aoa {text!r}: angles must be finite and within [-90, 90] degrees")
    return vals


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", metavar="SCENE|FILE.toml", help="a wind-tunnel or wind-tunnel-3d scene (built-in name or file)")
    p.add_argument("--aoa", required=True, metavar="START:STOP:STEP",
                   help="angles of attack in degrees, e.g. -10:20:2 (inclusive) or 0,5,10")
    p.add_argument("--backend", choices=("auto", "serial", "cpu", "cuda"), default="auto", help="backend")
    p.add_argument("--particles", metavar="N", help="number of particles (gas.particles)")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[], help="override a scene key")
    p.add_argument("--end-time", metavar="T", help="run.end_time of every run (s)")
    p.add_argument("--neighbors", metavar="INDEX", help="neighbour search (the kind's index: grid)")
    p.add_argument("--out", metavar="PREFIX", help="write PREFIX.csv and PREFIX.png (default: polar-SCENE)")
    p.add_argument("--no-plot", action="store_true", help="the CSV only")
    p.add_argument("--no-progress", action="store_true", help="no progress lines")


def theory_curves(scene, angles) -> dict[str, np.ndarray]:
    """The thin flat plate's free-molecular C_L, C_D for the scene's wing restitution and stream."""
    from . import free_molecular as fm
    from .kinds import wind_tunnel as wt

    v = scene.values
    m = float(v["gas.mass"])
    k, c, e = float(v["wing.k"]), float(v["wing.c"]), float(v["wing.restitution"])
    if not e > 0:
        e = wt.restitution(k, c, m)
    ratio = wt.thermal_ratio(v)
    S = math.inf if ratio == 0 else 1.0 / ratio
    th = fm.thin_plate(np.asarray(angles, dtype=np.float64), S, e)
    return {"cl": th["cl"], "cd": th["cd"], "restitution": e, "speed_ratio": S}


def run_command(args: argparse.Namespace) -> int:
    from .cli import UsageError, _float_option, _int_option, _load_with_options, _import_core_module

    angles = parse_aoa(args.aoa)
    args.particles = _int_option("--particles", args.particles, minimum=1)
    end = _float_option("--end-time", args.end_time)
    if end is not None and not end > 0:
        raise UsageError(f"--end-time must be positive, got {args.end_time!r}")
    scene = _load_with_options(args, {})
    if scene.kind not in ("wind-tunnel", "wind-tunnel-3d"):  # 3-D: the coefficients per unit span, the same theory
        raise UsageError(f"polar: scene {scene.name!r} is of kind {scene.kind!r}; polar sweeps a wind-tunnel or "
                         f"wind-tunnel-3d scene")
    if end is not None:
        scene = scene.with_overrides({"run.end_time": end})
    prefix = pathlib.Path(args.out) if args.out else pathlib.Path(f"polar-{scene.name}")
    if not prefix.parent.is_dir():
        raise UsageError(f"--out {args.out}: folder {prefix.parent} does not exist")
    for a in angles:  # every scene is checked before the first run
        scene.with_overrides({"airfoil.angle_of_attack": a})
    simulation = _import_core_module("corpuscle.simulation")
    Simulation = simulation.Simulation
    backend = args.backend
    if backend == "auto":
        backend = "cuda" if Simulation.cuda_available() else "cpu"
    th = theory_curves(scene, angles)
    rows = []
    for i, a in enumerate(angles):
        t0 = time.perf_counter()
        sc = scene.with_overrides({"airfoil.angle_of_attack": a})
        sim = Simulation.from_scene(sc, backend=backend, neighbors=args.neighbors)
        sim.run(until=float(sc.values["run.end_time"]), chunk=500)
        r = sim.result()
        row = {"angle_of_attack": a, "steps": int(sim.steps), "particles": int(sim.n_particles),
               "theory_cl": float(th["cl"][i]), "theory_cd": float(th["cd"][i])}
        for k in ("cl", "cl_se", "cd", "cd_se", "cm", "cm_se", "lift", "drag", "moment", "blocks"):
            row[k] = r.get(k, float("nan"))
        rows.append(row)
        if not args.no_progress:
            print(f"alpha {a:7.3f} deg: C_L {row['cl']:.4g} ± {row['cl_se']:.2g}, C_D {row['cd']:.4g} ± "
                  f"{row['cd_se']:.2g} ({row['steps']} steps, {time.perf_counter() - t0:.1f} s)", file=sys.stderr)
        del sim
    csv_path = prefix.with_name(prefix.name + ".csv")
    try:
        with open(csv_path, "w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=COLUMNS)
            w.writeheader()
            for row in rows:
                w.writerow({k: row[k] for k in COLUMNS})
    except OSError as exc:
        raise UsageError(f"cannot write {csv_path}: {exc.strerror or exc}") from None
    print(f"wrote {csv_path}")
    if not args.no_plot:
        png = prefix.with_name(prefix.name + ".png")
        plot_polar(rows, th, scene, png)
        print(f"wrote {png}")
    return 0


def plot_polar(rows, th, scene, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = np.array([r["angle_of_attack"] for r in rows])
    fine = np.linspace(a.min(), a.max(), 200) if len(a) > 1 else a
    thf = theory_curves(scene, fine)
    S = th["speed_ratio"]
    label = (f"free-molecular flat plate (e = {th['restitution']:.2f}, "
             + ("cold beam" if not math.isfinite(S) else f"S = {S:g}") + ")")
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for ax, k, name in ((axes[0], "cl", "C_L"), (axes[1], "cd", "C_D")):
        y = np.array([r[k] for r in rows], dtype=np.float64)
        e = np.array([r[k + "_se"] for r in rows], dtype=np.float64)
        ax.errorbar(a, y, yerr=np.where(np.isfinite(e), e, 0.0), fmt="o", ms=4, capsize=2, label="measured")
        ax.plot(fine, thf[k], "-", lw=1.2, label=label)
        ax.set_xlabel("angle of attack (deg)")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"{scene.name}: {scene.values['airfoil.shape']}, {rows[0]['particles']:,} particles")
    fig.savefig(path, dpi=120)
    plt.close(fig)
