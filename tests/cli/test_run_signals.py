"""Through the real console script: Ctrl-C stops within about a second and keeps every
whole frame; a full disk (here: a file size limit) is one line, exit code 4 and the summary."""
import json
import resource
import signal
import subprocess
import time

import pytest

pytest.importorskip("corpuscle._core")

import corpuscle


def test_ctrl_c_stops_within_a_second_and_keeps_the_frames(tmp_path):
    out = tmp_path / "i.cps"
    proc = subprocess.Popen(["corpuscle", "run", "magic8ball", "--backend", "cpu", "--particles", "300", "--time",
                             "100", "--every", "100000", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not (out.exists() and out.stat().st_size > 4096):
        time.sleep(0.02)
    time.sleep(1.5)  # well inside the first chunk of 100,000 steps
    t = time.monotonic()
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=30)
    waited = time.monotonic() - t
    assert proc.returncode == 130
    assert waited < 1.5, waited
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("corpuscle: run interrupted at step"), stderr
    step = int(lines[0].split("at step ")[1].split(";")[0])
    with corpuscle.open(out) as run:
        # frame 0 and the whole step it stopped after
        assert list(run.steps) == [0, step] and step > 0
        assert "2 frames kept" in lines[0]
        run.verify()


def _limit_file_size(limit):
    def apply():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return apply


def test_full_disk_is_one_line_exit_4_and_keeps_whole_frames(tmp_path):
    out = tmp_path / "f.cps"
    p = subprocess.run(["corpuscle", "run", "magic8ball", "--backend", "cpu", "--particles", "300", "--steps", "200",
                        "--every", "5", "--out", str(out), "--json"],
                       capture_output=True, text=True, timeout=300, preexec_fn=_limit_file_size(60_000))
    assert p.returncode == 4, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in p.stderr
    assert lines[0].startswith(f"corpuscle: error: cannot write {out}: File too large;")
    summary = json.loads(p.stdout)
    with corpuscle.open(out) as run:
        n = len(run)
        assert n == summary["frames"] >= 2
        assert list(run.steps) == [5 * i for i in range(n)]
        run.verify()
    assert f"{n} frames kept up to step {5 * (n - 1)}" in lines[0]
    assert out.stat().st_size <= 60_000
