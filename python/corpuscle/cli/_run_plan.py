"""``corpuscle run``'s plan: the options checked and the scene loaded (or the checkpoint to
resume read), everything that can fail before the compiled core is imported."""

from __future__ import annotations

import argparse
import importlib
import math
import os
import pathlib
import warnings
from dataclasses import dataclass
from typing import Any

from ._options import UsageError, float_option, int_option, live_options, load_with_options, safe_filename

RUN_OPTIONS = {"seed": "run.seed", "time": "run.end_time", "every": "run.record_every"}

@dataclass
class RunPlan:
    """What `run` will do, settled before the core is imported."""

    scene: Any
    out: pathlib.Path
    every: int
    end_time: float          # absolute simulated end time (inf: none)
    end_step: int | None     # absolute step to stop at (None: none)
    checkpoint_every: int | None
    resume: dict[str, Any] | None = None  # path, header, checkpoint frame index, state


def same_file(a: pathlib.Path, b: pathlib.Path) -> bool:
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


def _check_out(out: pathlib.Path, scene, force: bool = False) -> None:
    """The output folder must exist; the output must not be a folder or the scene file, nor a
    file that is not a frame stream (without --force), nor a file another run is writing."""
    from .._frame_claim import foreign_start, is_busy

    parent = out.parent if str(out.parent) else pathlib.Path(".")
    if not parent.is_dir():
        raise UsageError(f"--out {out}: folder {parent} does not exist")
    if out.is_dir():
        raise UsageError(f"--out {out}: is a folder")
    if scene is not None and scene.path and same_file(out, pathlib.Path(scene.path)):
        raise UsageError(f"--out {out}: is the scene file being run; choose another output")
    try:
        start = None if force else foreign_start(out)
    except OSError as exc:
        raise UsageError(f"--out {out}: cannot read it: {exc.strerror or exc}") from None
    if start is not None:
        raise UsageError(f"--out {out}: exists and is not a corpuscle frame stream (it starts {start[:16]!r}); "
                         "--force replaces it")
    busy = is_busy(out)
    if busy is not None:
        raise UsageError(f"--out {out}: {busy.strerror}")


def _check_render(args: argparse.Namespace, out: pathlib.Path) -> None:
    """``--render`` must not name the frame stream: the picture would replace the run."""
    render = getattr(args, "render", None)
    if render and same_file(pathlib.Path(render), out):
        raise UsageError(f"--render {render}: is the --out file {out}; choose another")


def prepare(args: argparse.Namespace) -> RunPlan:
    """Parse options and load the scene: everything that can fail without the core."""
    steps = int_option("--steps", args.steps, minimum=1)
    args.particles = int_option("--particles", args.particles)
    args.seed = int_option("--seed", args.seed)
    args.time = float_option("--time", args.time)
    args.every = int_option("--every", args.every, minimum=1)
    ckpt = int_option("--checkpoint-every", args.checkpoint_every, minimum=1)
    args.device = int_option("--device", args.device, minimum=0)
    live_options(args, needs_live=True)
    if getattr(args, "no_token", False):
        from ..live.server import is_local

        if not getattr(args, "live", False):
            raise UsageError("--no-token is an option of the live view: add --live")
        if not is_local(args.host):
            raise UsageError(f"--no-token: only on this machine's own address (127.0.0.1, localhost, ::1), "
                             f"not --host {args.host}")
    if args.resume:
        if args.time is not None and not args.time > 0:
            raise UsageError(f"--time must be a positive number of seconds, got {args.time:g}")
        return _resume_prepare(args, steps, ckpt)
    if args.scene is None:
        raise UsageError("run needs a SCENE or FILE.toml (or --resume RUN.cps); see `corpuscle run --help`")
    scene = load_with_options(args, RUN_OPTIONS)
    every = int(scene["run.record_every"])
    out = _out_path(args.out, pathlib.Path(f"{safe_filename(scene.name)}.cps"))
    _check_out(out, scene, bool(getattr(args, "force", False)))
    _check_render(args, out)
    if ckpt is not None and ckpt % every:
        raise UsageError(f"--checkpoint-every {ckpt} must be a multiple of the record interval "
                         f"(run.record_every = {every})")
    # --steps alone runs exactly that many steps; with --time, whichever comes first
    end_time = float(scene["run.end_time"]) if steps is None or args.time is not None else math.inf
    return RunPlan(scene, out, every, end_time, steps, ckpt)


def _resume_prepare(args: argparse.Namespace, steps: int | None, ckpt: int | None) -> RunPlan:
    """--resume RUN.cps: the scene, the record interval and the end come from its header."""
    for option, given in (("SCENE", args.scene), ("--particles", args.particles), ("--seed", args.seed),
                          ("--set", args.set), ("--every", args.every)):
        if given:
            raise UsageError(f"--resume continues the recorded scene; {option} cannot change it")
    import numpy as np

    from ..scene import Scene

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
    _check_out(out, None, bool(getattr(args, "force", False)))
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
    return RunPlan(scene, out, every, end_time, end_step, None if ckpt is None else int(ckpt), resume)


def checkpoint_state(fields: dict[str, Any]) -> dict[str, Any]:
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

