"""``corpuscle run``: run a scene (or resume a recorded run) and record it to a frame stream,
with a progress bar, ``--render`` and ``--live``; a summary (or ``--json``) at the end."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import math
import platform
import signal
import sys
import threading
import time
from typing import Any

from .. import _json
from .. import kinds as _kinds
from .._errors import DISK_FULL_ERRNOS as _DISK_FULL, EXIT_WRITE  # a full disk or a file size limit: exit 4
from .._frame_sink import FrameSink
from ._common import (STOP_SIGNALS, command_line, interrupt_exit_code, interruptible_init, now_iso, relistings,
                      signal_name)
from ._options import (BACKENDS, EXIT_OK, EXIT_STOPPED, PROG, Command, UsageError,
                       add_engine_options, add_live_arguments, err, fmt_rate, import_core_module, live_url_message,
                       one_line, particles_help, progress_enabled, register)
from ._run_plan import RunPlan, checkpoint_state, prepare, same_file


def _configure_run(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", metavar="SCENE|FILE.toml", nargs="?",
                   help="a built-in scene name (see `corpuscle scenes`) or a scene file (not with --resume)")
    p.add_argument("--backend", choices=("auto", *BACKENDS), default="auto", help="compute backend (default: auto)")
    add_engine_options(p)
    p.add_argument("--steps", metavar="N",
                   help="run exactly N steps (past run.end_time unless --time is also given; then whichever "
                        "comes first)")
    p.add_argument("--time", metavar="T", help="simulated end time in seconds (sets run.end_time)")
    p.add_argument("--particles", metavar="N", help=particles_help())
    p.add_argument("--seed", metavar="S", help="random seed (sets run.seed)")
    p.add_argument(
        "--set", metavar="KEY=VALUE", action="append", default=[],
        help="override any scene key, value in TOML syntax (repeatable), e.g. --set fluid.stiffness=2e4",
    )
    p.add_argument("--out", metavar="FILE.cps", help="output frame stream (default: <scene name>.cps here; "
                                                     "with --resume: the resumed file itself)")
    p.add_argument("--force", action="store_true",
                   help="replace --out even when it is not a corpuscle frame stream (a .cps)")
    p.add_argument("--every", metavar="K", help="record a frame every K steps (sets run.record_every)")
    p.add_argument("--checkpoint-every", metavar="K",
                   help="make every recorded frame at a multiple of K steps a checkpoint (the full state to "
                        "resume from; K a multiple of the record interval), and the last frame too")
    p.add_argument("--resume", metavar="RUN.cps",
                   help="continue the run recorded in RUN.cps from its last checkpoint (appending to it, or "
                        "writing --out); --time or --steps set a new end, else the original one stands")
    p.add_argument("--ghosts", action="store_true", help="also record the wall ghost particles")
    p.add_argument("--velocity", action="store_true", help="also record particle velocities")
    p.add_argument("--json", action="store_true", help="print only one JSON summary object on stdout")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    from .. import render  # light: heavy imaging libraries load only when rendering

    render.add_live_render_arguments(p)
    add_live_arguments(p, "--live: ")
    p.add_argument("--no-token", action="store_true",
                   help="--live: steer the run without the token in the URL (on 127.0.0.1 only; any web page "
                        "this machine opens can then reach it)")
    p.add_argument("--live", action="store_true",
                   help="also serve a live view of the run at http://127.0.0.1:PORT/ (WebGL2 page; shake the "
                        "8-ball from the keyboard, pause, resume); needs pip install \".[viewer]\"")


class _Progress:
    """A tqdm bar on stderr (steps when a step budget is set, else simulated seconds)."""

    def __init__(self, enabled: bool, budget: int | None, end_time: float) -> None:
        self.bar = None
        self.budget = budget if budget is not None or not math.isfinite(end_time) else None
        if not enabled or (self.budget is None and not math.isfinite(end_time)):
            return
        from tqdm import tqdm  # lazily: only runs with a terminal need it

        if self.budget is not None:
            self.bar = tqdm(total=self.budget, unit="step", file=sys.stderr, dynamic_ncols=True, leave=False)
        else:
            self.bar = tqdm(
                total=end_time, unit="s", file=sys.stderr, dynamic_ncols=True, leave=False,
                bar_format="{l_bar}{bar}| {n:.3f}/{total:.3f} s simulated [{elapsed}<{remaining}{postfix}]",
            )

    def update(self, steps_done: int, sim_time: float, wall: float) -> None:
        if self.bar is None:
            return
        if self.budget is not None:
            self.bar.update(steps_done - self.bar.n)
        else:
            self.bar.update(min(sim_time, self.bar.total) - self.bar.n)
            rate = steps_done / wall if wall > 0 else 0.0
            self.bar.set_postfix_str(f"{rate:,.0f} steps/s", refresh=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _run_header(plan: RunPlan, sim, backend: str, args: argparse.Namespace) -> dict[str, Any]:
    """The frame-stream header: the simulation's own description (scene name, container,
    bodies, h, ...) plus what was run, how and by which build, and where it ends."""
    from .. import __version__

    scene = plan.scene
    header = dict(sim.header()) if hasattr(sim, "header") else {}
    header.update({
        "program": PROG,
        "version": __version__,
        "command": command_line(args),
        "created": now_iso(),
        "scene": scene.name,
        "parameters": scene.to_dict(),
        "scene_path": str(scene.path) if scene.path else None,
        "backend": getattr(sim, "backend", backend),
        "particles": int(sim.n_particles),
        "ghosts_recorded": bool(args.ghosts),
        "velocity_recorded": bool(args.velocity),
        "record_every": plan.every,
        "checkpoint_every": plan.checkpoint_every,
        "end_time": plan.end_time if math.isfinite(plan.end_time) else None,
        "end_step": plan.end_step,
        "host": platform.node(),
    })
    return header


def _live_render(args: argparse.Namespace, header: dict[str, Any]):
    """The `--render OUT` sink, or None."""
    if not getattr(args, "render", None):
        return None
    from .. import render
    return render.LiveRender.from_args(args, header)


@contextlib.contextmanager
def _interrupts_deferred():
    """Ctrl-C (SIGTERM, SIGHUP) while a frame is queued takes effect once it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    hits: list[int] = []
    previous = {}
    for signum in STOP_SIGNALS:
        handler = signal.getsignal(signum)
        if handler in (signal.SIG_IGN, signal.SIG_DFL, None):
            continue  # ignored (nohup) or not ours: left alone
        previous[signum] = signal.signal(signum, lambda signum, _frame: hits.append(signum))
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        if hits:
            if hits[0] == signal.SIGINT:
                raise KeyboardInterrupt
            handler = previous.get(hits[0])
            if callable(handler):
                handler(hits[0], None)  # raises as the signal would have
            raise KeyboardInterrupt


def _checkpoint_record(sim, rec: dict) -> None:
    """Add the full state (Simulation.checkpoint) to a frame's fields: the checkpointed
    particle fields (the 8-ball's positions, velocities and ids) in their groups, and every
    scalar as a one-element array of the group ``state``."""
    import numpy as np

    state = sim.checkpoint()
    fields, groups = rec["fields"], rec["groups"]
    for name, group in sim.checkpoint_fields.items():
        fields[name] = np.asarray(state.pop(name))
        groups[name] = group
    float64 = set(sim.checkpoint_float64)
    for name, value in state.items():
        arr = np.asarray(value)
        if arr.dtype.kind == "f" and name not in float64:
            arr = arr.astype(np.float32)  # the core's float32 values, exactly
        elif arr.dtype.kind in "iu":
            arr = arr.astype(np.int64)
        fields[f"state.{name}"] = arr.reshape(1, *arr.shape)
        groups[f"state.{name}"] = "state"


def _record(sink, sim, args: argparse.Namespace, live, kind: str = "frame") -> None:
    """Queue one frame for writing (a checkpoint carries the full state too), and render it
    when `--render` asked for that."""
    rec = sim.frame(ghosts=args.ghosts or bool(getattr(args, "render_ghosts", False)), velocity=args.velocity)
    if kind == "checkpoint":
        _checkpoint_record(sim, rec)
    with _interrupts_deferred():
        sink.put(sim.steps, sim.time, sim.dt, rec, kind)
    if live is not None:
        from types import SimpleNamespace
        live.add_frame(SimpleNamespace(**rec, time=sim.time, step=sim.steps))
    viewer = getattr(args, "_viewer", None)  # --live: the page gets the latest frame (never waited for)
    if viewer is not None:
        try:
            viewer.publish(sim, rec)
        except Exception as exc:  # noqa: BLE001 - the viewer never stops a run
            err(f"live: frame not published: {one_line(exc)}")


def _start_viewer(args: argparse.Namespace, sim, header: dict[str, Any]):
    """`run --live`: the viewer's server, started (its URL printed on stderr), or None."""
    args._viewer = None
    if not getattr(args, "live", False):
        return None
    live = importlib.import_module("corpuscle.live")
    try:
        viewer = live.RunViewer.start(sim, header, host=args.host, port=args.port,
                                      require_token=not getattr(args, "no_token", False))
    except live.ServerError as exc:
        raise UsageError(f"--live: {one_line(exc)}") from None
    err(live_url_message(viewer.server, "live view"))
    args._viewer = viewer
    return viewer


def _open_writer(io, plan: RunPlan, header: dict[str, Any], args: argparse.Namespace):
    """A new frame stream, or (resuming in place) the recorded one cut back to its checkpoint."""
    out = plan.out
    try:
        if plan.resume is not None and same_file(out, plan.resume["path"]):
            return io.FrameWriter.append(out, keep=plan.resume["frame"] + 1)
        if plan.resume is not None:
            header = dict(plan.resume["header"], resumed_from=str(plan.resume["path"]),
                          resumed_at_step=plan.resume["step"], command=header["command"])
        force = {"force": True} if getattr(args, "force", False) else {}  # a file that is not a .cps
        return io.FrameWriter(out, header, **force)
    except OSError as exc:
        error = UsageError(f"cannot write {out}: {exc.strerror or one_line(exc)}")
        if exc.errno in _DISK_FULL:
            error.exit_code = EXIT_WRITE  # the disk, not the input: as when it fills up mid-run
        raise error from None




class _NullSink:
    """The frame sink of a rank other than 0 (rank 0 writes the one frame stream)."""

    written = 0
    last_step = None

    def put(self, *args) -> None:
        pass

    def close(self) -> None:
        pass


def _prepare_ranks(args: argparse.Namespace, comm) -> RunPlan:
    """`run` under mpiexec: the plan, and one line when the scene cannot be split over the ranks."""
    from .._ranks_sph import check_splittable

    plan = prepare(args)
    if getattr(args, "live", False) or getattr(args, "render", None):
        raise UsageError(f"--live and --render run on one rank, not {comm.Get_size()}")
    check_splittable(plan.scene, comm.Get_size(), args.neighbors)
    return plan


def _cmd_run(args: argparse.Namespace) -> int:
    from .. import _mpi

    comm = _mpi.world()  # None without mpiexec: the whole scene here
    rank = 0 if comm is None else comm.Get_rank()
    # validate everything cheap first; the core is imported only after this (under mpiexec every
    # rank checks the same input; a failure anywhere is reported once and stops all)
    plan = prepare(args) if comm is None else _mpi.agree(comm, lambda: _prepare_ranks(args, comm))
    scene, out, every = plan.scene, plan.out, plan.every
    simulation = import_core_module("corpuscle.simulation")
    io = importlib.import_module("corpuscle.io")
    if rank != 0:
        args.json, args.no_progress = True, True  # (rank 0 reports)

    # initialisation (timed on its own, not part of steps/s)
    t_init = time.perf_counter()
    with interruptible_init("initialising (nothing written)"):
        state = None if plan.resume is None else checkpoint_state(plan.resume["state"])
        if comm is not None:
            from .._ranks_sph import ranked_simulation

            sim = ranked_simulation(scene, args.backend, comm, checkpoint=state, neighbors=args.neighbors,
                                    device=args.device or None)
            plan.scene = scene = sim.scene  # (with sph.order_by_id on, as the ranks run it)
        elif plan.resume is None:
            sim = simulation.Simulation.from_scene(scene, backend=args.backend, neighbors=args.neighbors,
                                                   device=args.device)
        else:
            sim = simulation.Simulation(scene, backend=args.backend, checkpoint=state,
                                        neighbors=args.neighbors, device=args.device)
    sim.set_end_time(plan.end_time)  # the core shortens the last step to land on it
    start_steps = int(sim.steps)
    start_sim_time = float(sim.time)
    start_relists = relistings(sim)
    init_seconds = time.perf_counter() - t_init
    backend = str(getattr(sim, "backend", args.backend))
    header = _run_header(plan, sim, backend, args)
    viewer = _start_viewer(args, sim, header)
    try:
        live = _live_render(args, header)
        writer = _open_writer(io, plan, header, args) if rank == 0 else contextlib.nullcontext()
    except BaseException:
        if viewer is not None:
            viewer.close()
        raise

    frames = 0
    last_recorded = start_steps
    stopped: str | None = None
    interrupted: KeyboardInterrupt | None = None
    write_error: str | None = None
    budget = None if plan.end_step is None else plan.end_step - start_steps
    progress = _Progress(progress_enabled(args), budget, plan.end_time)
    ckpt = plan.checkpoint_every

    def kind_at(step: int, final: bool) -> str:
        if ckpt is None:
            return "frame"
        return "checkpoint" if final or step % ckpt == 0 else "frame"

    # the frame writer's thread shares the interpreter with this loop: a short switch
    # interval hands the loop the interpreter back soon after a chunk of steps returns (the
    # default 5 ms would leave the device idle that long behind a frame being encoded)
    switch = sys.getswitchinterval()
    sys.setswitchinterval(min(switch, 0.0005))
    t0 = time.perf_counter()
    try:
        with writer:
            sink = FrameSink(writer) if rank == 0 else _NullSink()  # written while the next chunk steps
            try:
                if plan.resume is None:
                    _record(sink, sim, args, live, kind_at(start_steps, False))
                # advance to each multiple of K steps, record, check health
                while True:
                    if viewer is not None:
                        viewer.between_chunks(sim)  # the page's control; waits while it paused the run
                    now = int(sim.steps)
                    left = None if plan.end_step is None else plan.end_step - now
                    if (left is not None and left <= 0) or sim.time >= plan.end_time:
                        break
                    k = (now // every + 1) * every - now
                    if left is not None:
                        k = min(k, left)
                    if viewer is not None:
                        k = viewer.chunk(k)  # short chunks: the page's control is taken within a frame
                    taken = int(sim.step(k))
                    progress.update(int(sim.steps) - start_steps, float(sim.time), time.perf_counter() - t0)
                    message = sim.check_health()
                    if message:
                        stopped = one_line(message)
                        if taken > 0:
                            _record(sink, sim, args, live)  # the state where it stopped
                        break
                    if taken == 0:
                        break  # nothing left to do (the end time was reached)
                    now = int(sim.steps)
                    final = ((plan.end_step is not None and now >= plan.end_step) or sim.time >= plan.end_time)
                    if viewer is not None and not final and now % every != 0:
                        viewer.stepped(sim)  # between recorded frames: the page may get one
                        continue
                    _record(sink, sim, args, live, kind_at(now, final))
                    last_recorded = now
                    if viewer is not None:
                        viewer.stepped(sim, recorded=True)
            except KeyboardInterrupt as exc:
                if comm is not None:
                    raise  # every rank stops (MPI_Abort): no frame that needs the others
                interrupted = exc
                if int(sim.steps) > last_recorded:
                    try:
                        _record(sink, sim, args, live)  # the whole step it stopped after
                    except (KeyboardInterrupt, OSError):
                        pass
            except BaseException:
                # a failure (the disk, the core): the live render is dropped, not published
                if live is not None:
                    live.abort()
                    live = None
                raise
            finally:
                try:
                    sink.close()  # the queued frames are written (a write error is raised here)
                finally:
                    wall = time.perf_counter() - t0
                    frames = sink.written
                    last_recorded = sink.last_step if sink.last_step is not None else start_steps
                    progress.close()
                    if live is not None:
                        live.close()
                    if viewer is not None:
                        viewer.close()
                        args._viewer = None
    except OSError as exc:
        # the writer cut the file back to its last whole frame
        write_error = f"cannot write {out}: {exc.strerror or one_line(exc)}"
    finally:
        sys.setswitchinterval(switch)
    # the writer is closed here, so every recorded frame is readable

    steps = int(sim.steps) - start_steps
    if interrupted is not None:
        by = signal_name(interrupted)
        err(f"run interrupted at step {sim.steps}; {frames} frames kept in {out}" + (f" ({by})" if by else ""))
        return interrupt_exit_code(interrupted)
    result = None if stopped or write_error else dict(sim.result() or {})
    n = int(sim.n_particles)
    ghosts = getattr(sim, "n_ghosts", None)
    sps = steps / wall if wall > 0 else float("inf")
    summary = {
        "scene": scene.name,
        "backend": backend,
        "particles": n,
        "ghosts": None if ghosts is None else int(ghosts),
        "steps": steps,
        "sim_time": float(sim.time),
        "init_time": init_seconds,
        "wall_time": wall,
        "steps_per_second": sps,
        "particle_steps_per_second": sps * n,
        "frames": frames,
        "out": str(out),
        "result": result,
        "stopped": stopped or write_error,
    }
    if plan.resume is not None:
        summary["resumed_at_step"] = plan.resume["step"]
    if start_relists is not None:
        summary["relistings"] = relistings(sim) - start_relists
    # time to solution and the particles' kinds and memory (corpuscle/_solution.py)
    from .. import _solution

    summary["wall_seconds_per_sim_second"] = _solution.wall_per_sim_second(wall, float(sim.time) - start_sim_time)
    summary.update(_solution.particle_counts(sim))
    summary.update(_solution.memory_per_particle(sim))
    if comm is not None:
        bal = sim.core.balance()  # (every rank: a collective)
        summary["ranks"] = bal["ranks"]
        summary["imbalance"] = bal["imbalance"]
        summary["decomposition"] = {k: bal[k] for k in ("axis", "owned", "halo", "migrations", "rebalances", "cuts")}
        if rank != 0:
            return EXIT_STOPPED if stopped else (EXIT_WRITE if write_error else EXIT_OK)
    else:
        summary["ranks"] = 1
    if args.json:
        print(_json.dumps(summary))
    else:
        print_summary(summary, scene)
    if write_error:
        err(f"error: {write_error}; {frames} frames kept up to step {last_recorded}")
        return EXIT_WRITE
    if stopped:
        err(f"run stopped at step {sim.steps}: {stopped}")
        return EXIT_STOPPED
    return EXIT_OK


def print_summary(s: dict[str, Any], scene) -> None:
    """The human-readable run summary."""
    where = f" ({scene.path})" if scene.path and not scene.builtin else ""
    rows = [
        ("scene", f"{s['scene']}{where}"),
        ("backend", s["backend"]),
        ("particles", f"{s['particles']:,}"),
    ]
    if s["ghosts"] is not None:
        rows.append(("ghosts", f"{s['ghosts']:,}"))
    if s.get("resumed_at_step") is not None:
        rows.append(("resumed at step", f"{s['resumed_at_step']:,}"))
    if s.get("ranks", 1) > 1:
        d = s["decomposition"]
        rows.append(("ranks", f"{s['ranks']} (slabs along {d['axis']}; owned {', '.join(map(str, d['owned']))}; "
                              f"imbalance {s['imbalance']:.2f}, {d['rebalances']} rebalances)"))
    rows += [
        ("steps", f"{s['steps']:,}"),
        ("simulated time", f"{s['sim_time']:.4g} s"),
        ("initialisation", f"{s['init_time']:.3f} s"),
        ("wall time", f"{s['wall_time']:.3f} s"),
        ("steps/s", fmt_rate(s["steps_per_second"])),
        ("particle-steps/s", fmt_rate(s["particle_steps_per_second"])),
    ]
    if s.get("wall_seconds_per_sim_second") is not None:
        rows.append(("wall s per simulated s", f"{s['wall_seconds_per_sim_second']:.4g}"))
    if s.get("fluid_particles") is not None:
        rows.append(("fluid / wall particles", f"{s['fluid_particles']:,} / {s['wall_particles']:,}"))
    if s.get("bytes_per_particle") is not None:
        most = s.get("largest_particles")
        rows.append(("memory", f"{s['bytes_per_particle']:,.0f} bytes a particle ({_kinds.fmt_bytes(s['bytes_needed'])})" +
                     (f"; the device holds about {most:,} particles so" if most else "")))
    if s.get("relistings") is not None:
        share = f" ({100.0 * s['relistings'] / s['steps']:.0f}% of the steps)" if s["steps"] else ""
        rows.append(("relistings", f"{s['relistings']:,}{share}"))
    rows += [
        ("output", f"{s['out']} ({s['frames']} frames)"),
    ]
    width = max(len(k) for k, _ in rows)
    for key, value in rows:
        print(f"{key:<{width}}  {value}")
    result = s["result"] or {}
    # the kind's lines for its result (the 8-ball's answer), then anything else it reports
    kind = _kinds.find(scene.kind)
    lines, rest = kind.summary(result) if kind is not None else ([], dict(result))
    for line in lines:
        print(line)
    for key, value in rest.items():
        print(f"{key:<{width}}  {value}")


register(Command("run", "run a scene and record it to a frame stream", _configure_run, _cmd_run))
