"""The ``corpuscle`` command line.

Each subcommand is a module of this package (``scenes``, ``info``, ``run``, ``view``,
``bench``, ``validate``, ``polar``, ``render``, ``plot``, ``export``) that registers a
:class:`Command` in the table :data:`COMMANDS` with :func:`register`; a new one is a module
added to :data:`COMMAND_MODULES`. The options they share are in ``_options.py``. Bad input
(scene errors, bad options, unusable backends, unwritable files) ends with exit code 2 and
one line ``corpuscle: error: ...`` on stderr, never a traceback. Scenes are loaded and
validated before the compiled core is imported, so those errors need no build.

Exit codes: 0 success, 2 bad input, 3 run stopped by a health check, 4 the output could not
be written (disk full ...; the frames written so far are kept), 130 interrupted (Ctrl-C;
SIGTERM and SIGHUP stop a command the same way, exit 143 and 129: 128 + the signal), 141
stdout closed (broken pipe).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from typing import Sequence

from ..scene import SceneError
from ._common import install_stop_signals, interrupt_exit_code, signal_name
from ._options import (BACKENDS, COMMANDS, EXIT_INTERRUPTED, EXIT_OK, EXIT_STOPPED, EXIT_USAGE, PROG, Command,
                       Parser, UsageError, err, one_line, register)

__all__ = ["main", "build_parser", "COMMANDS", "Command", "register", "UsageError", "PROG", "BACKENDS",
           "EXIT_OK", "EXIT_USAGE", "EXIT_STOPPED", "EXIT_INTERRUPTED"]

# the subcommands, in the order --help lists them (each module registers its command when
# imported; render, plot and export import their heavy libraries only when they run)
COMMAND_MODULES = ("scenes", "info", "run", "view", "bench", "validate", "polar", "render", "plot", "export")
for _name in COMMAND_MODULES:
    importlib.import_module(f"{__name__}.{_name}")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every registered subcommand."""
    from .. import __version__

    parser = Parser(
        prog=PROG, description="corpuscle: GPU particle simulator (SPH fluids, DEM, rigid bodies)"
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=Parser)
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
    install_stop_signals()  # SIGTERM and SIGHUP stop a command as Ctrl-C does
    if getattr(args, "force", False):  # outputs of another kind may be replaced
        from .._viz_common import FORCE_OUTPUT

        FORCE_OUTPUT.set(True)
    from .. import _mpi

    if _mpi.launched_size() > 1:
        return _main_ranks(args)
    return _main_one(args)


def _main_one(args: argparse.Namespace) -> int:
    try:
        return int(args._handler(args) or 0)
    except KeyboardInterrupt as exc:
        # Ctrl-C (SIGTERM, SIGHUP) outside a run's loop (which reports its own): no traceback
        by = signal_name(exc)
        err("interrupted" + (f" by {by}" if by else ""))
        return interrupt_exit_code(exc)
    except BrokenPipeError:
        # stdout was closed early (`corpuscle bench ... | head`): stop quietly, as Unix tools do
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 141
    except Exception as exc:
        # bad input: one line, exit 2; CORPUSCLE_DEBUG=1 shows the traceback
        if not isinstance(exc, _user_errors()) or os.environ.get("CORPUSCLE_DEBUG"):
            raise
        err(f"error: {one_line(exc)}")
        return int(getattr(exc, "exit_code", EXIT_USAGE))


# the commands that run over several MPI ranks (docs/distributed.md); the others refuse them
RANK_COMMANDS = ("run", "polar", "info")


def _main_ranks(args: argparse.Namespace) -> int:
    """One of several ranks under ``mpiexec``: bad input is agreed on every rank and reported
    once (by rank 0); after that an error, an interrupt or a dead rank on any rank stops them all
    with one line naming the rank (MPI_Abort), never a hang."""
    from .. import _mpi

    rank = _mpi.launched_rank()
    try:
        comm = _mpi.world()
    except _mpi.MpiUnavailable as exc:
        if rank == 0:
            err(f"error: {one_line(exc)}")
        return EXIT_USAGE
    if comm is None:  # MPI's world is one rank after all: the command as without a launcher
        return _main_one(args)
    if args.command not in RANK_COMMANDS:
        if comm.Get_rank() == 0:
            err(f"error: `{PROG} {args.command}` runs on one rank, not {comm.Get_size()}: under mpiexec only "
                f"{', '.join(RANK_COMMANDS)} spread over ranks (docs/distributed.md)")
        return EXIT_USAGE
    try:
        return int(args._handler(args) or 0)
    except _mpi.RankInputError as exc:
        if not exc.quiet:
            err(f"error: {one_line(exc)}")
        return exc.exit_code
    except KeyboardInterrupt as exc:
        by = signal_name(exc)
        _mpi.abort(comm, "interrupted" + (f" by {by}" if by else ""), interrupt_exit_code(exc))
    except BrokenPipeError:
        _mpi.abort(comm, "stdout closed", 141)
    except Exception as exc:  # noqa: BLE001 - every rank must stop, not wait for this one
        if not _mpi.in_collective() and isinstance(exc, _user_errors()):
            # before the ranks agreed: the check is the same on every rank, so each reports its
            # own (rank 0 prints) and none waits for another
            if comm.Get_rank() == 0:
                err(f"error: {one_line(exc)}")
            return int(getattr(exc, "exit_code", EXIT_USAGE))
        from .._errors import UnstableRunError

        code = EXIT_STOPPED if isinstance(exc, UnstableRunError) else int(getattr(exc, "exit_code", 1)) or 1
        _mpi.abort(comm, f"{type(exc).__name__}: {one_line(exc)}" if not isinstance(exc, _user_errors())
                   else one_line(exc), code)
    return 1
