"""``corpuscle validate NAME``: a validation case against its reference (PASS/FAIL)."""

from __future__ import annotations

import argparse
import contextlib
import sys

from .. import _json
from ._options import EXIT_OK, PROG, Command, Parser, register


def _configure_validate(p: argparse.ArgumentParser) -> None:
    from .. import validation

    p.add_argument("name", metavar="NAME",
                   help=f"what to validate: {', '.join(validation.VALIDATIONS)}, or all (every one, and a report)")
    p.add_argument("--json", action="store_true", help="print the checks as JSON (after the table)")
    p.add_argument("--force", action="store_true", help="replace an existing output file of another kind than its name says")
    # each validation's own options; those of the one named are parsed in _cmd_validate
    p.add_argument("options", nargs=argparse.REMAINDER, help="the validation's options (NAME --help lists them)")


def options_parser(name: str):
    """(the validation module, the parser of its own options) for ``validate NAME`` (``all``: no
    module, the options of ``validate all``)."""
    from .. import validation

    if name == "all":
        return None, all_parser()
    module = validation.load(name)  # unknown name: ValueError, one line, exit 2
    sub = Parser(prog=f"{PROG} validate {name}", description=(module.__doc__ or "").strip().splitlines()[0])
    sub.add_argument("--json", action="store_true", help="print the checks as JSON (and nothing else) on stdout")
    sub.add_argument("--force", action="store_true", help="replace an existing output file of another kind than "
                                                          "its name says")
    module.add_arguments(sub)
    return module, sub


def all_parser() -> Parser:
    """The options of ``validate all``."""
    from .. import validation

    sub = Parser(prog=f"{PROG} validate all",
                 description="run every validation and write one report (Markdown, with the plots beside it)")
    sub.add_argument("--backend", choices=("serial", "cpu", "cuda"), default=None,
                     help="compute backend of every validation (default: each one's own)")
    sub.add_argument("--full", action="store_true", help="each validation's --full (the GPU sizes)")
    sub.add_argument("--only", metavar="NAMES", default=None,
                     help=f"a comma-separated subset of {','.join(validation.VALIDATIONS)}")
    sub.add_argument("--report", metavar="FILE.md", default="validation-report.md",
                     help="where the report goes (default: validation-report.md); its plots go in FILE_plots/ "
                          "beside it")
    sub.add_argument("--readme", metavar="README.md", default=None,
                     help="also write the summary table between the file's <!-- validation-table --> markers")
    sub.add_argument("--json", action="store_true", help="print the results as JSON (and nothing else) on stdout")
    sub.add_argument("--force", action="store_true", help="replace an existing report of another kind than its "
                                                          "name says")
    return sub


def _cmd_validate_all(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .. import validation
    from .._viz_common import FORCE_OUTPUT, check_file_output, prepare_dir
    from ..validation import report

    opts = all_parser().parse_args(args.options)
    if opts.force or args.force:
        FORCE_OUTPUT.set(True)
    names = list(validation.VALIDATIONS)
    if opts.only is not None:
        names = [n.strip() for n in opts.only.split(",") if n.strip()]
        bad = [n for n in names if n not in validation.VALIDATIONS]
        if bad or not names:
            raise ValueError(f"--only must name validations among {', '.join(validation.VALIDATIONS)}, "
                             f"got {opts.only!r}")
    out = check_file_output(opts.report, ValueError)
    readme = Path(opts.readme) if opts.readme else None
    if readme is not None:
        text = readme.read_text(encoding="utf-8") if readme.is_file() else ""
        if report.README_BEGIN not in text or report.README_END not in text:
            raise ValueError(f"--readme {opts.readme}: no {report.README_BEGIN} ... {report.README_END} block")
    plot_dir = prepare_dir(out.with_name(out.stem + "_plots"), ValueError)
    command = "corpuscle validate all" + ("" if not args.options else " " + " ".join(args.options))
    results = report.run_all(names, opts.backend, opts.full, plot_dir)
    text = report.markdown(results, report.environment(opts.backend), command, out.parent)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(out)
    if readme is not None:
        report.update_readme(readme, results)
    ok = all(r.passed for r in results) and bool(results)
    if args.json or opts.json:
        print(_json.dumps([{"validation": r.name, "command": r.command, "passed": r.passed, "error": r.error,
                            "seconds": r.seconds, "checks": validation.as_dicts(r.checks),
                            "plots": [str(p) for p in r.plots]} for r in results], indent=2))
        return EXIT_OK if ok else 1
    print()
    for r in results:
        verdict = "PASS" if r.passed else "FAIL"
        what = f"could not run: {r.error}" if r.error else f"{len(r.checks) - r.failed} of {len(r.checks)} checks pass"
        print(f"{r.name:<16} {verdict}  {what} ({r.seconds:.0f} s)")
    print(f"report: {out}")
    print("PASS" if ok else "FAIL")
    return EXIT_OK if ok else 1


def _cmd_validate(args: argparse.Namespace) -> int:
    from .. import validation

    if args.name == "all":
        return _cmd_validate_all(args)
    module, sub = options_parser(args.name)
    opts = sub.parse_args(args.options)  # bad options exit 2 with one line
    if opts.force:
        from .._viz_common import FORCE_OUTPUT

        FORCE_OUTPUT.set(True)
    if args.json or opts.json:  # the JSON alone on stdout: the runs' own tables go to stderr
        with contextlib.redirect_stdout(sys.stderr):
            checks = module.run(opts)
    else:
        checks = module.run(opts)
    ok = all(c.passed for c in checks) and bool(checks)
    if args.json or opts.json:
        print(_json.dumps(validation.as_dicts(checks), indent=2))
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
