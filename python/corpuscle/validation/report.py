"""``corpuscle validate all``: every validation in one run, and one report a reviewer reads
without running anything.

Each validation of :data:`~corpuscle.validation.VALIDATIONS` runs with its own defaults (or its
``--full``), on the backend asked for, with its plot (when it draws one) written beside the
report. The report (Markdown) holds, per validation: what it compares, the exact command that
reruns it alone, its checks (measured, reference, difference, tolerance, PASS/FAIL, and where a
check says so, where its tolerance comes from), its plots, and how long it took; at the top the
version, backend, device, date and the command of the whole run, and a summary table. The
README's validation table is the same summary (:func:`update_readme` writes it between the
``<!-- validation-table -->`` markers).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import os
import platform
import re
import shlex
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from . import VALIDATIONS, Check, load

README_BEGIN = "<!-- validation-table -->"
README_END = "<!-- /validation-table -->"


@dataclass
class Result:
    """One validation's outcome in a report."""

    name: str
    command: str
    summary: str
    checks: list[Check] = field(default_factory=list)
    plots: list[Path] = field(default_factory=list)
    seconds: float = 0.0
    error: str = ""  # a validation that could not run: its one-line reason (it counts as FAIL)

    @property
    def passed(self) -> bool:
        return not self.error and bool(self.checks) and all(c.passed for c in self.checks)

    @property
    def failed(self) -> int:
        return sum(not c.passed for c in self.checks)


def _options(parser: argparse.ArgumentParser) -> set[str]:
    return {s for a in parser._actions for s in a.option_strings}


def module_argv(name: str, parser: argparse.ArgumentParser, backend: str | None, full: bool,
                plot_dir: Path | None) -> list[str]:
    """The options ``validate all`` passes to one validation: its backend, ``--full`` and where
    its plot goes, each only where the validation takes it."""
    have = _options(parser)
    argv: list[str] = []
    if backend and "--backend" in have:
        argv += ["--backend", backend]
    if full and "--full" in have:
        argv.append("--full")
    if "--plot" in have:
        argv += ["--plot", str(plot_dir / f"{name}.png") if plot_dir is not None else "none"]
    return argv


def _summary(module) -> str:
    doc = (module.__doc__ or "").strip()
    first = " ".join(doc.split("\n\n", 1)[0].split())
    first = re.sub(r"^`{1,2}corpuscle validate [^`]*`{1,2}:\s*", "", first)  # the command has its own column
    return first[:1].upper() + first[1:]


def run_one(name: str, backend: str | None, full: bool, plot_dir: Path | None, log=sys.stderr) -> Result:
    """Run one validation as ``validate all`` does; an error it raises becomes the result's
    one-line reason (a FAIL), a Ctrl-C stops everything."""
    from ..cli.validate import options_parser

    module, parser = options_parser(name)
    argv = module_argv(name, parser, backend, full, plot_dir)
    command = shlex.join(["corpuscle", "validate", name, *argv])
    res = Result(name, command, _summary(module))
    print(f"validate all: {name} ({command})", file=log, flush=True)
    t0, started = time.perf_counter(), time.time() - 1.0
    try:
        opts = parser.parse_args(argv)
        with contextlib.redirect_stdout(log):  # the validation's own tables go to the log
            res.checks = list(module.run(opts))
    except KeyboardInterrupt:
        raise
    except SystemExit as exc:  # a parser's exit: an option this validation refused
        res.error = f"exited with status {exc.code}"
    except Exception as exc:  # noqa: BLE001 -- a report records a validation that broke, and goes on
        from .._viz_common import one_line

        res.error = f"{type(exc).__name__}: {one_line(exc)}"
    res.seconds = time.perf_counter() - t0
    if plot_dir is not None:  # this run's plots (one of an earlier report is older than the run)
        res.plots = sorted(p for p in plot_dir.glob(f"{name}*.png") if p.is_file() and p.stat().st_mtime >= started)
    return res


def run_all(names: list[str] | None = None, backend: str | None = None, full: bool = False,
            plot_dir: Path | None = None, log=sys.stderr) -> list[Result]:
    """Every validation (or those named), in the registry's order."""
    return [run_one(n, backend, full, plot_dir, log) for n in (names or list(VALIDATIONS))]


def environment(backend: str | None) -> dict[str, str]:
    """What ran it: version, backend, device, machine, date."""
    from .. import __version__

    env = {"version": __version__, "backend": backend or "each validation's default",
           "date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
           "machine": f"{platform.system()} {platform.machine()}, {os.cpu_count()} CPU threads",
           "python": platform.python_version()}
    try:
        from .. import _core

        info = dict(_core.build_info())
        gpus = info.get("gpus") or []
        if backend == "cuda" and gpus:
            env["device"] = ", ".join(str(g.get("name")) for g in gpus[:1])
    except ImportError:
        pass
    return env


def _fmt(x: float) -> str:
    return "NaN" if x != x else f"{x:.6g}"


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _closest(checks: list[Check]) -> str:
    """The check closest to its tolerance (of those with one), as a fraction of it."""
    scored = [(abs(c.measured - c.reference) / c.tolerance, c) for c in checks
              if c.tolerance > 0 and c.measured == c.measured and c.reference == c.reference]
    if not scored:
        return ""
    f, c = max(scored, key=lambda x: x[0])
    return f"; closest to its tolerance: {_cell(c.name)} ({f:.0%} of it)"


def summary_rows(results: list[Result]) -> list[str]:
    """The summary table (Markdown lines): one row a validation."""
    rows = ["| validation | what it checks | command | result |", "|---|---|---|---|"]
    for r in results:
        if r.error:
            verdict = f"FAIL: could not run ({_cell(r.error)})"
        elif r.passed:
            verdict = f"PASS: {len(r.checks)} of {len(r.checks)} checks{_closest(r.checks)}"
        else:
            verdict = f"FAIL: {r.failed} of {len(r.checks)} checks"
        rows.append(f"| {r.name} | {_cell(r.summary)} | `{r.command}` | {verdict} |")
    return rows


def markdown(results: list[Result], env: dict[str, str], command: str, base: Path) -> str:
    """The report: a header, the summary table, then each validation's checks and plots (their
    paths relative to ``base``, the report's folder)."""
    ok = all(r.passed for r in results) and bool(results)
    lines = ["# Validation report", "",
             f"`{command}`: **{'PASS' if ok else 'FAIL'}** "
             f"({sum(r.passed for r in results)} of {len(results)} validations pass).", ""]
    lines += [f"- {k}: {v}" for k, v in env.items()]
    lines += ["", "## Summary", "", *summary_rows(results), ""]
    for r in results:
        lines += [f"## {r.name}", "", r.summary, "", f"Command: `{r.command}` ({r.seconds:.1f} s).", ""]
        if r.error:
            lines += [f"**Could not run**: {_cell(r.error)}", ""]
        if r.checks:
            lines += ["| check | measured | reference | difference | tolerance | |", "|---|---:|---:|---:|---:|---|"]
            for c in r.checks:
                tol = _fmt(c.tolerance) + (f" {c.unit}" if c.unit else "")
                lines.append(f"| {_cell(c.name)} | {_fmt(c.measured)} | {_fmt(c.reference)} | "
                             f"{_fmt(c.measured - c.reference)} | {tol} | {'PASS' if c.passed else '**FAIL**'} |")
            notes = [(c.name, c.detail) for c in r.checks if c.detail]
            if notes:
                lines.append("")
                lines += [f"- {_cell(n)}: {_cell(d)}" for n, d in notes]
            lines.append("")
        for p in r.plots:
            rel = os.path.relpath(p, base)
            lines += [f"![{r.name}]({Path(rel).as_posix()})", ""]
    return "\n".join(lines).rstrip() + "\n"


def update_readme(path: Path, results: list[Result]) -> None:
    """Replace the table between the README's validation-table markers by this run's summary."""
    text = path.read_text(encoding="utf-8")
    i, j = text.find(README_BEGIN), text.find(README_END)
    if i < 0 or j < i:
        raise ValueError(f"--readme {path}: no {README_BEGIN} ... {README_END} block")
    block = "\n".join([README_BEGIN, *summary_rows(results), README_END])
    text = text[:i] + block + text[j + len(README_END):]
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)
