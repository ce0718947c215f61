"""``corpuscle plot``: the time series a run recorded, as a page of labelled plots.

Whichever the scene has: time step, kinetic energy, density error and mean density, die height
and speed, lift and drag and their coefficients, particle counts, and any other per-frame
diagnostic, each against simulated time with its units (matplotlib, Agg, no pyplot state).

Python API::

    fig = plot_run("run.cps", "run.png")     # also returns the matplotlib Figure
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

import numpy as np

from ._errors import write_failure
from ._viz_common import AtomicOutputs, check_file_output, cli_warnings, open_run, os_reason, require, scene_name, units_of


class PlotError(ValueError):
    """Bad input to ``corpuscle plot`` (one-line message)."""


# panels: (title, diagnostics drawn together, y scale); the rest get a panel each
PANELS = [
    ("time step", ["dt"], "log"),
    ("kinetic energy", ["kinetic_energy"], "linear"),
    ("density error", ["density_error"], "linear"),
    ("mean density", ["mean_density"], "linear"),
    ("die height", ["die_height"], "linear"),
    ("die speed", ["die_speed"], "linear"),
    ("lift and drag", ["lift", "drag"], "linear"),
    ("force coefficients", ["cl", "cd"], "linear"),
    ("particles", ["n_particles", "n_ghosts"], "linear"),
]
# readable names of the series in legends and axis labels
NAMES = {
    "dt": "dt", "kinetic_energy": "kinetic energy", "density_error": "max relative density error",
    "mean_density": "mean density", "die_height": "die height", "die_speed": "die speed", "lift": "lift",
    "drag": "drag", "cl": "C_L", "cd": "C_D", "n_particles": "particles", "n_ghosts": "ghosts",
}
# output formats matplotlib writes here
FORMATS = (".png", ".pdf", ".svg")


def available_series(run) -> dict[str, np.ndarray]:
    """Every per-frame series the run has, by name, with at least one finite value."""
    names: list[str] = ["dt"]
    recorded = getattr(run, "diagnostic_names", None)
    if recorded is None:
        recorded = list(dict.fromkeys(k for frame in run for k in (getattr(frame, "diagnostics", None) or {})))
    names += [k for k in recorded if k not in names and k not in ("time", "step")]
    out = {}
    for k in names:
        try:
            v = np.asarray(run.series(k), dtype=np.float64)
        except (KeyError, ValueError):
            continue
        if v.size and np.any(np.isfinite(v)):
            out[k] = v
    return out


def _label(name: str, header: dict) -> str:
    u = units_of(name, header)
    base = NAMES.get(name, name.replace("_", " "))
    return f"{base} [{u}]" if u else base


def plot_run(run, out=None, *, series: list[str] | str | None = None, width: float = 11.0, dpi: int = 110):
    """Plot a run's recorded time series; save to ``out`` (.png, .pdf or .svg) when given.

    ``series``: names to draw (list or comma-separated), default all. Returns the
    matplotlib ``Figure``; each line carries its series name as its label.
    Raises :class:`PlotError` for bad input.
    """
    if out is not None:
        if Path(os.fspath(out)).suffix.lower() not in FORMATS:
            raise PlotError(f"cannot plot to '{out}': the output must end in {', '.join(FORMATS)}")
        out = check_file_output(out, PlotError)
    if not (isinstance(dpi, int) and 20 <= dpi <= 1200):
        raise PlotError(f"--dpi must be an integer in 20..1200, got {dpi}")
    run = open_run(run, PlotError)
    if len(run) == 0:
        raise PlotError("the run has no frames to plot")
    have = available_series(run)
    if isinstance(series, str):
        series = [s.strip() for s in series.split(",") if s.strip()]
    if series:
        unknown = [s for s in series if s not in have]
        if unknown:
            raise PlotError(f"unknown series '{unknown[0]}': this run has {', '.join(have) or 'none'}")
        have = {k: have[k] for k in series}
    if not have:
        raise PlotError("the run recorded no time series to plot")
    # group the series into panels: known groups first, then one panel per other diagnostic
    panels, used = [], set()
    for title, names, scale in PANELS:
        present = [n for n in names if n in have]
        if present:
            positive = all(np.nanmin(have[n]) > 0 for n in present if np.any(np.isfinite(have[n])))
            panels.append((title, present, scale if positive else "linear"))
            used.update(present)
    panels += [(NAMES.get(k, k.replace("_", " ")), [k], "linear") for k in have if k not in used]

    require("matplotlib", "matplotlib", "corpuscle plot", PlotError)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    t = np.asarray(run.series("time"), dtype=np.float64)
    header = run.header or {}
    ncols = 1 if len(panels) <= 3 else 2
    nrows = math.ceil(len(panels) / ncols)
    fig = Figure(figsize=(width, 2.6 * nrows + 0.8), dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False, sharex=True)
    for ax, (title, names, scale) in zip(axes.flat, panels):
        for name in names:
            y = have[name]
            style = "o-" if np.count_nonzero(np.isfinite(y)) < 30 else "-"
            ax.plot(t, y, style, ms=3, lw=1.3, label=name)
        units = {units_of(n, header) for n in names}
        if len(names) == 1:
            ax.set_ylabel(_label(names[0], header))
        else:
            u = units.pop() if len(units) == 1 else ""
            ax.set_ylabel(f"{title} [{u}]" if u else title)
            ax.legend([NAMES.get(n, n) for n in names], loc="best", fontsize="small")
        ax.set_yscale(scale)
        ax.set_title(title, fontsize="medium")
        ax.grid(True, alpha=0.3)
    for ax in axes.flat[len(panels):]:
        ax.set_visible(False)
    for ax in axes.flat[:len(panels)]:
        ax.tick_params(labelbottom=True)
        ax.set_xlabel("time [s]")
    name = scene_name(header)
    fig.suptitle(f"{name}: {len(run)} frames, t = {np.nanmin(t):.4g}..{np.nanmax(t):.4g} s".lstrip(": "))
    if out is not None:
        # written under a temporary name and moved into place when complete
        with AtomicOutputs() as files:
            try:
                fig.savefig(files.path(out), format=out.suffix.lower()[1:])
                files.commit()
            except OSError as exc:
                files.discard()
                raise write_failure(PlotError, f"cannot write {out}: {os_reason(exc)}", exc) from None
    return fig


def run_command(args: argparse.Namespace) -> int:
    """Run ``corpuscle plot`` from parsed arguments; returns the exit code."""
    with cli_warnings():
        return _run_command(args)


def _run_command(args: argparse.Namespace) -> int:
    try:
        dpi = int(args.dpi)
    except ValueError:
        raise PlotError(f"--dpi must be an integer, got '{args.dpi}'") from None
    plot_run(args.run, args.output, series=args.series, dpi=dpi)
    print(f"wrote {args.output}")
    return 0


# one-line help and description of the subcommand (for a command table such as corpuscle.cli's)
HELP = "plot the time series a run recorded"
DESCRIPTION = "Plot a recorded run's time series (dt, energies, errors, forces, counts)."


def configure_parser(p: argparse.ArgumentParser) -> None:
    """Add ``corpuscle plot``'s arguments to a (sub)parser."""
    p.add_argument("run", metavar="RUN", help="recorded run (frame stream file)")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output picture: .png, .pdf or .svg")
    p.add_argument("--force", action="store_true", help="replace an existing output file of another kind than its name says")
    p.add_argument("--series", metavar="A,B,...", help="series to plot (default: every one the run has)")
    p.add_argument("--dpi", default=110, metavar="DPI", help="resolution of a .png (default 110)")


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``corpuscle plot`` on an argparse subparsers object (handler in ``func``)."""
    p = subparsers.add_parser("plot", help=HELP, description=DESCRIPTION)
    configure_parser(p)
    p.set_defaults(func=run_command)
    return p
