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
import zlib
from pathlib import Path

import numpy as np
import pytest

import corpuscle
from corpuscle.io import FrameStreamError, FrameWriter
from cli_script import assert_one_line_error, corpuscle as run_cli, listing, script

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


# --- concurrent writers: one at a time, the second told who holds the file ----------------

def test_a_second_writer_of_a_file_is_refused_naming_the_holder(tmp_path):
    path = tmp_path / "w.cps"
    first = FrameWriter(path, {"scene": "first"})
    try:
        first.write_frame(0, 0.0, 0.1, {"position": np.zeros((10, 3), np.float32)})
        for second in (lambda: FrameWriter(path, {"scene": "second"}), lambda: FrameWriter.append(path)):
            with pytest.raises(OSError, match=rf"w\.cps: is being written by process {os.getpid()}\b"):
                second()
        first.write_frame(1, 0.1, 0.1, {"position": np.ones((10, 3), np.float32)})
    finally:
        first.close()
    with corpuscle.open(path) as run:  # the first writer's frames, whole and alone
        assert run.header["scene"] == "first" and list(run.steps) == [0, 1]
        run.verify()
    FrameWriter(path, {"scene": "after"}).close()  # closed: the file is free again
    assert listing(tmp_path) == {"w.cps"}  # and no temporary file is left beside it


@needs_core
@pytest.mark.parametrize("second", [
    pytest.param(("run", "magic8ball", "--backend", "cpu", "--particles", "300", "--steps", "10"), id="run"),
    pytest.param(("run", "--resume"), id="resume"),
])
def test_a_second_run_of_the_same_out_is_refused_while_the_first_writes(tmp_path, second):
    out = tmp_path / "c.cps"
    first = _long_run(out, "--checkpoint-every", "100000")
    try:
        assert first.poll() is None, first.communicate()
        argv = (*second, str(out)) if second[-1] == "--resume" else (*second, "--out", str(out))
        p = run_cli(*argv)
        assert_one_line_error(p, f"{out}: is being written by process {first.pid}")
    finally:
        first.send_signal(signal.SIGINT)
        _, stderr = first.communicate(timeout=30)
    assert first.returncode == 130, stderr
    with corpuscle.open(out) as run:
        assert len(run) == 2 and run.header["particles"] == 300
        run.verify()


# --- files from elsewhere: only a frame stream is replaced, and never under a reader -------

FOREIGN = {
    "notes.txt": b"my notes: do not lose these\n",
    "naca.dat": b"NACA 0012\n1.0 0.00126\n0.5 0.0\n0.0 0.0\n0.5 -0.0\n1.0 -0.00126\n",
    "scene.toml": b'kind = "magic8ball"\n[fluid]\nparticles = 300\n',
    "picture.png": b"\x89PNG\r\n\x1a\n" + bytes(100),
    "almost.cps": b"\x89CPS\r\n",  # a prefix of the magic is not a frame stream
}


@pytest.mark.parametrize("name", FOREIGN)
def test_the_api_never_replaces_a_file_that_is_not_a_frame_stream(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(FOREIGN[name])
    with pytest.raises(FileExistsError, match=rf"{name}: exists and is not a corpuscle frame stream"):
        FrameWriter(path, {"scene": "t"})
    assert path.read_bytes() == FOREIGN[name] and listing(tmp_path) == {name}
    FrameWriter(path, {"scene": "t"}, force=True).close()
    with corpuscle.open(path) as run:
        assert run.header == {"scene": "t"}


@needs_core
@pytest.mark.parametrize("name", ["notes.txt", "naca.dat", "scene.toml"])
def test_run_never_replaces_a_file_that_is_not_a_frame_stream_without_force(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(FOREIGN[name])
    argv = (*RUN, "--steps", "5", "--every", "5", "--out", str(path))
    assert_one_line_error(run_cli(*argv), f"--out {path}: exists and is not a corpuscle frame stream")
    assert path.read_bytes() == FOREIGN[name]
    p = run_cli(*argv, "--force")
    assert p.returncode == 0, p.stderr
    with corpuscle.open(path) as run:
        assert list(run.steps) == [0, 5]


_READER = """
    import sys, zlib
    import corpuscle
    from corpuscle.io import FrameStreamError
    run = corpuscle.open(sys.argv[1])
    print(len(run), flush=True)
    sys.stdin.readline()  # meanwhile the file is rewritten or cut
    try:
        crc = [zlib.crc32(f["position"].tobytes()) for f in run]
        run.verify()
        print(crc, flush=True)
    except FrameStreamError as exc:
        print("error:", exc, flush=True)
"""


def _rewrite(path):
    _write_run(path, frames=1, n=10, seed=1)


def _resume_cut(path):
    with FrameWriter.append(path, keep=1) as w:
        w.write_frame(1, 0.1, 0.1, {"position": np.zeros((10, 3), np.float32)})


@pytest.mark.parametrize("change", [_rewrite, _resume_cut], ids=["a new run", "a resume that cuts frames"])
def test_a_reader_keeps_the_run_it_opened_when_a_writer_replaces_it(tmp_path, change):
    path = tmp_path / "r.cps"
    _write_run(path)
    with corpuscle.open(path) as run:
        want = [zlib.crc32(f["position"].tobytes()) for f in run]
    reader = _python(_READER, path)
    assert reader.stdout.readline().strip() == "3", reader.communicate()
    change(path)  # used to truncate the file under the reader's map: SIGBUS
    out, err = reader.communicate("go\n", timeout=60)
    assert reader.returncode == 0, (reader.returncode, err)
    assert out.strip() == str(want)
    with corpuscle.open(path) as run:  # and the file holds the new run
        assert len(run) in (1, 2) and run[0]["position"].shape[0] in (10, 5000)


def test_a_file_cut_short_under_a_reader_is_one_line_not_a_signal(tmp_path):
    path = tmp_path / "t.cps"
    _write_run(path)
    reader = _python(_READER, path)
    assert reader.stdout.readline().strip() == "3", reader.communicate()
    os.truncate(path, 4096)  # another program (not corpuscle's writer) cuts it in place
    out, err = reader.communicate("go\n", timeout=60)
    assert reader.returncode == 0, (reader.returncode, err)
    lines = out.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {path}: the file was cut to 4096 bytes"), out


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec") / "rec.cps"
    p = run_cli(*RUN, "--steps", "10", "--every", "5", "--out", str(out))
    assert p.returncode == 0, p.stderr
    return out


OTHER_OUTPUTS = [  # (argv with {run} and {out}, the output's name): each writes a user-named file
    (("render", "{run}", "-o", "{out}"), "movie.png"),
    (("render", "{run}", "-o", "{out}"), "movie.mp4"),
    (("plot", "{run}", "-o", "{out}"), "figure.svg"),
    (("plot", "{run}", "-o", "{out}"), "figure.pdf"),
    (("bench", "magic8ball", "--backend", "cpu", "--particles", "300", "--steps", "1", "--json", "{out}"), "b.json"),
]


@needs_core
@pytest.mark.parametrize("argv,name", OTHER_OUTPUTS, ids=[f"{a[0]}-{n}" for a, n in OTHER_OUTPUTS])
def test_no_command_replaces_a_file_of_another_kind_without_force(tmp_path, recorded, argv, name):
    path = tmp_path / name
    path.write_bytes(FOREIGN["notes.txt"])
    args = [a.format(run=recorded, out=path) for a in argv]
    p = run_cli(*args)
    assert_one_line_error(p, f"cannot write {path}: it exists and is not a {path.suffix} output")
    assert path.read_bytes() == FOREIGN["notes.txt"]
    if argv[0] == "plot":
        p = run_cli(*args, "--force")
        assert p.returncode == 0, p.stderr
        assert path.read_bytes() != FOREIGN["notes.txt"]
