"""A small ``corpuscle``-style command line for render, plot and export alone.

For testing these subcommands before they are registered in ``corpuscle.cli``: same error
convention (``corpuscle: error: <one line>`` on stderr, exit code 2).
Run as ``python -m corpuscle._viz_cli render RUN -o OUT``.
"""

from __future__ import annotations

import argparse
import sys

from . import export, plot, render


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors and exit code 2."""

    def error(self, message: str):
        print(f"corpuscle: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    """The parser with the render, plot and export subcommands."""
    parser = _Parser(prog="corpuscle", description="corpuscle pictures, videos, plots and ParaView export")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in (render, plot, export):
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand; bad input prints one line and returns 2."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        return int(args.func(args) or 0)
    except SystemExit as exc:
        return int(exc.code or 0) if isinstance(exc.code, int) else 2
    except (ValueError, OSError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"corpuscle: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("corpuscle: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
