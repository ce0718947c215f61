"""What a neighbour (another run, another program, the machine's own signals) can do to a
recorded run: every case here lost data before its fix.

A table of hostile cases, each through the real console script (tests/cli_script.py) or the
API, as a user meets them:

- concurrent writers: a second writer of a file being written is refused, naming the holder;
- files from elsewhere: an output that is not a frame stream is never replaced without
  ``--force``; a file rewritten (or cut short) under a reader fails with one line, never a
  signal;
- signals: SIGTERM and SIGHUP stop a command as Ctrl-C does, keeping every step.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

import corpuscle
from corpuscle.io import FrameStreamError, FrameWriter
from cli_script import assert_one_line_error, corpuscle as run_cli, script

needs_core = pytest.mark.skipif(not any(Path(corpuscle.__file__).parent.glob("_core*")),
                                reason="needs the compiled core")

RUN = ("run", "magic8ball", "--backend", "cpu", "--particles", "300", "--no-progress")


def _long_run(out: Path, *extra: str) -> subprocess.Popen:
    """A run that records frame 0 and then steps for a long time; returned once frame 0 is on disk."""
    proc = subprocess.Popen([script(), *RUN, "--time", "100", "--every", "100000", "--out", str(out), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not (out.exists() and out.stat().st_size > 4096):
        if proc.poll() is not None:
            break
        time.sleep(0.02)
    return proc


def _write_run(path: Path, frames: int = 3, n: int = 5000, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    with FrameWriter(path, {"scene": "t", "seed": seed}) as w:
        for i in range(frames):
            w.write_frame(i, 0.1 * i, 0.1, {"position": rng.random((n, 3), dtype=np.float32)})


def _python(code: str, *args) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(code), *map(str, args)], env=env,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


# --- signals: SIGTERM and SIGHUP are Ctrl-C ------------------------------------------------

@needs_core
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_a_stop_signal_keeps_the_steps_since_the_last_frame(tmp_path, sig):
    out = tmp_path / "s.cps"
    proc = _long_run(out)
    time.sleep(1.0)  # inside the first chunk of 100,000 steps
    t = time.monotonic()
    proc.send_signal(sig)
    _, stderr = proc.communicate(timeout=30)
    assert time.monotonic() - t < 5
    assert proc.returncode == 128 + sig, stderr  # as a shell reports a command the signal ended
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("corpuscle: run interrupted at step"), stderr
    assert lines[0].endswith(f"({sig.name})")
    with corpuscle.open(out) as run:
        assert len(run) == 2 and run.steps[1] > 0  # frame 0 and the whole step it stopped at
        run.verify()


@needs_core
@pytest.mark.parametrize("argv", [
    ("validate", "hydrostatic", "--backend", "cpu", "--time", "100"),
])
def test_a_stop_signal_stops_any_command_with_one_line(argv):
    proc = subprocess.Popen([script(), *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(4.0)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 143, stderr
    assert "Traceback" not in stderr and stderr.strip().splitlines()[-1].startswith("corpuscle: "), stderr
    assert "SIGTERM" in stderr
