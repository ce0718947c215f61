"""Pieces the run-like commands (run, bench) share: the record of what ran where (time,
command line, build, device), the stop signals (Ctrl-C, SIGTERM, SIGHUP) and Ctrl-C during a
long initialisation, the lists index's relistings."""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import importlib
import os
import platform
import shlex
import signal
import sys
import threading
from typing import Any

from ._options import EXIT_INTERRUPTED, PROG, err


# what `timeout`, `docker stop`, a batch scheduler or a closed terminal send: each stops a
# command as Ctrl-C does (the steps since the last frame saved, one line), exit 128 + signal
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


class Interrupted(KeyboardInterrupt):
    """A stop signal other than SIGINT, raised where Ctrl-C raises KeyboardInterrupt."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)


def interrupt_exit_code(exc: BaseException | None = None) -> int:
    """128 + the signal number: 130 for Ctrl-C (and a bare KeyboardInterrupt), 143 for
    SIGTERM, 129 for SIGHUP."""
    signum = getattr(exc, "signum", None)
    return EXIT_INTERRUPTED if signum is None else 128 + signum


def signal_name(exc: BaseException | None) -> str | None:
    """``SIGTERM`` / ``SIGHUP`` for an :class:`Interrupted`, None for Ctrl-C."""
    signum = getattr(exc, "signum", None)
    return None if signum is None else signal.Signals(signum).name


def _raise_interrupted(signum, _frame):
    raise Interrupted(signum)


def install_stop_signals() -> None:
    """SIGTERM and SIGHUP raise :class:`Interrupted` (a KeyboardInterrupt), so every place
    that handles Ctrl-C handles them too. A signal the parent set to be ignored (``nohup``)
    stays ignored; only the main thread can do this."""
    if threading.current_thread() is not threading.main_thread():
        return
    for signum in STOP_SIGNALS:
        if signum == signal.SIGINT:
            continue
        try:
            if signal.getsignal(signum) in (signal.SIG_IGN, None):
                continue
            signal.signal(signum, _raise_interrupted)
        except (OSError, ValueError):
            pass


def now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()


def command_line(args: argparse.Namespace) -> str:
    return shlex.join([PROG, *getattr(args, "_argv", [])])


def build_info() -> dict[str, Any] | None:
    """``_core.build_info()``, or None when the core is not built."""
    try:
        core = importlib.import_module("corpuscle._core")
    except ImportError:
        return None
    return dict(core.build_info())


def cpu_name() -> str:
    """The CPU model, from /proc/cpuinfo where there is one."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def device_name(backend: str, info: dict[str, Any] | None, device: int = 0) -> str:
    """A human-readable device for benchmark records."""
    if backend == "cuda" and info and info.get("gpus"):
        gpus = info["gpus"]
        gpu = gpus[device] if 0 <= device < len(gpus) else gpus[0]
        return f"{gpu.get('name', 'GPU')} (compute {gpu.get('compute_capability', '?')})"
    cpu = f"{cpu_name()}, {os.cpu_count() or '?'} logical cores"
    if backend == "cpu" and info:
        return f"{cpu}, {info.get('omp_threads', '?')} OpenMP threads"
    return cpu


@contextlib.contextmanager
def interruptible_init(what: str):
    """Ctrl-C (or SIGTERM, SIGHUP) during initialisation exits at once (128 + the signal),
    with one line.

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
            stop = next((signum for signum in STOP_SIGNALS if signum in got), None)
            if state["done"] or stop is None:
                return
            by = "" if stop == signal.SIGINT else f" by {signal.Signals(stop).name}"
            err(f"interrupted{by} while {what}")
            sys.stderr.flush()
            os._exit(128 + stop)

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

def relistings(sim) -> int | None:
    """The `lists` index's relistings so far (None for any other index or scene)."""
    if getattr(sim, "neighbors", None) != "lists" or not hasattr(sim, "state"):
        return None
    state = sim.state()
    return int(state["rebuilds"]) if "rebuilds" in state else None

