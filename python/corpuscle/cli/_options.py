"""What every command shares: the command table (:class:`Command`, :func:`register`), the
exit codes, :class:`UsageError` and the parsing of options into one-line errors, the scene
with ``--set`` and the dedicated options applied, and the engine and live-view options."""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import math
import re
import sys
from dataclasses import dataclass
from typing import Callable

from .. import kinds as _kinds
from ..scene import SceneError, load_scene, parse_set

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


def one_line(text: object) -> str:
    """Collapse a message onto one line."""
    return " ".join(str(text).split()) or "unknown error"


def err(message: str) -> None:
    print(f"{PROG}: {message}", file=sys.stderr)


def int_option(name: str, text: str | None, minimum: int | None = None) -> int | None:
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


def float_option(name: str, text: str | None) -> float | None:
    if text is None:
        return None
    try:
        value = float(text.strip())
    except ValueError:
        raise UsageError(f"{name} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise UsageError(f"{name} must be a finite number, got {text!r}")
    return value


def overrides(args: argparse.Namespace, options: dict[str, str]) -> dict[str, object]:
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


def load_with_options(args: argparse.Namespace, options: dict[str, str]):
    """The scene with ``--set`` and the dedicated options applied; ``--particles`` sets the
    kind's particle key (an error for a kind without one)."""
    ovr = overrides(args, options)  # --set is parsed before the scene is read
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
        raise named_by_option(exc, args, options) from None


def named_by_option(exc: SceneError, args: argparse.Namespace, options: dict[str, str]) -> SceneError:
    """A scene error about a key that a dedicated option set (``--time`` sets
    ``run.end_time``) says which option it was: the user never typed the key."""
    given = {key: f"--{attr}" for attr, key in options.items() if getattr(args, attr, None) is not None}
    for key, option in given.items():
        if str(exc).startswith(f"{key} "):
            value = getattr(args, option[2:])
            return SceneError(f"{option} {value:g}: {exc}" if isinstance(value, float) else f"{option} {value}: {exc}")
    return exc


def particles_help() -> str:
    keys = ", ".join(f"{k.particle_key} for {name}" for name, k in _kinds.registry().items() if k.particle_key)
    return f"number of particles (sets the scene kind's particle key: {keys or 'none'})"


def safe_filename(name: str) -> str:
    """A scene name made safe to use as a file name."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "run"


def import_core_module(module: str):
    """Import a module that needs the compiled core, as a one-line error if missing."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise UsageError(
            f"the compiled core is not available ({one_line(exc)}); build it with `pip install .`"
        ) from None


def progress_enabled(args: argparse.Namespace) -> bool:
    """A progress bar only on a terminal, and never with --no-progress or --json."""
    if getattr(args, "no_progress", False) or getattr(args, "json", None):
        return False
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def fmt_rate(x: float) -> str:
    """Rates: plain below a million, scientific above."""
    if not math.isfinite(x):
        return "inf"
    return f"{x:,.1f}" if x < 1e6 else f"{x:.3e}"

def add_engine_options(p: argparse.ArgumentParser) -> None:
    """--neighbors and --device: how the engine runs a scene (not part of the scene)."""
    p.add_argument("--neighbors", metavar="INDEX",
                   help="neighbour search: lists (cells on rebuilds, lists with a skin reused in between; the "
                        "8-ball's default), grid (the cells every step; the SPH box's default), compact (the SPH "
                        "box's cells in chunks of <= 32 through shared memory) or allpairs (every pair: O(N^2), a "
                        "reference); `corpuscle scenes --keys` lists each kind's")
    p.add_argument("--device", metavar="N", default="0", help="CUDA device number (default: 0)")

def add_live_arguments(p: argparse.ArgumentParser, what: str = "") -> None:
    p.add_argument("--port", metavar="P", help=f"{what}the viewer's port (default: 8765; 0 picks a free one)")
    p.add_argument("--host", metavar="H",
                   help=f"{what}the address to listen on (default: 127.0.0.1, this machine only; any other "
                        "needs the random token printed with the URL)")


def live_options(args: argparse.Namespace, needs_live: bool) -> None:
    """Check --port and --host (and that the viewer's server library is installed)."""
    if needs_live and not getattr(args, "live", False):
        for option in ("port", "host"):
            if getattr(args, option, None) is not None:
                raise UsageError(f"--{option} is an option of the live view; add --live")
        return
    port = int_option("--port", args.port if args.port is not None else "8765", minimum=0)
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
        raise UsageError(f"--host {host}: not an address to listen on ({one_line(exc)})") from None
    args.host = host
    if importlib.util.find_spec("aiohttp") is None:
        raise UsageError('the live viewer needs aiohttp: pip install "corpuscle[viewer]" (or ".[viewer]" '
                         'from a checkout)')


def live_url_message(server, what: str) -> str:
    text = f"{what} at {server.url} (Ctrl-C stops)"
    from ..live.server import is_local

    if server.token and not is_local(getattr(server, "host", "127.0.0.1")):
        text += "; the token in the URL is required: this address may be reachable from other machines"
    return text



# a value that begins as a negative number does (-10:20:2, -30,20, -3:, -.5, -1e3): argparse's
# own pattern takes only -12 and -1.5 as values, anything else after '-' as an option name, so
# `--aoa -10:20:2` failed with "expected one argument" (no option name starts with '-' and a digit)
NEGATIVE_VALUE = re.compile(r"^-\.?\d")


class Parser(argparse.ArgumentParser):
    """argparse with usage errors on one line: the message and where to find the usage; a
    value that begins as a negative number does is a value, for every option
    (:data:`NEGATIVE_VALUE`)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_VALUE

    def error(self, message: str):  # noqa: D401 - argparse's hook
        self.exit(EXIT_USAGE, f"{PROG}: error: {one_line(message)} (see `{self.prog} --help`)\n")
