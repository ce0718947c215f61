"""``corpuscle render``: pictures and videos of recorded runs.

2-D scenes are drawn as a heat map of a per-particle value (by default pressure on the seed's
7-stop ramp over log(p+1)) with the obstacles filled and the walls drawn; 3-D scenes as lit
sphere impostors with a depth buffer, the container outlined and rigid bodies as lit meshes
(the die with its pips). The rasterizer is the compiled ``corpuscle._render`` module.

Python API::

    render_run("run.cps", "run.mp4", size=(1280, 720), fps=30, color="speed")

    with LiveRender("run.mp4", header, fps=30) as live:     # while a run records
        for frame in frames:
            live.add_frame(frame)

    img = FrameRenderer(header).render(frame)                # one (H, W, 3) uint8 picture
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import _colors
from ._errors import write_failure
from ._frame_renderer import FrameRenderer
from ._render_scene import (  # noqa: F401  (the look and the option parsers are public here)
    BACKGROUND_2D, BACKGROUND_3D, CONTAINER_RGB, DIE_RGB, GHOST_RGB, LIGHT, MIN_RADIUS_PX, OBSTACLE_EDGE,
    OBSTACLE_FILL, PIP_RGB, PIPS, ROBUST_PERCENTILES, WALL_RGB, RenderError, monotone_triangles, parse_camera,
    parse_fps, parse_range, up_axis)
from ._video import VideoSink, open_sink, output_kind
from ._viz_common import cli_warnings, open_run, os_reason, parse_frames, parse_index, parse_size


# ---- outputs ------------------------------------------------------------------------------


def _open_sink(out, size, fps) -> VideoSink:
    """The output sink, or a one-line RenderError when it cannot be started (no ffmpeg ...)."""
    try:
        return open_sink(out, size, fps, RenderError)
    except OSError as exc:
        raise write_failure(RenderError, f"cannot write {out}: {os_reason(exc)}", exc) from None


@dataclass
class RenderResult:
    """What ``render_run`` wrote."""

    path: Path
    frames: int
    size: tuple[int, int]
    seconds: float
    color_range: tuple[float, float] | None


class LiveRender:
    """Render a run while it records: ``add_frame(frame)`` after each recorded frame, then
    ``close()`` (or use it as a context manager). ``out`` and the options are those of
    :func:`render_run`; the colour range, unless given, widens to cover the frames seen."""

    def __init__(self, out, header: dict, *, fps: float = 30.0, size=(1280, 720), **options):
        self.renderer = FrameRenderer(header, size=size, **options)
        self.sink: VideoSink = _open_sink(out, self.renderer.size, parse_fps(fps))

    def add_frame(self, frame) -> np.ndarray:
        """Render ``frame`` and append it to the output; returns the picture."""
        img = self.renderer.render(frame)
        try:
            self.sink.add(img)
        except OSError as exc:
            raise write_failure(RenderError, f"cannot write {self.sink.path}: {os_reason(exc)}", exc) from None
        return img

    def close(self) -> None:
        """Finish the output and move it into place (it appears only now, complete)."""
        try:
            self.sink.close()
        except OSError as exc:
            raise write_failure(RenderError, f"cannot write {self.sink.path}: {os_reason(exc)}", exc) from None

    def abort(self) -> None:
        """Give up on the output: nothing of it is left behind."""
        self.sink.abort()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        if exc_type is None:
            self.close()
        else:
            self.abort()

    @classmethod
    def from_args(cls, args: argparse.Namespace, header: dict) -> "LiveRender | None":
        """The live renderer ``corpuscle run --render OUT`` asked for (None without --render)."""
        out = getattr(args, "render", None)
        if not out:
            return None
        return cls(out, header, fps=args.render_fps, size=args.render_size, color=args.render_color,
                   value_range=args.render_range, camera=args.render_camera, ghosts=args.render_ghosts)


def add_live_render_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--render OUT`` and its ``--render-*`` options to ``corpuscle run``'s parser."""
    g = parser.add_argument_group("rendering while recording")
    g.add_argument("--render", metavar="OUT", help="render frames as they are recorded to OUT (.mp4, .gif, .png or a directory)")
    g.add_argument("--render-size", metavar="WxH", default="1280x720", help="frame size in pixels (default 1280x720)")
    g.add_argument("--render-fps", metavar="FPS", default=30.0, help="video frame rate (default 30)")
    g.add_argument("--render-color", metavar="FIELD", help="colour field (default: the kind's choice, e.g. the wind tunnel's number_density "
                   "over 0 to 4x the free stream's; else pressure in 2-D, speed in 3-D)")
    g.add_argument("--render-range", metavar="LO:HI", help="colour range in field units (default: the kind's range for its "
                   "field, else robust percentiles)")
    g.add_argument("--render-camera", metavar="AZ,EL[,DIST]", help="3-D camera: azimuth, elevation (degrees), distance (m)")
    g.add_argument("--render-ghosts", action="store_true", help="draw ghost particles too")


def render_run(run, out, *, frames=None, frame=None, size=(1280, 720), fps: float = 30.0, color: str | None = None,
               value_range=None, log: bool | None = None, ramp: str | None = None, camera=None, ghosts: bool = False,
               cutaway: bool | None = None, overlay: bool = True, colorbar: bool = True,
               progress: bool | None = None) -> RenderResult:
    """Render a recorded run (path or opened Run) to ``out``.

    ``out`` decides the output: ``.mp4`` (H.264), ``.gif``, ``.png`` (one frame: ``frame``,
    default the last) or a directory of numbered PNGs. ``frames`` selects frames as
    ``"a:b[:step]"`` (or a slice). The other options are those of :class:`FrameRenderer`.
    ``progress``: a progress bar on stderr (None: only when stderr is a terminal).
    Raises :class:`RenderError` for bad input.
    """
    kind = output_kind(out, RenderError)
    size = parse_size(size, RenderError)
    fps = parse_fps(fps)
    run = open_run(run, RenderError)
    count = len(run)
    if kind == "png":
        if frames is not None:
            raise RenderError("--frames selects frames for videos and PNG directories; use --frame I for one .png")
        indices = [parse_index(frame, count, RenderError)]
    else:
        if frame is not None:
            raise RenderError("--frame picks the frame of a .png; use --frames a:b[:step] for videos and directories")
        indices = parse_frames(frames, count, RenderError)
    # colour range from up to 12 frames spread over the selection (stable over the whole video);
    # a range given by the caller needs no samples
    picks = [] if value_range is not None else sorted(
        {indices[int(round(k))] for k in np.linspace(0, len(indices) - 1, min(12, len(indices)))})
    renderer = FrameRenderer(run.header, size=size, color=color, value_range=value_range, log=log, ramp=ramp,
                             camera=camera, ghosts=ghosts, cutaway=cutaway, overlay=overlay, colorbar=colorbar,
                             sample_frames=[run[i] for i in picks])
    start = time.perf_counter()
    from tqdm import tqdm

    # the output appears only when complete: any failure (a corrupted frame, a full disk, an
    # encoder that died, Ctrl-C) removes what was written so far
    sink = _open_sink(out, size, fps)
    try:
        with tqdm(total=len(indices), unit="frame", desc="render", disable=None if progress is None else not progress,
                  leave=False) as bar:
            for i in indices:
                sink.add(renderer.render(run[i]))
                bar.update(1)
        sink.close()
    except OSError as exc:
        sink.abort()
        raise write_failure(RenderError, f"cannot write {out}: {os_reason(exc)}", exc) from None
    except BaseException:
        sink.abort()
        raise
    return RenderResult(Path(os.fspath(out)), len(indices), size, time.perf_counter() - start, renderer.color_range)


# ---- command line --------------------------------------------------------------------------


def run_command(args: argparse.Namespace) -> int:
    """Run ``corpuscle render`` from parsed arguments; returns the exit code."""
    with cli_warnings():
        return _run_command(args)


def _run_command(args: argparse.Namespace) -> int:
    res = render_run(args.run, args.output, frames=args.frames, frame=args.frame, size=args.size, fps=args.fps,
                     color=args.color, value_range=args.range, log=args.log, ramp=args.ramp, camera=args.camera,
                     ghosts=args.ghosts, cutaway=args.cutaway, overlay=not args.no_overlay, colorbar=not args.no_colorbar,
                     progress=False if args.quiet else None)
    if not args.quiet:
        print(f"wrote {res.path} ({res.frames} frame{'s' if res.frames != 1 else ''}, {res.size[0]}x{res.size[1]}, {res.seconds:.1f} s)")
    return 0


# one-line help and description of the subcommand (for a command table such as corpuscle.cli's)
HELP = "render a recorded run to a video, GIF, PNG or PNG frames"
DESCRIPTION = ("Render a recorded run. OUT decides the output: .mp4 (H.264), .gif, .png (one frame) "
               "or a directory of numbered PNGs.")


def configure_parser(p: argparse.ArgumentParser) -> None:
    """Add ``corpuscle render``'s arguments to a (sub)parser."""
    p.add_argument("run", metavar="RUN", help="recorded run (frame stream file)")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output: .mp4, .gif, .png or a directory")
    p.add_argument("--force", action="store_true", help="replace an existing output file of another kind than its name says")
    p.add_argument("--frame", metavar="I", help="frame of a .png output (default: the last; negatives count from the end)")
    p.add_argument("--frames", metavar="A:B[:STEP]", help="frames of a video or directory (Python slice; default all)")
    p.add_argument("--size", metavar="WxH", default="1280x720", help="picture size in pixels (default 1280x720)")
    p.add_argument("--fps", metavar="FPS", default=30.0, help="video frame rate (default 30)")
    p.add_argument("--color", metavar="FIELD", help="colour by a recorded per-particle field, 'speed' or 'none' "
                                                    "(default: the kind's choice, e.g. the wind tunnel's number_density over "
                                                    "0 to 4x the free stream's; else pressure in 2-D, speed or density "
                                                    "in 3-D)")
    p.add_argument("--range", metavar="LO:HI", help="colour range in field units (default: the kind's range for its "
                                                   "field, else the 1st-99th percentile)")
    scale = p.add_mutually_exclusive_group()
    scale.add_argument("--log", dest="log", action="store_true", default=None, help="colour on log(1+value) (default for 2-D pressure)")
    scale.add_argument("--linear", dest="log", action="store_false", help="colour on the value itself")
    p.add_argument("--ramp", choices=sorted(_colors.RAMPS), help="colour ramp (default: heat in 2-D, ocean in 3-D)")
    p.add_argument("--camera", metavar="AZ,EL[,DIST]", help="3-D camera: azimuth and elevation in degrees, distance in m")
    p.add_argument("--ghosts", action="store_true", help="draw ghost (boundary) particles too")
    cut = p.add_mutually_exclusive_group()
    cut.add_argument("--cutaway", dest="cutaway", action="store_true", default=None,
                     help="leave out particles in front of the die (or the scene centre) so it shows "
                          "(default in 3-D scenes with a rigid body)")
    cut.add_argument("--no-cutaway", dest="cutaway", action="store_false", help="draw every particle")
    p.add_argument("--no-overlay", action="store_true", help="leave out the time/step text")
    p.add_argument("--no-colorbar", action="store_true", help="leave out the colour bar")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``corpuscle render`` on an argparse subparsers object (handler in ``func``)."""
    p = subparsers.add_parser("render", help=HELP, description=DESCRIPTION)
    configure_parser(p)
    p.set_defaults(func=run_command)
    return p
