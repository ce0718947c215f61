"""Limits a hostile user reaches: nesting, file sizes, memory, counts, run times, Ctrl-C.

Each kind of limit is a table of cases (the command or call, its input, the one-line error
or the bound it must meet); the next feature adds its rows. Every case failed before its fix:
a traceback (RecursionError, MemoryError, IndexError, AttributeError), a hang, or minutes of
work before a limit that could be checked at once.

The command-line cases go through the installed ``corpuscle`` console script
(tests/cli_script.py): exit code 2, nothing on stdout, one line ``corpuscle: error: ...``."""
from __future__ import annotations

import pytest

from cli_script import assert_one_line_error, corpuscle as run_cli


def _nested(depth: int, leaf: str = "1", open_: str = "[", close: str = "]") -> str:
    return open_ * depth + leaf + close * depth


def _deep_list(depth: int):
    value: list = []
    for _ in range(depth):
        value = [value]
    return value


# --- nesting: one depth check for every scene file, --set value and override ---------------

DEEP = 3000  # past Python's recursion limit in tomllib, repr and deepcopy

NESTING_CLI = [  # (id, scene file text or None, extra args, words of the error)
    ("set-inline-table", None, ["--set", "x=" + _nested(DEEP, "1", "{a=", "}")], "--set x nests"),
    ("set-array", None, ["--set", "fluid.particles=" + _nested(DEEP)], "--set fluid.particles nests"),
    ("set-shake-array", None, ["--set", "shake=" + _nested(40)], "--set shake nests"),
    ("file-array", f'[scene]\nkind = "magic8ball"\n[fluid]\nx = {_nested(DEEP)}\n', [],
     "nests arrays or tables more than 32 levels deep"),
    ("file-shallow-enough-to-parse", f'[scene]\nkind = "magic8ball"\n[fluid]\nparticles = {_nested(100)}\n', [],
     "nests arrays or tables more than 32 levels deep"),
    ("file-inline-tables", f'[scene]\nkind = "magic8ball"\nfluid = {_nested(DEEP, "1", "{a=", "}")}\n', [],
     "nests arrays or tables more than 32 levels deep"),
]


@pytest.mark.parametrize("text, extra, words", [c[1:] for c in NESTING_CLI], ids=[c[0] for c in NESTING_CLI])
def test_deep_nesting_is_one_line(tmp_path, text, extra, words):
    scene = "magic8ball"
    if text is not None:
        scene = tmp_path / "deep.toml"
        scene.write_text(text, encoding="utf-8")
    proc = run_cli("run", scene, *extra, "--backend", "serial", "--steps", 1, "--out", tmp_path / "o.cps")
    assert_one_line_error(proc, words)
    assert not (tmp_path / "o.cps").exists()


@pytest.mark.parametrize("overrides, words", [
    ({"shake": _deep_list(DEEP)}, "shake nests"),
    ({"fluid.particles": _deep_list(DEEP)}, "fluid.particles nests"),
    ({"scene.name": {"a": _deep_list(40)}}, "scene.name nests"),
])
def test_deep_nesting_in_api_overrides_is_a_scene_error(overrides, words):
    from corpuscle.scene import SceneError, load_scene

    with pytest.raises(SceneError, match=words):
        load_scene("magic8ball", overrides)


def test_deep_nesting_in_a_scene_dict_is_a_scene_error():
    from corpuscle.scene import Scene, SceneError

    with pytest.raises(SceneError, match="the scene nests"):
        Scene.from_dict({"scene": {"kind": "magic8ball"}, "fluid": {"x": _deep_list(DEEP)}})


# --- files a user names: each kind read with its own bound ----------------------------------

def _ellipse_dat(path, n: int) -> None:
    import math

    rows = (f"{math.cos(2 * math.pi * i / n) / 2 + 0.5:.7f} {math.sin(2 * math.pi * i / n) * 0.05:.7f}\n"
            for i in range(n))
    path.write_text("ellipse\n" + "".join(rows), encoding="ascii")


def _fifo(path) -> None:
    import os

    os.mkfifo(path)


FILES_CLI = [  # (id, make the file at PATH or None for a fixed path, args with PATH in them, words)
    ("scene-dev-zero", None, ["run", "/dev/zero"], "/dev/zero: more than 1 MiB (a scene file holds at most 1 MiB"),
    ("scene-2MiB", lambda p: p.write_text('[scene]\nkind = "magic8ball"\n' + "#" * (2 << 20) + "\n"),
     ["run", "PATH"], "bytes (a scene file holds at most 1 MiB)"),
    ("scene-fifo-without-writer", _fifo, ["run", "PATH"], "scene.kind is missing"),  # not a hang
    ("airfoil-dev-zero", None, ["run", "wind-tunnel", "--set", "airfoil.shape=/dev/zero"],
     "airfoil.shape: /dev/zero: more than 1 MiB (an airfoil file holds at most 1 MiB"),
    ("airfoil-2MiB", lambda p: p.write_text("t\n" + "0 0\n" * (1 << 19)),
     ["run", "wind-tunnel", "--set", "airfoil.shape=PATH"], "bytes (an airfoil file holds at most 1 MiB)"),
]


@pytest.mark.parametrize("make, args, words", [c[1:] for c in FILES_CLI], ids=[c[0] for c in FILES_CLI])
def test_a_named_file_is_read_with_a_bound(tmp_path, make, args, words):
    path = tmp_path / "named"
    if make is not None:
        make(path)
    args = [str(a).replace("PATH", str(path)) for a in args]
    proc = run_cli(*args, "--backend", "serial", "--steps", 1, "--out", tmp_path / "o.cps", timeout=30)
    assert_one_line_error(proc, words.replace("PATH", str(path)))


def test_read_dat_is_bounded():
    from corpuscle import airfoils

    with pytest.raises(ValueError, match=r"^/dev/zero: more than 1 MiB \(an airfoil file holds at most 1 MiB"):
        airfoils.read_dat("/dev/zero")


# --- cheap limits first, naming the key ----------------------------------------------------

def test_airfoil_vertex_limit_comes_before_the_quadratic_check(tmp_path):
    import time

    dat = tmp_path / "ellipse.dat"
    _ellipse_dat(dat, 20_000)  # a valid section: its self-intersection test took 11 s
    t0 = time.perf_counter()
    proc = run_cli("run", "wind-tunnel", "--set", f"airfoil.shape={dat}", "--backend", "serial", "--steps", 1,
                   "--out", tmp_path / "o.cps", timeout=60)
    assert_one_line_error(proc, f"airfoil.shape: {dat}: 20,000 coordinate lines, at most 1024 vertices")
    assert time.perf_counter() - t0 < 5


def test_validate_polygon_vertex_limit_comes_first():
    import time

    import numpy as np
    from corpuscle import airfoils

    a = np.linspace(0, 2 * np.pi, 20_000, endpoint=False)
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"^wing: 20,000 vertices, at most 1024$"):
        airfoils.validate_polygon(np.c_[np.cos(a), np.sin(a)], "wing")
    assert time.perf_counter() - t0 < 1


# --- memory: the limits a process really has, not only the host's free memory ----------------

def _run_limited(args, rlimit_as: int, timeout: float = 60):
    """``corpuscle ARGS`` under ``ulimit -v`` (RLIMIT_AS, bytes)."""
    import os
    import resource
    import subprocess

    from cli_script import script

    env = {k: v for k, v in os.environ.items() if k not in ("CORPUSCLE_DEBUG", "PYTHONWARNINGS")}
    return subprocess.run([script(), *map(str, args)], env=env, capture_output=True, text=True, timeout=timeout,
                          preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (rlimit_as, rlimit_as)))


MEMORY_CLI = [  # (id, args, RLIMIT_AS, words): 2,000,000 particles need 8.5 GB
    ("run-ulimit-v", ["run", "magic8ball", "--particles", 2_000_000, "--steps", 1], 2 << 30,
     "fluid.particles=2000000"),
    ("bench-ulimit-v", ["bench", "magic8ball", "--particles", 2_000_000, "--steps", 1, "--repeats", 1], 2 << 30,
     "of memory this process may still use (the process's limit, ulimit -v)"),
]


@pytest.mark.parametrize("args, limit, words", [c[1:] for c in MEMORY_CLI], ids=[c[0] for c in MEMORY_CLI])
def test_a_run_over_the_process_memory_limit_is_refused(tmp_path, args, limit, words):
    # it took the host's free memory for its own: 100 s of placement, then std::bad_alloc
    proc = _run_limited([*args, "--backend", "serial", *(["--out", tmp_path / "o.cps"] if args[0] == "run" else [])],
                        limit)
    assert_one_line_error(proc, words)


def _write(path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="ascii")


CGROUPS = [  # (id, files under a fake root, expected (bytes, words) of process_limit, or None)
    ("v2", {"proc/self/cgroup": "0::/job/step\n", "sys/fs/cgroup/cgroup.controllers": "memory\n",
            "sys/fs/cgroup/job/step/memory.max": "max\n", "sys/fs/cgroup/job/step/memory.current": "100\n",
            "sys/fs/cgroup/job/memory.max": "1000000\n", "sys/fs/cgroup/job/memory.current": "400000\n"},
     (600000.0, "memory.max")),
    ("v2-namespace-root", {"proc/self/cgroup": "0::/elsewhere\n", "sys/fs/cgroup/cgroup.controllers": "memory\n",
                           "sys/fs/cgroup/memory.max": "5000\n", "sys/fs/cgroup/memory.current": "1000\n"},
     (4000.0, "memory.max")),
    ("v1", {"proc/self/cgroup": "4:memory:/docker/abc\n1:cpu:/\n",
            "sys/fs/cgroup/memory/docker/abc/memory.limit_in_bytes": "3000000\n",
            "sys/fs/cgroup/memory/docker/abc/memory.usage_in_bytes": "1000000\n"},
     (2000000.0, "memory.limit_in_bytes")),
    ("v1-unlimited", {"proc/self/cgroup": "4:memory:/\n",
                      "sys/fs/cgroup/memory/memory.limit_in_bytes": "9223372036854771712\n",
                      "sys/fs/cgroup/memory/memory.usage_in_bytes": "1000000\n"}, None),
    ("none", {}, None),
]


@pytest.mark.parametrize("files, expected", [c[1:] for c in CGROUPS], ids=[c[0] for c in CGROUPS])
def test_cgroup_memory_limits_are_read(tmp_path, monkeypatch, files, expected):
    from corpuscle import _memory_limits

    monkeypatch.setattr(_memory_limits, "_rlimits", lambda root: [])  # this process's own ulimits aside
    for rel, text in files.items():
        _write(tmp_path / rel, text)
    got = _memory_limits.process_limit(tmp_path)
    if expected is None:
        assert got is None
    else:
        assert got[0] == expected[0] and expected[1] in got[1]


# --- validations: refused before the run, bounded as `run` is ---------------------------------

VALIDATE_CLI = [  # (id, args, words): IndexError after the run, or a run that never ended
    ("hydrostatic-1-particle", ["hydrostatic", "--particles", 1], "--particles must be at least 32"),
    ("hydrostatic-4-particles", ["hydrostatic", "--particles", 4], "got 4"),
    ("hydrostatic-3d-4-particles", ["hydrostatic", "--dim", 3, "--particles", 4], "got 4"),
    ("hydrostatic-time-1e30", ["hydrostatic", "--time", "1e30"],
     "--time 1e30: run.end_time must be a number in (0, 1e7] s, got 1e30"),
    ("hydrostatic-3d-time-1e30", ["hydrostatic", "--dim", 3, "--time", "1e30"], "--time 1e30: run.end_time"),
]


@pytest.mark.parametrize("args, words", [c[1:] for c in VALIDATE_CLI], ids=[c[0] for c in VALIDATE_CLI])
def test_validate_refuses_at_once(args, words):
    proc = run_cli("validate", *args, "--backend", "serial", timeout=30)
    assert_one_line_error(proc, words)


def test_validate_hydrostatic_runs_at_its_smallest_size():
    proc = run_cli("validate", "hydrostatic", "--particles", 32, "--time", 0.01, "--backend", "serial", timeout=60)
    assert proc.returncode in (0, 1) and "Traceback" not in proc.stderr, proc.stderr


# --- the Python API: sizes checked before anything of that size is made ----------------------

BATCH_SIZES = [  # (id, from_scene keywords, error, words): a NumPy MemoryError, or 767 s of work
    ("n-2**31", {"n": 2**31}, ValueError, r"^n = 2147483648 scenes of fluid.particles = 3500: .* particle slots, at most"),
    ("n-1e7-of-2e6", {"n": 10**7, "particles": 2_000_000}, ValueError,
     r"^n = 10000000 scenes of fluid.particles = 2000000: 20,000,000,000,000 particle slots"),
    ("per-scene-counts", {"n": 2, "particles": [300, 2**31]}, ValueError, r"fluid.particles = 2147483648"),
    ("memory-lower-bound", {"n": 200_000, "particles": 10_000}, ValueError,
     r"^n = 200000, fluid.particles = 10000 need more than 512 GB"),
    ("shake-1e6", {"n": 2, "shake": [{"start": 0.0, "end": 1.0}] * 10**6}, ValueError,
     r"^shake: 1,000,000 \[\[shake\]\] entries, at most 32$"),
]


@pytest.mark.parametrize("kw, error, words", [c[1:] for c in BATCH_SIZES], ids=[c[0] for c in BATCH_SIZES])
def test_batch_sizes_are_checked_first(kw, error, words):
    import time

    import corpuscle

    t0 = time.perf_counter()
    with pytest.raises(error, match=words):
        corpuscle.Batch.from_scene("magic8ball", backend="serial", settle=0.0, **kw)
    assert time.perf_counter() - t0 < 2


SHAKES = [  # (id, how the windows are given, words): the core refused 33 after placement, naming fluid.particles
    ("api-33", "api", 33, r"^shake: 33 \[\[shake\]\] entries, at most 32$"),
    ("api-1e6", "api", 10**6, r"^shake: 1,000,000 \[\[shake\]\] entries, at most 32$"),
    ("file-60000", "file", 60_000, "shake: 60,000 [[shake]] entries, at most 32"),
]


@pytest.mark.parametrize("how, count, words", [c[1:] for c in SHAKES], ids=[c[0] for c in SHAKES])
def test_shake_windows_are_counted_first(tmp_path, how, count, words):
    import time

    t0 = time.perf_counter()
    if how == "api":
        import corpuscle
        from corpuscle.scene import SceneError

        with pytest.raises(SceneError, match=words):
            corpuscle.Simulation.from_scene("magic8ball", backend="serial",
                                            overrides={"shake": [{"start": 0.0, "end": 1.0}] * count})
        assert time.perf_counter() - t0 < 2
    else:
        scene = tmp_path / "shakes.toml"
        scene.write_text("shake = [" + ",".join(["{start=0,end=1}"] * count) + ']\n[scene]\nkind = "magic8ball"\n')
        proc = run_cli("run", scene, "--backend", "serial", "--steps", 1, "--out", tmp_path / "o.cps")
        assert_one_line_error(proc, words)


@pytest.mark.parametrize("env", ["vector", "single"])
@pytest.mark.parametrize("call", ["step", "reset"])
def test_a_closed_env_says_it_is_closed(env, call):
    pytest.importorskip("gymnasium")
    import numpy as np
    from corpuscle.envs import Magic8BallEnv, Magic8BallVectorEnv

    if env == "vector":
        e, action = Magic8BallVectorEnv(num_envs=2, backend="serial", particles=200, settle=0.0), np.zeros((2, 6))
    else:
        e, action = Magic8BallEnv(backend="serial", particles=200, settle=0.0), np.zeros(6)
    e.reset(seed=1)
    e.close()
    with pytest.raises(RuntimeError, match=r"^the environment is closed"):  # was AttributeError on None
        e.step(action) if call == "step" else e.reset()


# --- the live viewer: a request it cannot parse is one line, never a traceback ---------------

BAD_REQUESTS = [  # (id, raw request): aiohttp printed a 15-line traceback for each
    ("oversized-header-value", b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: " + b"a" * 20000 + b"\r\n\r\n"),
    ("oversized-header-name", b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n" + b"X" * 20000 + b": 1\r\n\r\n"),
    ("oversized-url", b"GET /" + b"b" * 20000 + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"),
]


@pytest.mark.parametrize("raw", [c[1] for c in BAD_REQUESTS], ids=[c[0] for c in BAD_REQUESTS])
def test_viewer_bad_request_is_at_most_one_line(capfd, caplog, raw):
    pytest.importorskip("aiohttp")
    import socket
    import time

    from corpuscle.live import LiveServer

    lines: list[str] = []
    s = LiveServer({"scene": "t", "kind": "test", "dim": 3,
                    "container": {"type": "sphere", "center": [0, 0, 0], "radius": 1.0}}, port=0, log=lines.append)
    s.start()
    try:
        with socket.create_connection(("127.0.0.1", s.port), timeout=10) as c:
            c.sendall(raw)
            assert c.recv(64).startswith(b"HTTP/1.") or True  # the client's 400 (or a closed socket)
        time.sleep(0.3)
    finally:
        s.stop()
    out, err = capfd.readouterr()
    assert not [r for r in caplog.records if r.exc_info], caplog.text  # logged tracebacks reach stderr
    assert "Traceback" not in err + out and err.count("\n") <= 1, err
    assert len(lines) <= 1 and all("\n" not in line and len(line) < 300 for line in lines), lines


# ---- a measurement stops at a signal -------------------------------------------------------

@pytest.mark.parametrize("sig, code", [("SIGINT", 130), ("SIGTERM", 143)])
@pytest.mark.parametrize("args", [
    ["bench", "magic8ball", "--backend", "serial", "--particles", "500", "--steps", "1000000", "--repeats", "1",
     "--warmup", "0"],
    ["bench", "magic8ball", "--backend", "serial", "--particles", "300", "--batch", "2", "--steps", "1000000",
     "--repeats", "1", "--warmup", "0"],
], ids=["single", "batch"])
def test_a_benchmark_stops_within_a_second_or_two_of_a_signal(args, sig, code):
    # a million timed steps would take hours: the core's bench looks at signals as step does
    import signal
    import subprocess
    import time

    from cli_script import script

    p = subprocess.Popen([script(), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(4.0)  # well into the timed steps (initialisation takes a fraction of a second)
        assert p.poll() is None, p.communicate()
        t0 = time.monotonic()
        p.send_signal(getattr(signal, sig))
        out, errs = p.communicate(timeout=20)
        took = time.monotonic() - t0
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()
    assert p.returncode == code, errs
    assert took < 5.0, took
    assert "Traceback" not in errs and len(errs.strip().splitlines()) <= 1, errs
