"""The ``corpuscle`` command line.

Subcommands live in one table, :data:`COMMANDS`; a new one (render, plot, export,
validate) is a :class:`Command` added with :func:`register`. Bad input (scene errors,
bad options, unusable backends, unwritable files) ends with exit code 2 and one line
``corpuscle: error: ...`` on stderr, never a traceback. Scenes are loaded and validated
before the compiled core is imported, so those errors need no build.

Exit codes: 0 success, 2 bad input, 3 run stopped by a health check, 4 the output could not
be written (disk full ...; the frames written so far are kept), 130 interrupted, 141 stdout
closed (broken pipe).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import importlib
import importlib.util
import json
import math
import os
import pathlib
import platform
import re
import shlex
import signal
import statistics
import sys
import threading
import time
import warnings
from dataclasses import dataclass
from typing import Any, Callable, Sequence

from . import kinds as _kinds
from ._errors import DISK_FULL_ERRNOS as _DISK_FULL, EXIT_WRITE  # a full disk or a file size limit: exit 4
from ._frame_sink import FrameSink
from .scene import SceneError, builtin_scenes, load_scene, parse_set

PROG = "corpuscle"
BACKENDS = ("serial", "cpu", "cuda")
EXIT_OK, EXIT_USAGE, EXIT_STOPPED, EXIT_INTERRUPTED = 0, 2, 3, 130


class UsageError(ValueError):
    """Bad command-line input found after argparse (one-line message)."""


@dataclass
class Command:
    """One subcommand: its name, one-line help, argument setup and handler.

    ``configure(parser)`` adds the arguments; ``handler(args)`` returns the exit code.
    """

    name: str
    help: str
    configure: Callable[[argparse.ArgumentParser], None]
    handler: Callable[[argparse.Namespace], int]
    description: str | None = None


# every subcommand, in the order --help lists them
COMMANDS: dict[str, Command] = {}


def register(command: Command) -> Command:
    """Add a subcommand to the table (later registrations replace earlier ones)."""
    COMMANDS[command.name] = command
    return command


# ---------------------------------------------------------------------------
# small helpers
# ---------------------------------------------------------------------------


def _one_line(text: object) -> str:
    """Collapse a message onto one line."""
    return " ".join(str(text).split()) or "unknown error"


def _err(message: str) -> None:
    print(f"{PROG}: {message}", file=sys.stderr)


def _int_option(name: str, text: str | None, minimum: int | None = None) -> int | None:
    """Parse an integer option ourselves so a bad one gives a one-line error."""
    if text is None:
        return None
    try:
        value = int(text.strip())
    except ValueError:
        raise UsageError(f"{name} must be an integer, got {text!r}") from None
    if minimum is not None and value < minimum:
        what = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"
        raise UsageError(f"{name} must be {what}, got {value}")
    return value


def _float_option(name: str, text: str | None) -> float | None:
    if text is None:
        return None
    try:
        value = float(text.strip())
    except ValueError:
        raise UsageError(f"{name} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise UsageError(f"{name} must be a finite number, got {text!r}")
    return value


def _overrides(args: argparse.Namespace, options: dict[str, str]) -> dict[str, object]:
    """Scene overrides from ``--set`` (applied first) and dedicated options (which win)."""
    out: dict[str, object] = {}
    for expr in getattr(args, "set", None) or []:
        key, value = parse_set(expr)
        out[key] = value
    for attr, key in options.items():
        value = getattr(args, attr, None)
        if value is not None:
            out[key] = value
    return out


def _load_with_options(args: argparse.Namespace, options: dict[str, str]):
    """The scene with ``--set`` and the dedicated options applied; ``--particles`` sets the
    kind's particle key (an error for a kind without one)."""
    ovr = _overrides(args, options)  # --set is parsed before the scene is read
    scene = load_scene(args.scene)
    if getattr(args, "particles", None) is not None:
        kind = _kinds.find(scene.kind)
        key = kind.particle_key if kind is not None else None
        if key is None:
            raise UsageError(f"--particles: scene kind {scene.kind!r} has no particle count (use --set)")
        ovr[key] = args.particles
    try:
        return scene.with_overrides(ovr)
    except SceneError as exc:
        raise _named_by_option(exc, args, options) from None


def _named_by_option(exc: SceneError, args: argparse.Namespace, options: dict[str, str]) -> SceneError:
    """A scene error about a key that a dedicated option set (``--time`` sets
    ``run.end_time``) says which option it was: the user never typed the key."""
    given = {key: f"--{attr}" for attr, key in options.items() if getattr(args, attr, None) is not None}
    for key, option in given.items():
        if str(exc).startswith(f"{key} "):
            value = getattr(args, option[2:])
            return SceneError(f"{option} {value:g}: {exc}" if isinstance(value, float) else f"{option} {value}: {exc}")
    return exc


def _particles_help() -> str:
    keys = ", ".join(f"{k.particle_key} for {name}" for name, k in _kinds.registry().items() if k.particle_key)
    return f"number of particles (sets the scene kind's particle key: {keys or 'none'})"


def _safe_filename(name: str) -> str:
    """A scene name made safe to use as a file name."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "run"


def _import_core_module(module: str):
    """Import a module that needs the compiled core, as a one-line error if missing."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise UsageError(
            f"the compiled core is not available ({_one_line(exc)}); build it with `pip install .`"
        ) from None


def _progress_enabled(args: argparse.Namespace) -> bool:
    """A progress bar only on a terminal, and never with --no-progress or --json."""
    if getattr(args, "no_progress", False) or getattr(args, "json", None):
        return False
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def _fmt_rate(x: float) -> str:
    """Rates: plain below a million, scientific above."""
    if not math.isfinite(x):
        return "inf"
    return f"{x:,.1f}" if x < 1e6 else f"{x:.3e}"


def _now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()


def _command_line(args: argparse.Namespace) -> str:
    return shlex.join([PROG, *getattr(args, "_argv", [])])


def _build_info() -> dict[str, Any] | None:
    """``_core.build_info()``, or None when the core is not built."""
    try:
        core = importlib.import_module("corpuscle._core")
    except ImportError:
        return None
    return dict(core.build_info())


def _cpu_name() -> str:
    """The CPU model, from /proc/cpuinfo where there is one."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def _device_name(backend: str, info: dict[str, Any] | None, device: int = 0) -> str:
    """A human-readable device for benchmark records."""
    if backend == "cuda" and info and info.get("gpus"):
        gpus = info["gpus"]
        gpu = gpus[device] if 0 <= device < len(gpus) else gpus[0]
        return f"{gpu.get('name', 'GPU')} (compute {gpu.get('compute_capability', '?')})"
    cpu = f"{_cpu_name()}, {os.cpu_count() or '?'} logical cores"
    if backend == "cpu" and info:
        return f"{cpu}, {info.get('omp_threads', '?')} OpenMP threads"
    return cpu


# ---------------------------------------------------------------------------
# corpuscle scenes
# ---------------------------------------------------------------------------


def _configure_scenes(p: argparse.ArgumentParser) -> None:
    p.add_argument("--keys", action="store_true", help="also list every key of each scene kind (type, default, unit, range)")


def _core_kinds() -> dict[str, list[str]]:
    """The core's kinds and their index plug-ins ({} when the core is not built)."""
    try:
        core = importlib.import_module("corpuscle._core")
    except ImportError:
        return {}
    return {str(k): list(v) for k, v in dict(core.kinds()).items()}


def _cmd_scenes(args: argparse.Namespace) -> int:
    # built-in scenes, one a line
    scenes = builtin_scenes()
    width = max((len(n) for n, _ in scenes), default=4)
    for name, description in scenes:
        print(f"{name:<{width}}  {description}")
    if not args.keys:
        return EXIT_OK
    # the schema of every kind, for --set
    for kind_name, registered in _kinds.registry().items():
        kind = registered.schema
        keys = kind.keys
        print(f"\nkind {kind_name}: {kind.description}")
        indexes = _core_kinds().get(kind_name)
        if indexes:
            print(f"  --neighbors: {', '.join(indexes)} (default {indexes[0]})")
        kw = max(len(k) for k in keys)
        for key, spec in keys.items():
            default = json.dumps(spec.default, ensure_ascii=False)
            rng = spec.interval()
            unit = spec.unit
            print(f"  {key:<{kw}}  {spec.type:<9} {default:<22} {unit:<7} {rng:<20} {spec.doc}")
        for array, specs in kind.arrays.items():
            print(f"  [[{array}]] (repeatable; `--set {array}=[{{...}}, ...]` replaces them all)")
            for key, spec in specs.items():
                default = json.dumps(spec.default, ensure_ascii=False)
                print(f"    {key:<{kw - 2}}  {spec.type:<9} {default:<22} {spec.unit:<7} {spec.interval():<20} {spec.doc}")
    return EXIT_OK


register(Command("scenes", "list the built-in scenes", _configure_scenes, _cmd_scenes))


# ---------------------------------------------------------------------------
# corpuscle info
# ---------------------------------------------------------------------------


def _configure_info(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")


def _cmd_info(args: argparse.Namespace) -> int:
    from . import __version__, _omp

    # the compiled core may be missing on a source checkout
    try:
        core = importlib.import_module("corpuscle._core")
    except ImportError as exc:
        _err(f"error: the compiled core is not available ({_one_line(exc)}); build it with `pip install .`")
        return EXIT_USAGE
    info = dict(core.build_info())
    if args.json:
        print(json.dumps({"version": __version__, "build_info": info, "openmp_policy": _omp.policy()}, default=str))
        return EXIT_OK
    # text report
    print(f"corpuscle {__version__}")
    print(f"  core version       {info.get('version')}")
    if info.get("cuda_compiled"):
        print(f"  CUDA               compiled (architectures: {info.get('cuda_architectures') or '?'})")
    else:
        print("  CUDA               not compiled (CPU-only build)")
    omp = f"yes, {_omp.describe(info.get('omp_threads'))}" if info.get("openmp") else "no"
    print(f"  OpenMP             {omp}")
    gpus = info.get("gpus") or []
    for i, gpu in enumerate(gpus):
        mem = gpu.get("memory_gib")
        mem_text = f", {mem:.1f} GiB" if isinstance(mem, (int, float)) else ""
        print(f"  GPU {i}              {gpu.get('name')} (compute {gpu.get('compute_capability')}{mem_text})")
    if info.get("gpu_error"):
        print(f"  GPU                none usable: {_one_line(info['gpu_error'])}")
    elif not gpus:
        print("  GPU                none")
    return EXIT_OK


register(Command("info", "show the version, build options and usable GPUs", _configure_info, _cmd_info))


# ---------------------------------------------------------------------------
# corpuscle run
# ---------------------------------------------------------------------------

# dedicated options -> the run keys every kind has (--particles sets the kind's particle key)
RUN_OPTIONS = {"seed": "run.seed", "time": "run.end_time", "every": "run.record_every"}


def _add_engine_options(p: argparse.ArgumentParser) -> None:
    """--neighbors and --device: how the engine runs a scene (not part of the scene)."""
    p.add_argument("--neighbors", metavar="INDEX",
                   help="neighbour search: lists (cells on rebuilds, lists with a skin reused in between; the "
                        "8-ball's default), grid (the cells every step; the SPH box's default), compact (the SPH "
                        "box's cells in chunks of <= 32 through shared memory) or allpairs (every pair: O(N^2), a "
                        "reference); `corpuscle scenes --keys` lists each kind's")
    p.add_argument("--device", metavar="N", default="0", help="CUDA device number (default: 0)")


def _configure_run(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", metavar="SCENE|FILE.toml", nargs="?",
                   help="a built-in scene name (see `corpuscle scenes`) or a scene file (not with --resume)")
    p.add_argument("--backend", choices=("auto", *BACKENDS), default="auto", help="compute backend (default: auto)")
    _add_engine_options(p)
    p.add_argument("--steps", metavar="N",
                   help="run exactly N steps (past run.end_time unless --time is also given; then whichever "
                        "comes first)")
    p.add_argument("--time", metavar="T", help="simulated end time in seconds (sets run.end_time)")
    p.add_argument("--particles", metavar="N", help=_particles_help())
    p.add_argument("--seed", metavar="S", help="random seed (sets run.seed)")
    p.add_argument(
        "--set", metavar="KEY=VALUE", action="append", default=[],
        help="override any scene key, value in TOML syntax (repeatable), e.g. --set fluid.stiffness=2e4",
    )
    p.add_argument("--out", metavar="FILE.cps", help="output frame stream (default: <scene name>.cps here; "
                                                     "with --resume: the resumed file itself)")
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
    from . import render  # light: heavy imaging libraries load only when rendering

    render.add_live_render_arguments(p)
    _add_live_arguments(p, "--live: ")
    p.add_argument("--live", action="store_true",
                   help="also serve a live view of the run at http://127.0.0.1:PORT/ (WebGL2 page; shake the "
                        "8-ball from the keyboard, pause, resume); needs pip install \".[viewer]\"")


def _add_live_arguments(p: argparse.ArgumentParser, what: str = "") -> None:
    p.add_argument("--port", metavar="P", help=f"{what}the viewer's port (default: 8765; 0 picks a free one)")
    p.add_argument("--host", metavar="H",
                   help=f"{what}the address to listen on (default: 127.0.0.1, this machine only; any other "
                        "needs the random token printed with the URL)")


def _live_options(args: argparse.Namespace, needs_live: bool) -> None:
    """Check --port and --host (and that the viewer's server library is installed)."""
    if needs_live and not getattr(args, "live", False):
        for option in ("port", "host"):
            if getattr(args, option, None) is not None:
                raise UsageError(f"--{option} is an option of the live view; add --live")
        return
    port = _int_option("--port", args.port if args.port is not None else "8765", minimum=0)
    if port > 65535:
        raise UsageError(f"--port must be at most 65535, got {port}")
    args.port = port
    host = "127.0.0.1" if args.host is None else args.host.strip()
    if not host or any(c.isspace() or c in "/?#@" for c in host):
        raise UsageError(f"--host {args.host!r}: not a host name or address")
    import socket

    try:
        socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError, OSError) as exc:
        raise UsageError(f"--host {host}: not an address to listen on ({_one_line(exc)})") from None
    args.host = host
    if importlib.util.find_spec("aiohttp") is None:
        raise UsageError('the live viewer needs aiohttp: pip install "corpuscle[viewer]" (or ".[viewer]" '
                         'from a checkout)')


def _live_url_message(server, what: str) -> str:
    text = f"{what} at {server.url} (Ctrl-C stops)"
    if server.token:
        text += "; the token in the URL is required: this address may be reachable from other machines"
    return text


@dataclass
class _RunPlan:
    """What `run` will do, settled before the core is imported."""

    scene: Any
    out: pathlib.Path
    every: int
    end_time: float          # absolute simulated end time (inf: none)
    end_step: int | None     # absolute step to stop at (None: none)
    checkpoint_every: int | None
    resume: dict[str, Any] | None = None  # path, header, checkpoint frame index, state


def _same_file(a: pathlib.Path, b: pathlib.Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
        return a.resolve() == b.resolve()
    except OSError:
        return False


def _out_path(text: str | None, default: pathlib.Path) -> pathlib.Path:
    """``--out`` as given (an empty one is an error, not the default), or the default."""
    if text is None:
        return default
    if not text.strip():
        raise UsageError(f"--out must name a file, got {text!r}")
    return pathlib.Path(text)


def _check_out(out: pathlib.Path, scene) -> None:
    """The output folder must exist, and the output must not be a folder or the scene file."""
    parent = out.parent if str(out.parent) else pathlib.Path(".")
    if not parent.is_dir():
        raise UsageError(f"--out {out}: folder {parent} does not exist")
    if out.is_dir():
        raise UsageError(f"--out {out}: is a folder")
    if scene is not None and scene.path and _same_file(out, pathlib.Path(scene.path)):
        raise UsageError(f"--out {out}: is the scene file being run; choose another output")


def _check_render(args: argparse.Namespace, out: pathlib.Path) -> None:
    """``--render`` must not name the frame stream: the picture would replace the run."""
    render = getattr(args, "render", None)
    if render and _same_file(pathlib.Path(render), out):
        raise UsageError(f"--render {render}: is the --out file {out}; choose another")


def _run_prepare(args: argparse.Namespace) -> _RunPlan:
    """Parse options and load the scene: everything that can fail without the core."""
    steps = _int_option("--steps", args.steps, minimum=1)
    args.particles = _int_option("--particles", args.particles)
    args.seed = _int_option("--seed", args.seed)
    args.time = _float_option("--time", args.time)
    args.every = _int_option("--every", args.every, minimum=1)
    ckpt = _int_option("--checkpoint-every", args.checkpoint_every, minimum=1)
    args.device = _int_option("--device", args.device, minimum=0)
    _live_options(args, needs_live=True)
    if args.resume:
        if args.time is not None and not args.time > 0:
            raise UsageError(f"--time must be a positive number of seconds, got {args.time:g}")
        return _resume_prepare(args, steps, ckpt)
    if args.scene is None:
        raise UsageError("run needs a SCENE or FILE.toml (or --resume RUN.cps); see `corpuscle run --help`")
    scene = _load_with_options(args, RUN_OPTIONS)
    every = int(scene["run.record_every"])
    out = _out_path(args.out, pathlib.Path(f"{_safe_filename(scene.name)}.cps"))
    _check_out(out, scene)
    _check_render(args, out)
    if ckpt is not None and ckpt % every:
        raise UsageError(f"--checkpoint-every {ckpt} must be a multiple of the record interval "
                         f"(run.record_every = {every})")
    # --steps alone runs exactly that many steps; with --time, whichever comes first
    end_time = float(scene["run.end_time"]) if steps is None or args.time is not None else math.inf
    return _RunPlan(scene, out, every, end_time, steps, ckpt)


def _resume_prepare(args: argparse.Namespace, steps: int | None, ckpt: int | None) -> _RunPlan:
    """--resume RUN.cps: the scene, the record interval and the end come from its header."""
    for option, given in (("SCENE", args.scene), ("--particles", args.particles), ("--seed", args.seed),
                          ("--set", args.set), ("--every", args.every)):
        if given:
            raise UsageError(f"--resume continues the recorded scene; {option} cannot change it")
    import numpy as np

    from .scene import Scene

    io = importlib.import_module("corpuscle.io")
    src = pathlib.Path(args.resume)
    if not src.is_file():
        raise UsageError(f"--resume {src}: {'is a folder' if src.is_dir() else 'no such file'}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a torn tail is what a killed run leaves: it is cut off
        run = io.open(src)
    try:
        header = dict(run.header)
        kinds = run.kinds
        last = max((i for i, k in enumerate(kinds) if k == "checkpoint"), default=None)
        if last is None:
            raise UsageError(f"--resume {src}: the run has no checkpoint (record with --checkpoint-every K)")
        frame = run[last]
        state = {name: np.array(frame[name]) for name in frame.fields}
        step0, time0 = int(frame.step), float(frame.time)
    finally:
        run.close()
    params = header.get("parameters")
    if not isinstance(params, dict):
        raise UsageError(f"--resume {src}: the header has no scene parameters")
    scene = Scene.from_dict(params, name=str(header.get("scene", "scene")))
    every = int(header.get("record_every") or scene["run.record_every"])
    # the frames go on holding what the recorded ones hold
    args.velocity = bool(args.velocity or header.get("velocity_recorded"))
    args.ghosts = bool(args.ghosts or header.get("ghosts_recorded"))
    out = _out_path(args.out, src)
    _check_out(out, None)
    _check_render(args, out)
    if ckpt is None:
        ckpt = header.get("checkpoint_every")
    if ckpt is not None and int(ckpt) % every:
        raise UsageError(f"--checkpoint-every {ckpt} must be a multiple of the record interval ({every})")
    if args.time is not None and not args.time > time0:
        # an end already passed would take no step and still report success
        raise UsageError(f"--time {args.time:g} must be after the checkpoint's time {time0:g} s "
                         f"(step {step0} of {src})")
    # a new end, or the recorded run's own
    if steps is not None or args.time is not None:
        end_time = args.time if args.time is not None else math.inf
        end_step = step0 + steps if steps is not None else None
    else:
        t = header.get("end_time")
        end_time = math.inf if t is None else float(t)
        end_step = header.get("end_step")
    resume = {"path": src, "header": header, "frame": last, "state": state, "step": step0}
    return _RunPlan(scene, out, every, end_time, end_step, None if ckpt is None else int(ckpt), resume)


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


def _run_header(plan: _RunPlan, sim, backend: str, args: argparse.Namespace) -> dict[str, Any]:
    """The frame-stream header: the simulation's own description (scene name, container,
    bodies, h, ...) plus what was run, how and by which build, and where it ends."""
    from . import __version__

    scene = plan.scene
    header = dict(sim.header()) if hasattr(sim, "header") else {}
    header.update({
        "program": PROG,
        "version": __version__,
        "command": _command_line(args),
        "created": _now_iso(),
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
    from . import render
    return render.LiveRender.from_args(args, header)


@contextlib.contextmanager
def _interruptible_init(what: str):
    """Ctrl-C during initialisation exits at once (130), with one line.

    Placing and building a large scene is one long call into the core (a minute for
    2,000,000 particles on 2 cores), and Python runs its SIGINT handler only when that call
    returns. The signal's byte on a wakeup fd reaches a watcher thread as soon as the core
    lets go of the interpreter (placement and evaluation do); nothing has been written yet,
    so it ends the process there."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    rfd, wfd = os.pipe()
    os.set_blocking(wfd, False)
    lock, state = threading.Lock(), {"done": False}

    def watch() -> None:
        try:
            got = os.read(rfd, 64)
        except OSError:
            return
        with lock:
            if state["done"] or signal.SIGINT not in got:
                return
            _err(f"interrupted while {what}")
            sys.stderr.flush()
            os._exit(EXIT_INTERRUPTED)

    try:
        previous = signal.set_wakeup_fd(wfd, warn_on_full_buffer=False)
    except ValueError:  # not the main interpreter
        os.close(rfd)
        os.close(wfd)
        yield
        return
    watcher = threading.Thread(target=watch, name="corpuscle-init-interrupt", daemon=True)
    watcher.start()
    try:
        yield
    finally:
        with lock:
            state["done"] = True
        signal.set_wakeup_fd(previous)
        os.close(wfd)  # the watcher's read returns b"" and it ends
        watcher.join()
        os.close(rfd)


@contextlib.contextmanager
def _interrupts_deferred():
    """Ctrl-C while a frame is written takes effect once it is whole."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    hits: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, _frame: hits.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if hits:
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
            _err(f"live: frame not published: {_one_line(exc)}")


def _start_viewer(args: argparse.Namespace, sim, header: dict[str, Any]):
    """`run --live`: the viewer's server, started (its URL printed on stderr), or None."""
    args._viewer = None
    if not getattr(args, "live", False):
        return None
    live = importlib.import_module("corpuscle.live")
    try:
        viewer = live.RunViewer.start(sim, header, host=args.host, port=args.port)
    except live.ServerError as exc:
        raise UsageError(f"--live: {_one_line(exc)}") from None
    _err(_live_url_message(viewer.server, "live view"))
    args._viewer = viewer
    return viewer


def _open_writer(io, plan: _RunPlan, header: dict[str, Any]):
    """A new frame stream, or (resuming in place) the recorded one cut back to its checkpoint."""
    out = plan.out
    try:
        if plan.resume is not None and _same_file(out, plan.resume["path"]):
            return io.FrameWriter.append(out, keep=plan.resume["frame"] + 1)
        if plan.resume is not None:
            header = dict(plan.resume["header"], resumed_from=str(plan.resume["path"]),
                          resumed_at_step=plan.resume["step"], command=header["command"])
        return io.FrameWriter(out, header)
    except OSError as exc:
        error = UsageError(f"cannot write {out}: {exc.strerror or _one_line(exc)}")
        if exc.errno in _DISK_FULL:
            error.exit_code = EXIT_WRITE  # the disk, not the input: as when it fills up mid-run
        raise error from None




def _cmd_run(args: argparse.Namespace) -> int:
    # validate everything cheap first; the core is imported only after this
    plan = _run_prepare(args)
    scene, out, every = plan.scene, plan.out, plan.every
    simulation = _import_core_module("corpuscle.simulation")
    io = importlib.import_module("corpuscle.io")

    # initialisation (timed on its own, not part of steps/s)
    t_init = time.perf_counter()
    with _interruptible_init("initialising (nothing written)"):
        if plan.resume is None:
            sim = simulation.Simulation.from_scene(scene, backend=args.backend, neighbors=args.neighbors,
                                                   device=args.device)
        else:
            sim = simulation.Simulation(scene, backend=args.backend,
                                        checkpoint=_checkpoint_state(plan.resume["state"]),
                                        neighbors=args.neighbors, device=args.device)
    sim.set_end_time(plan.end_time)  # the core shortens the last step to land on it
    start_steps = int(sim.steps)
    start_relists = _relistings(sim)
    init_seconds = time.perf_counter() - t_init
    backend = str(getattr(sim, "backend", args.backend))
    header = _run_header(plan, sim, backend, args)
    viewer = _start_viewer(args, sim, header)
    try:
        live = _live_render(args, header)
        writer = _open_writer(io, plan, header)
    except BaseException:
        if viewer is not None:
            viewer.close()
        raise

    frames = 0
    last_recorded = start_steps
    stopped: str | None = None
    interrupted = False
    write_error: str | None = None
    budget = None if plan.end_step is None else plan.end_step - start_steps
    progress = _Progress(_progress_enabled(args), budget, plan.end_time)
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
            sink = FrameSink(writer)  # frames are written while the next chunk steps
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
                        stopped = _one_line(message)
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
            except KeyboardInterrupt:
                interrupted = True
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
        write_error = f"cannot write {out}: {exc.strerror or _one_line(exc)}"
    finally:
        sys.setswitchinterval(switch)
    # the writer is closed here, so every recorded frame is readable

    steps = int(sim.steps) - start_steps
    if interrupted:
        _err(f"run interrupted at step {sim.steps}; {frames} frames kept in {out}")
        return EXIT_INTERRUPTED
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
        summary["relistings"] = _relistings(sim) - start_relists
    if args.json:
        print(json.dumps(summary, default=_json_default))
    else:
        _print_run_summary(summary, scene)
    if write_error:
        _err(f"error: {write_error}; {frames} frames kept up to step {last_recorded}")
        return EXIT_WRITE
    if stopped:
        _err(f"run stopped at step {sim.steps}: {stopped}")
        return EXIT_STOPPED
    return EXIT_OK


def _checkpoint_state(fields: dict[str, Any]) -> dict[str, Any]:
    """A checkpoint frame's fields as Simulation.restore takes them: the ``state.*`` scalars
    and the particle fields (restore takes the checkpointed ones and names any missing)."""
    import numpy as np

    state: dict[str, Any] = {}
    for name, arr in fields.items():
        if name.startswith("state."):
            value = np.asarray(arr)[0]
            state[name[len("state."):]] = value.tolist() if value.ndim else value.item()
        else:
            state[name] = np.asarray(arr)
    missing = [k for k in ("time", "step") if k not in state]
    if missing:
        raise UsageError(f"--resume: the checkpoint lacks {', '.join(missing)}")
    return state


def _json_default(obj: Any) -> Any:
    """Make NumPy scalars and arrays JSON-serialisable."""
    for attr in ("tolist", "item"):
        if hasattr(obj, attr):
            return getattr(obj, attr)()
    return str(obj)


def _relistings(sim) -> int | None:
    """The `lists` index's relistings so far (None for any other index or scene)."""
    if getattr(sim, "neighbors", None) != "lists" or not hasattr(sim, "state"):
        return None
    state = sim.state()
    return int(state["rebuilds"]) if "rebuilds" in state else None


def _print_run_summary(s: dict[str, Any], scene) -> None:
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
    rows += [
        ("steps", f"{s['steps']:,}"),
        ("simulated time", f"{s['sim_time']:.4g} s"),
        ("initialisation", f"{s['init_time']:.3f} s"),
        ("wall time", f"{s['wall_time']:.3f} s"),
        ("steps/s", _fmt_rate(s["steps_per_second"])),
        ("particle-steps/s", _fmt_rate(s["particle_steps_per_second"])),
    ]
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


# ---------------------------------------------------------------------------
# corpuscle view
# ---------------------------------------------------------------------------


def _configure_view(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", metavar="RUN.cps", help="a recorded run")
    _add_live_arguments(p)


def _cmd_view(args: argparse.Namespace) -> int:
    _live_options(args, needs_live=False)
    path = pathlib.Path(args.run)
    if not path.is_file():
        raise UsageError(f"{path}: {'is a folder' if path.is_dir() else 'no such file'}")
    live = importlib.import_module("corpuscle.live")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a torn tail: its whole frames are shown
        try:
            server, run = live.serve_recording(path, host=args.host, port=args.port)
        except live.ServerError as exc:
            raise UsageError(f"view: {_one_line(exc)}") from None
    _err(_live_url_message(server, f"viewing {path} ({len(run)} frames)"))
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
        run.close()
    return EXIT_OK


register(Command("view", "serve a recorded run to a web page (play, pause, scrub, speed)", _configure_view,
                 _cmd_view))


# ---------------------------------------------------------------------------
# corpuscle bench
# ---------------------------------------------------------------------------


def _configure_bench(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", metavar="SCENE|FILE.toml", help="a built-in scene name or a scene file")
    p.add_argument("--backend", nargs="+", choices=BACKENDS, metavar="B",
                   help="backends to time: serial, cpu, cuda (default: every usable one)")
    p.add_argument("--particles", metavar="N", nargs="+",
                   help=_particles_help() + "; several values (or a comma-separated list): a sweep over them")
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
    p.add_argument("--json", metavar="FILE", help="also write the results as a JSON list of rows to FILE")
    p.add_argument("--plot", metavar="FILE.png",
                   help="also plot particle-steps/s against particles, a line for each backend and index (PNG)")
    p.add_argument("--max-step", metavar="SECONDS",
                   help="in a sweep over --particles, leave out a backend and index's larger sizes once a step "
                        "there would take longer than this (from its last size: O(N), all pairs O(N^2))")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _cmd_bench(args: argparse.Namespace) -> int:
    from . import __version__

    # options and scene first; the core only after
    steps = _int_option("--steps", args.steps, minimum=1)
    repeats = _int_option("--repeats", args.repeats, minimum=1)
    warmup = _int_option("--warmup", args.warmup, minimum=0)
    start_time = _float_option("--start-time", args.start_time)
    if start_time < 0.0:
        raise UsageError(f"--start-time must be a simulated time of 0 s or more, got {args.start_time!r}")
    args.device = _int_option("--device", args.device, minimum=0)
    sizes = [None]
    if args.particles:
        sizes = [_int_option("--particles", t, minimum=1) for v in args.particles for t in str(v).split(",")]
    indexes = [None]
    if args.neighbors:
        names = [t.strip() for v in args.neighbors for t in str(v).split(",")]
        if any(not t for t in names):
            raise UsageError(f"--neighbors {' '.join(args.neighbors)!r}: an empty index name")
        indexes = list(dict.fromkeys(names))
    scenes = []
    for size in sizes:
        args.particles = size
        scenes.append(_load_with_options(args, {}))
    scene = scenes[0]
    batches = [_int_option("--batch", b, minimum=1) for b in args.batch] if args.batch else [None]
    if args.batch and scene.kind != "magic8ball":
        raise UsageError(f"--batch: batches of scenes are magic8ball scenes, got kind {scene.kind!r}")
    if args.batch and start_time > 0.0:
        raise UsageError(f"--start-time {args.start_time}: not with --batch (each scene of a batch keeps its own clock)")
    end = float(scene["run.end_time"])
    if start_time > 0.0 and start_time >= end:
        raise UsageError(f"--start-time {args.start_time}: not before {scene.name}'s end time run.end_time = {end:g} s "
                         f"(raise it with --set run.end_time=T to time the flow later)")
    max_step = _float_option("--max-step", args.max_step)
    if max_step is not None and not max_step > 0.0:
        raise UsageError(f"--max-step must be a positive number of seconds, got {args.max_step!r}")
    if args.plot is not None:
        from ._viz_common import check_file_output

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
    simulation = _import_core_module("corpuscle.simulation")
    Simulation = simulation.Simulation
    backends = list(dict.fromkeys(args.backend)) if args.backend else [
        b for b in BACKENDS if b != "cuda" or Simulation.cuda_available()
    ]
    info = _build_info()
    date = _now_iso()

    # progress over backends x repeats (stderr, terminals only)
    bar = None
    if _progress_enabled(argparse.Namespace(no_progress=args.no_progress)):
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
            with _interruptible_init(f"initialising {backend}"):
                if batch is None:
                    sim = Simulation.from_scene(scene, backend=backend, neighbors=index, device=args.device)
                else:
                    from .batch import Batch

                    # no settling: the timing does not depend on it
                    sim = Batch.from_scene(scene, n=batch, backend=backend, neighbors=index, device=args.device,
                                           settle=0.0)
            init_seconds = time.perf_counter() - t_init
            if start_time > 0.0:
                if bar is not None:
                    bar.set_description(f"{backend}: running to t = {start_time:g} s")
                _bench_advance(sim, start_time, backend)
                if bar is not None:
                    bar.set_description(backend)
            if warmup:
                sim.step(warmup)
            relists = _relistings(sim)
            times = []
            for _ in range(repeats):
                times.append(float(sim.bench_steps(steps)))
                if bar is not None:
                    bar.update(1)
            if relists is not None:
                relists = _relistings(sim) - relists
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
                "device": _device_name(backend, info, args.device),
                "date": date,
                "version": __version__,
                "command": _command_line(args),
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
            if batch is None and "n_wall" in (getattr(sim, "info", None) or {}):
                row["wall_particles"] = int(sim.info["n_wall"])
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
                json.dump(rows, f, indent=2, default=_json_default)
                f.write("\n")
        except OSError as exc:
            raise UsageError(f"cannot write {args.json}: {exc.strerror or _one_line(exc)}") from None
    _print_bench(rows)
    from . import _bench_report

    if len({r["particles"] for r in rows}) > 1 and (tables := _bench_report.speedup_tables(rows)):
        print()
        print("\n".join(tables))
    for note in left_out:
        print(f"left out: {note}")
    if args.plot:
        try:
            _bench_report.plot(rows, args.plot, title=f"corpuscle {scene.name}")
        except OSError as exc:
            raise UsageError(f"cannot write {args.plot}: {exc.strerror or _one_line(exc)}") from None
        print(f"plot: {args.plot}")
    return EXIT_OK


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
    head = f"{'backend':<8} " + (f"{'batch':>7} " if batched else "") + f"{'particles':>10} {'init(s)':>8} {'steps/s':>12} "
    head += (f"{'scene-steps/s':>14} " if batched else "") + f"{'particle-steps/s':>18}"
    if sweep or nbr:
        head = f"{'index':<9}" + head + f" {'neighbours':>10}"
    print(head + (f" {'speedup':>9}" if serial else ""))
    for r in rows:
        if sweep or nbr:
            serial = None if batched else base(r, "serial")  # a batch's rows have no speedup column
            print(f"{str(r.get('neighbors')):<9}", end="")
        init = r.get("init_seconds")
        init_text = f"{init:8.3f}" if isinstance(init, (int, float)) else f"{'':>8}"
        line = (f"{r['backend']:<8} " + (f"{r.get('batch', 1):>7,} " if batched else "") +
                f"{r['particles']:>10,} {init_text} {_fmt_rate(r['steps_per_second']):>12} " +
                (f"{_fmt_rate(r['scene_steps_per_second']):>14} " if batched else "") +
                f"{_fmt_rate(r['particle_steps_per_second']):>18}")
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


register(Command("bench", "time steps per second on each backend", _configure_bench, _cmd_bench))


# ---------------------------------------------------------------------------
# corpuscle validate
# ---------------------------------------------------------------------------


def _configure_validate(p: argparse.ArgumentParser) -> None:
    from . import validation

    p.add_argument("name", metavar="NAME", help=f"what to validate: {', '.join(validation.VALIDATIONS)}")
    p.add_argument("--json", action="store_true", help="print the checks as JSON (after the table)")
    # each validation's own options; those of the one named are parsed in _cmd_validate
    p.add_argument("options", nargs=argparse.REMAINDER, help="the validation's options (NAME --help lists them)")


def _cmd_validate(args: argparse.Namespace) -> int:
    from . import validation

    module = validation.load(args.name)  # unknown name: ValueError, one line, exit 2
    sub = _Parser(prog=f"{PROG} validate {args.name}", description=(module.__doc__ or "").strip().splitlines()[0])
    sub.add_argument("--json", action="store_true", help="print the checks as JSON (and nothing else) on stdout")
    module.add_arguments(sub)
    opts = sub.parse_args(args.options)  # bad options exit 2 with one line
    if args.json or opts.json:  # the JSON alone on stdout: the runs' own tables go to stderr
        with contextlib.redirect_stdout(sys.stderr):
            checks = module.run(opts)
    else:
        checks = module.run(opts)
    ok = all(c.passed for c in checks) and bool(checks)
    if args.json or opts.json:
        print(json.dumps(validation.as_dicts(checks), indent=2, default=_json_default))
        return EXIT_OK if ok else 1
    print()
    rows = [(c.name, f"{c.measured:.6g}", f"{c.reference:.6g}", f"{c.measured - c.reference:+.4g}",
             f"{c.tolerance:.4g}" + (f" {c.unit}" if c.unit else ""), "PASS" if c.passed else "FAIL") for c in checks]
    head = ("check", "measured", "reference", "difference", "tolerance", "")
    widths = [max(len(str(r[k])) for r in [head, *rows]) for k in range(6)]
    print("  ".join(str(h).ljust(w) if k == 0 else str(h).rjust(w) for k, (h, w) in enumerate(zip(head, widths))))
    for r in rows:
        print("  ".join(str(x).ljust(w) if k == 0 else str(x).rjust(w) for k, (x, w) in enumerate(zip(r, widths))))
    for c in checks:
        if c.detail:
            print(f"  {c.name}: {c.detail}")
    print("PASS" if ok else "FAIL")
    return EXIT_OK if ok else 1


register(Command("validate", "run a validation case and check it against its reference (PASS/FAIL)",
                 _configure_validate, _cmd_validate))


def _register_polar() -> None:
    from . import polar

    register(Command("polar", polar.HELP, polar.configure_parser, polar.run_command, polar.DESCRIPTION))


_register_polar()


def _register_viz() -> None:
    """render / plot / export (issue 3): their modules import heavy libraries lazily."""
    from . import export, plot, render

    for name, mod in (("render", render), ("plot", plot), ("export", export)):
        register(Command(name, mod.HELP, mod.configure_parser, mod.run_command, mod.DESCRIPTION))


_register_viz()


# ---------------------------------------------------------------------------
# entry point
# ---------------------------------------------------------------------------


class _Parser(argparse.ArgumentParser):
    """argparse with usage errors on one line: the message and where to find the usage."""

    def error(self, message: str):  # noqa: D401 - argparse's hook
        self.exit(EXIT_USAGE, f"{PROG}: error: {_one_line(message)} (see `{self.prog} --help`)\n")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every registered subcommand."""
    from . import __version__

    parser = _Parser(
        prog=PROG, description="corpuscle: GPU particle simulator (SPH fluids, DEM, rigid bodies)"
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=_Parser)
    for cmd in COMMANDS.values():
        p = sub.add_parser(cmd.name, help=cmd.help, description=cmd.description or cmd.help)
        cmd.configure(p)
        p.set_defaults(_handler=cmd.handler)
    return parser


def _user_errors() -> tuple[type[BaseException], ...]:
    """Exceptions reported as one-line input errors (only from modules already loaded,
    so this never imports the core)."""
    errors: list[type[BaseException]] = [SceneError, UsageError, ValueError]
    for module, name in (("corpuscle.io", "FrameStreamError"), ("corpuscle.simulation", "BackendError")):
        cls = getattr(sys.modules.get(module), name, None)
        if isinstance(cls, type) and issubclass(cls, BaseException):
            errors.append(cls)
    return tuple(errors)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(argv)  # usage errors exit 2 here
    args._argv = argv
    try:
        return int(args._handler(args) or 0)
    except KeyboardInterrupt:
        # Ctrl-C outside a run's loop (which reports its own): no traceback
        _err("interrupted")
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # stdout was closed early (`corpuscle bench ... | head`): stop quietly, as Unix tools do
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 141
    except Exception as exc:
        # bad input: one line, exit 2; CORPUSCLE_DEBUG=1 shows the traceback
        if not isinstance(exc, _user_errors()) or os.environ.get("CORPUSCLE_DEBUG"):
            raise
        _err(f"error: {_one_line(exc)}")
        return int(getattr(exc, "exit_code", EXIT_USAGE))


if __name__ == "__main__":
    sys.exit(main())
