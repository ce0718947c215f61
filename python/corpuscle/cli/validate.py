"""``corpuscle validate NAME``: a validation case against its reference (PASS/FAIL)."""

from __future__ import annotations

import argparse
import contextlib
import sys

from .. import _json
from ._options import EXIT_OK, PROG, Command, Parser, register


def _configure_validate(p: argparse.ArgumentParser) -> None:
    from .. import validation

    p.add_argument("name", metavar="NAME", help=f"what to validate: {', '.join(validation.VALIDATIONS)}")
    p.add_argument("--json", action="store_true", help="print the checks as JSON (after the table)")
    p.add_argument("--force", action="store_true", help="replace an existing output file of another kind than its name says")
    # each validation's own options; those of the one named are parsed in _cmd_validate
    p.add_argument("options", nargs=argparse.REMAINDER, help="the validation's options (NAME --help lists them)")


def options_parser(name: str):
    """(the validation module, the parser of its own options) for ``validate NAME``."""
    from .. import validation

    module = validation.load(name)  # unknown name: ValueError, one line, exit 2
    sub = Parser(prog=f"{PROG} validate {name}", description=(module.__doc__ or "").strip().splitlines()[0])
    sub.add_argument("--json", action="store_true", help="print the checks as JSON (and nothing else) on stdout")
    sub.add_argument("--force", action="store_true", help="replace an existing output file of another kind than "
                                                          "its name says")
    module.add_arguments(sub)
    return module, sub


def _cmd_validate(args: argparse.Namespace) -> int:
    from .. import validation

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
