"""``corpuscle bench``: steps per second on each backend (sweeps over particle counts,
indexes and batch sizes; per-stage times; JSON and a plot)."""

from __future__ import annotations

import argparse
import math
import pathlib
import statistics
import sys
import time
from typing import Any

from .. import _json
from ._common import build_info, command_line, device_name, interruptible_init, now_iso, relistings
from ._options import (BACKENDS, EXIT_OK, Command, UsageError, float_option, fmt_rate, import_core_module, int_option,
                       load_with_options, one_line, particles_help, progress_enabled, register)


def _configure_bench(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", metavar="SCENE|FILE.toml", help="a built-in scene name or a scene file")
    p.add_argument("--backend", nargs="+", choices=BACKENDS, metavar="B",
                   help="backends to time: serial, cpu, cuda (default: every usable one)")
    p.add_argument("--particles", metavar="N", nargs="+",
                   help=particles_help() + "; several values (or a comma-separated list): a sweep over them")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[], help="override any scene key (repeatable)")
    p.add_argument("--neighbors", metavar="INDEX", nargs="+",
                   help="neighbour search(es) to time (the kind's indexes, see `corpuscle info`; several: a sweep)")
    p.add_argument("--device", metavar="N", default="0", help="CUDA device number (default: 0)")
    p.add_argument("--stages", action="store_true",
                   help="per-stage times on the CPU backends too (CUDA always reports them, timed with events)")
    p.add_argument("--steps", metavar="S", default="100", help="steps per timed repeat (default: 100)")
    p.add_argument("--repeats", metavar="R", default="5", help="timed repeats; the median is reported (default: 5)")
    p.add_argument("--warmup", metavar="W", default="20", help="untimed warm-up steps (default: 20)")
    p.add_argument("--start-time", metavar="SECONDS", default="0",
                   help="run each scene to this simulated time before the warm-up, untimed (default: 0, the "
                        "scene's start): times the flow there, e.g. a dam break's surge, where a lists index "
                        "relists every few steps rather than at the still start")
    p.add_argument("--batch", nargs="+", metavar="B",
                   help="time batches of B independent scenes stepped together (magic8ball; several values: a sweep); "
                        "reports scene-steps/s and particle-steps/s")
    p.add_argument("--path", choices=("auto", "general", "chip"),
                   help="magic8ball on cuda: step on chip (a thread block per scene, the scene in shared memory, many "
                        "steps a launch) or the general path; auto (the default): general (chip measured slower). "
                        "The row's `path` says which ran")
    p.add_argument("--json", metavar="FILE", help="also write the results as a JSON list of rows to FILE")
    p.add_argument("--force", action="store_true", help="replace an existing output file of another kind than its name says")
    p.add_argument("--plot", metavar="FILE.png",
                   help="also plot particle-steps/s against particles, a line for each backend and index (PNG)")
    p.add_argument("--max-step", metavar="SECONDS",
                   help="in a sweep over --particles, leave out a backend and index's larger sizes once a step "
                        "there would take longer than this (from its last size: O(N), all pairs O(N^2))")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _cmd_bench(args: argparse.Namespace) -> int:
    from .. import __version__

    # options and scene first; the core only after
    steps = int_option("--steps", args.steps, minimum=1)
    repeats = int_option("--repeats", args.repeats, minimum=1)
    warmup = int_option("--warmup", args.warmup, minimum=0)
    start_time = float_option("--start-time", args.start_time)
    if start_time < 0.0:
        raise UsageError(f"--start-time must be a simulated time of 0 s or more, got {args.start_time!r}")
    args.device = int_option("--device", args.device, minimum=0)
    sizes = [None]
    if args.particles:
        sizes = [int_option("--particles", t, minimum=1) for v in args.particles for t in str(v).split(",")]
    indexes = [None]
    if args.neighbors:
        names = [t.strip() for v in args.neighbors for t in str(v).split(",")]
        if any(not t for t in names):
            raise UsageError(f"--neighbors {' '.join(args.neighbors)!r}: an empty index name")
        indexes = list(dict.fromkeys(names))
    scenes = []
    for size in sizes:
        args.particles = size
        scenes.append(load_with_options(args, {}))
    scene = scenes[0]
    if args.path is not None:
        if scene.kind != "magic8ball":
            raise UsageError(f"--path {args.path}: the step's paths are magic8ball's, got kind {scene.kind!r}")
        if args.path == "chip" and args.backend and any(b != "cuda" for b in args.backend):
            raise UsageError(f"--path chip runs on the cuda backend, got --backend {' '.join(args.backend)}")
        scenes = [sc.with_overrides({"sph.path": args.path}) for sc in scenes]
        scene = scenes[0]
    batches = [int_option("--batch", b, minimum=1) for b in args.batch] if args.batch else [None]
    if args.batch and scene.kind != "magic8ball":
        raise UsageError(f"--batch: batches of scenes are magic8ball scenes, got kind {scene.kind!r}")
    if args.batch and start_time > 0.0:
        raise UsageError(f"--start-time {args.start_time}: not with --batch (each scene of a batch keeps its own clock)")
    end = float(scene["run.end_time"])
    if start_time > 0.0 and start_time >= end:
        raise UsageError(f"--start-time {args.start_time}: not before {scene.name}'s end time run.end_time = {end:g} s "
                         f"(raise it with --set run.end_time=T to time the flow later)")
    max_step = float_option("--max-step", args.max_step)
    if max_step is not None and not max_step > 0.0:
        raise UsageError(f"--max-step must be a positive number of seconds, got {args.max_step!r}")
    if args.plot is not None:
        from .._viz_common import check_file_output

        check_file_output(args.plot, UsageError)
    if args.json is not None:
        # checked before the benchmark runs, not after it has taken minutes
        if not args.json.strip():
            raise UsageError(f"--json must name a file, got {args.json!r}")
        parent = pathlib.Path(args.json).parent
        if not parent.is_dir():
            raise UsageError(f"--json {args.json}: folder {parent} does not exist")
        if pathlib.Path(args.json).is_dir():
            raise UsageError(f"--json {args.json}: is a folder")
        from .._viz_common import check_file_output

        check_file_output(args.json, UsageError)
    simulation = import_core_module("corpuscle.simulation")
    Simulation = simulation.Simulation
    backends = list(dict.fromkeys(args.backend)) if args.backend else [
        b for b in BACKENDS if b != "cuda" or Simulation.cuda_available()
    ]
    if args.path == "chip" and backends != ["cuda"]:
        raise UsageError("--path chip runs on the cuda backend" + ("" if "cuda" in backends else
                                                                   ", and this machine has no CUDA device") +
                         ": add --backend cuda")
    info = build_info()
    date = now_iso()

    # progress over backends x repeats (stderr, terminals only)
    bar = None
    if progress_enabled(argparse.Namespace(no_progress=args.no_progress)):
        from tqdm import tqdm

        bar = tqdm(total=len(backends) * repeats * len(scenes) * len(indexes) * len(batches), unit="repeat",
                   file=sys.stderr, leave=False)
    rows: list[dict[str, Any]] = []
    runs = [(sz, sc, idx, b, B) for sz, sc in zip(sizes, scenes) for idx in indexes for b in backends for B in batches]
    last: dict[tuple, tuple[int, float]] = {}  # (index, backend, batch) -> (size, seconds a step) of its last row
    left_out: list[str] = []
    try:
        for size, scene, index, backend, batch in runs:
            config = (index, backend, batch)
            if max_step is not None and size is not None and config in last:
                n0, t0 = last[config]
                power = 2 if index == "allpairs" else 1
                guess = t0 * (size / n0) ** power if size > n0 else t0
                if guess > max_step:
                    left_out.append(f"{backend} {index or ''} at {size:,} (a step ~{guess:.3g} s > --max-step {max_step:g})")
                    if bar is not None:
                        bar.update(repeats)
                    continue
            if bar is not None:
                bar.set_description(backend if batch is None else f"{backend} B={batch}")
            t_init = time.perf_counter()
            with interruptible_init(f"initialising {backend}"):
                if batch is None:
                    sim = Simulation.from_scene(scene, backend=backend, neighbors=index, device=args.device)
                else:
                    from ..batch import Batch

                    # no settling: the timing does not depend on it
                    sim = Batch.from_scene(scene, n=batch, backend=backend, neighbors=index, device=args.device,
                                           settle=0.0)
            if args.path == "chip" and _path_of(sim) != "chip":
                raise UsageError(f"--path chip: the {backend} run steps the general path")
            init_seconds = time.perf_counter() - t_init
            if start_time > 0.0:
                if bar is not None:
                    bar.set_description(f"{backend}: running to t = {start_time:g} s")
                _bench_advance(sim, start_time, backend)
                if bar is not None:
                    bar.set_description(backend)
            if warmup:
                sim.step(warmup)
            relists = relistings(sim)
            t_sim0 = float(sim.time) if batch is None else None
            times = []
            for _ in range(repeats):
                times.append(float(sim.bench_steps(steps)))
                if bar is not None:
                    bar.update(1)
            if relists is not None:
                relists = relistings(sim) - relists
            median = statistics.median(times)
            if size is not None:
                last[config] = (size, median / steps)
            n = int(sim.n_particles)
            sps = steps / median if median > 0 else float("inf")
            row: dict[str, Any] = {
                "scene": scene.name,
                "backend": backend,
                "batch": batch if batch is not None else 1,
                "scene_steps_per_second": sps * (batch if batch is not None else 1),
                "particles": n,
                "steps": steps,
                "repeats": repeats,
                "warmup": warmup,
                "start_time": start_time,
                "init_seconds": init_seconds,
                "steps_per_second": sps,
                "particle_steps_per_second": sps * n,
                "seconds": times,
                "neighbors": getattr(sim, "neighbors", None),
                "path": _path_of(sim),
                "device": device_name(backend, info, args.device),
                "date": date,
                "version": __version__,
                "command": command_line(args),
            }
            state = sim.state() if batch is None and hasattr(sim, "state") else {}
            if "mean_neighbors" in state:
                row["mean_neighbors"] = float(state["mean_neighbors"])
            if "rebuilds" in state and getattr(sim, "neighbors", None) == "lists":
                # the relistings of the lists index over every step taken (warm-up included),
                # and over the timed steps alone
                row["rebuilds"] = int(state["rebuilds"])
                row["steps_taken"] = int(state["step"])
                row["timed_rebuilds"] = relists
            if batch is None:
                # time to solution: the timed steps' wall seconds per simulated second, and the
                # particles' kinds and memory (corpuscle/_solution.py)
                from .. import _solution

                row["wall_seconds_per_sim_second"] = _solution.wall_per_sim_second(
                    sum(times), float(sim.time) - t_sim0)
                row.update(_solution.particle_counts(sim))
                row.update(_solution.memory_per_particle(sim))
            if (backend == "cuda" or args.stages) and batch is None:
                row["stages"] = {str(k): float(v) for k, v in dict(sim.stage_times(steps)).items()}
            rows.append(row)
            del sim
    finally:
        if bar is not None:
            bar.close()

    # the file first: a closed stdout (| head) must not lose the measurements
    if args.json:
        try:
            with open(args.json, "w", encoding="utf-8") as f:
                _json.dump(rows, f, indent=2)
                f.write("\n")
        except OSError as exc:
            raise UsageError(f"cannot write {args.json}: {exc.strerror or one_line(exc)}") from None
    _print_bench(rows)
    from .. import _bench_report

    if len({r["particles"] for r in rows}) > 1 and (tables := _bench_report.speedup_tables(rows)):
        print()
        print("\n".join(tables))
    for note in left_out:
        print(f"left out: {note}")
    if args.plot:
        try:
            _bench_report.plot(rows, args.plot, title=f"corpuscle {scene.name}")
        except OSError as exc:
            raise UsageError(f"cannot write {args.plot}: {exc.strerror or one_line(exc)}") from None
        print(f"plot: {args.plot}")
    return EXIT_OK


def _path_of(sim) -> str | None:
    """How a magic8ball run steps (chip or general; None for other kinds)."""
    if hasattr(sim, "path"):
        return sim.path
    scalars = getattr(sim, "scalars", None)
    values = dict(scalars()) if callable(scalars) else {}
    return None if "chip_path" not in values else ("chip" if values["chip_path"] else "general")


def _bench_advance(sim, until: float, backend: str) -> None:
    """`bench --start-time`: the scene run to simulated time `until` (untimed); an unsound run
    stops the benchmark with the step it went bad at."""
    sim.run(until=until, chunk=500)
    bad = sim.check_health()
    if bad:
        raise UsageError(f"--start-time {until:g}: the {backend} run went {bad}")
    if sim.time < until:
        raise UsageError(f"--start-time {until:g}: the {backend} run stopped at t = {sim.time:g} s")
    sim.set_end_time(math.inf)  # (run() ended the clock at `until`: the warm-up steps would be no-ops)


def _print_bench(rows: list[dict[str, Any]]) -> None:
    """The benchmark table, then the per-stage table of each backend that has one."""
    def base(r, backend):
        return next((q for q in rows if q["backend"] == backend and q["particles"] == r["particles"]
                     and q.get("neighbors") == r.get("neighbors") and q.get("batch", 1) == r.get("batch", 1)), None)

    batched = any(r.get("batch", 1) != 1 for r in rows)
    serial = None if batched else next((r for r in rows if r["backend"] == "serial"), None)
    sweep = len({(r["particles"], r.get("neighbors")) for r in rows}) > 1
    nbr = any("mean_neighbors" in r for r in rows)
    paths = any(r.get("path") == "chip" for r in rows)  # (the JSON rows always say)
    head = f"{'backend':<8} " + (f"{'path':<8}" if paths else "") + (f"{'batch':>7} " if batched else "") + f"{'particles':>10} {'init(s)':>8} {'steps/s':>12} "
    head += (f"{'scene-steps/s':>14} " if batched else "") + f"{'particle-steps/s':>18}"
    tts = any(r.get("wall_seconds_per_sim_second") is not None for r in rows)
    if tts:
        head += f" {'wall s/sim s':>12}"
    if sweep or nbr:
        head = f"{'index':<9}" + head + f" {'neighbours':>10}"
    print(head + (f" {'speedup':>9}" if serial else ""))
    for r in rows:
        if sweep or nbr:
            serial = None if batched else base(r, "serial")  # a batch's rows have no speedup column
            print(f"{str(r.get('neighbors')):<9}", end="")
        init = r.get("init_seconds")
        init_text = f"{init:8.3f}" if isinstance(init, (int, float)) else f"{'':>8}"
        line = (f"{r['backend']:<8} " + (f"{str(r.get('path') or '-'):<8}" if paths else "") +
                (f"{r.get('batch', 1):>7,} " if batched else "") +
                f"{r['particles']:>10,} {init_text} {fmt_rate(r['steps_per_second']):>12} " +
                (f"{fmt_rate(r['scene_steps_per_second']):>14} " if batched else "") +
                f"{fmt_rate(r['particle_steps_per_second']):>18}")
        if tts:
            w = r.get("wall_seconds_per_sim_second")
            line += f" {w:12.4g}" if isinstance(w, (int, float)) else f" {'':>12}"
        if sweep or nbr:
            mn = r.get("mean_neighbors")
            line += f" {mn:10.1f}" if isinstance(mn, (int, float)) else f" {'':>10}"
        if serial:
            line += f" {r['steps_per_second'] / serial['steps_per_second']:>8.1f}x"
        elif sweep or nbr:
            line += f" {'':>9}"
        print(line)
    for r in rows:
        stages = r.get("stages")
        if not stages:
            continue
        total = sum(stages.values())
        what = f"{r['backend']}, {r['particles']:,} particles" + (f", {r['neighbors']}" if r.get("neighbors") else "")
        if r.get("start_time"):
            what += f", from t = {r['start_time']:g} s"
        if r.get("timed_rebuilds") is not None:
            what += f", relisting {100.0 * r['timed_rebuilds'] / (r['steps'] * r['repeats']):.0f}% of the timed steps"
        print(f"\n{what} stages (ms per step, {r['device']})")
        width = max(len(k) for k in stages)
        for name, ms in stages.items():
            share = 100.0 * ms / total if total > 0 else 0.0
            print(f"  {name:<{width}}  {ms:9.4f}  {share:5.1f}%")
        print(f"  {'total':<{width}}  {total:9.4f}")
    for r in rows:
        if r.get("fluid_particles") is None:
            continue
        what = f"{r['backend']}" + (f", {r['neighbors']}" if r.get("neighbors") else "")
        line = f"{what}: {r['fluid_particles']:,} fluid + {r['wall_particles']:,} wall particles"
        if r.get("bytes_per_particle") is not None:
            line += f", {r['bytes_per_particle']:,.0f} bytes a particle"
            if r.get("largest_particles"):
                line += f" (the device holds about {r['largest_particles']:,})"
        print(line)


register(Command("bench", "time steps per second on each backend", _configure_bench, _cmd_bench))
