"""``corpuscle polar SCENE --aoa START:STOP:STEP``: C_L and C_D of a wind-tunnel scene over
the angle of attack, to a CSV and a PNG beside the free-molecular theory (the sweep's
library part is :mod:`corpuscle.polar`)."""

from __future__ import annotations

import argparse
import csv
import pathlib
import sys
import time

from .. import polar as _polar
from ._options import Command, UsageError, float_option, import_core_module, int_option, load_with_options, register

HELP = "sweep the angle of attack of a wind-tunnel scene: CSV and PNG of C_L, C_D (with theory)"
DESCRIPTION = "`corpuscle polar SCENE --aoa START:STOP:STEP`: a sweep over the angle of attack."


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
    p.add_argument("--force", action="store_true", help="replace an existing output file of another kind than its name says")
    p.add_argument("--no-progress", action="store_true", help="no progress lines")


def run_command(args: argparse.Namespace) -> int:
    from .. import _mpi

    comm = _mpi.world()  # None without mpiexec: the whole sweep here
    if comm is None:
        return _sweep(args, None)
    # every rank checks the same input; a failure anywhere is reported once and stops all
    plan = _mpi.agree(comm, lambda: _plan(args))
    return _sweep(args, comm, plan)


def _plan(args: argparse.Namespace):
    angles = _polar.parse_aoa(args.aoa)
    args.particles = int_option("--particles", args.particles, minimum=1)
    end = float_option("--end-time", args.end_time)
    if end is not None and not end > 0:
        raise UsageError(f"--end-time must be positive, got {args.end_time!r}")
    scene = load_with_options(args, {})
    if scene.kind not in ("wind-tunnel", "wind-tunnel-3d"):  # 3-D: the coefficients per unit span, the same theory
        raise UsageError(f"polar: scene {scene.name!r} is of kind {scene.kind!r}; polar sweeps a wind-tunnel or "
                         f"wind-tunnel-3d scene")
    if end is not None:
        scene = scene.with_overrides({"run.end_time": end})
    prefix = pathlib.Path(args.out) if args.out else pathlib.Path(f"polar-{scene.name}")
    if not prefix.parent.is_dir():
        raise UsageError(f"--out {args.out}: folder {prefix.parent} does not exist")
    from .._viz_common import check_file_output

    for suffix in (".csv",) if args.no_plot else (".csv", ".png"):
        check_file_output(f"{prefix}{suffix}", UsageError)
    for a in angles:  # every scene is checked before the first run
        scene.with_overrides({"airfoil.angle_of_attack": a})
    simulation = import_core_module("corpuscle.simulation")
    Simulation = simulation.Simulation
    backend = args.backend
    if backend == "auto":
        backend = "cuda" if Simulation.cuda_available() else "cpu"
    return angles, scene, prefix, Simulation, backend


def _sweep(args: argparse.Namespace, comm, plan=None) -> int:
    """The sweep: with several ranks, angle i runs on rank i mod R (its own threads, its own
    device: the node-local rank's GPU) and rank 0 gathers the rows and writes the outputs."""
    angles, scene, prefix, Simulation, backend = plan if plan is not None else _plan(args)
    rank, size = (0, 1) if comm is None else (comm.Get_rank(), comm.Get_size())
    device = 0
    if comm is not None and backend == "cuda":  # the node-local rank picks its GPU (shared when fewer)
        from .. import _mpi

        local, _ = _mpi.node_local_rank(comm)
        gpus = import_core_module("corpuscle._core").build_info().get("gpus") or [None]
        device = local % len(gpus)
    th = _polar.theory_curves(scene, angles)
    rows = []
    for i, a in enumerate(angles):
        if i % size != rank:
            continue
        t0 = time.perf_counter()
        sc = scene.with_overrides({"airfoil.angle_of_attack": a})
        sim = Simulation.from_scene(sc, backend=backend, neighbors=args.neighbors, device=device)
        sim.run(until=float(sc.values["run.end_time"]), chunk=500)
        r = sim.result()
        row = {"angle_of_attack": a, "steps": int(sim.steps), "particles": int(sim.n_particles),
               "theory_cl": float(th["cl"][i]), "theory_cd": float(th["cd"][i])}
        for k in ("cl", "cl_se", "cd", "cd_se", "cm", "cm_se", "lift", "drag", "moment", "blocks"):
            row[k] = r.get(k, float("nan"))
        rows.append(row)
        row["_index"] = i
        if not args.no_progress:
            measured = (f"C_L, C_D: not measured ({r['not_measured']})" if r.get("not_measured") else
                        f"C_L {row['cl']:.4g} ± {row['cl_se']:.2g}, C_D {row['cd']:.4g} ± {row['cd_se']:.2g}")
            where = f" (rank {rank})" if size > 1 else ""
            print(f"alpha {a:7.3f} deg: {measured} ({row['steps']} steps, {time.perf_counter() - t0:.1f} s){where}",
                  file=sys.stderr, flush=True)
        del sim
    if comm is not None:
        parts = comm.gather(rows, root=0)
        if rank != 0:
            return 0
        rows = sorted((r for part in parts for r in part), key=lambda r: r["_index"])
    csv_path = prefix.with_name(prefix.name + ".csv")
    try:
        with open(csv_path, "w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=_polar.COLUMNS)
            w.writeheader()
            for row in rows:
                w.writerow({k: row[k] for k in _polar.COLUMNS})
    except OSError as exc:
        raise UsageError(f"cannot write {csv_path}: {exc.strerror or exc}") from None
    print(f"wrote {csv_path}")
    if not args.no_plot:
        png = prefix.with_name(prefix.name + ".png")
        _polar.plot_polar(rows, th, scene, png)
        print(f"wrote {png}")
    return 0


register(Command("polar", HELP, configure_parser, run_command, DESCRIPTION))
