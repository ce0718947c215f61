"""`corpuscle bench` and `corpuscle info` on the real core, and the broken-pipe exit code."""
import datetime
import json
import math
import os
import statistics
import subprocess
import sys
import time

import pytest

pytest.importorskip("corpuscle._core")

import corpuscle
from corpuscle import _core, _omp
from corpuscle.cli import main

BENCH = ["bench", "magic8ball", "--particles", "300", "--steps", "5", "--repeats", "2", "--warmup", "1",
         "--backend", "cpu", "--no-progress"]


def corpuscle_command():
    """The installed `corpuscle` script next to this Python, else `python -m corpuscle`."""
    exe = os.path.join(os.path.dirname(sys.executable), "corpuscle")
    return [exe] if os.path.exists(exe) else [sys.executable, "-m", "corpuscle"]


def test_bench_json_rows(tmp_path, capsys):
    out = tmp_path / "bench.json"
    t0 = time.perf_counter()
    rc = main(BENCH + ["--json", str(out)])
    wall = time.perf_counter() - t0
    assert rc == 0
    rows = json.loads(out.read_text())
    assert isinstance(rows, list) and len(rows) == 1
    row = rows[0]
    # the fields a benchmark record carries (docs/benchmarks.md, "Citing measurements": rates with the
    # device, the date and the exact command)
    for key in ("scene", "backend", "particles", "steps", "repeats", "warmup", "steps_per_second",
                "particle_steps_per_second", "seconds", "device", "date", "command"):
        assert key in row, key
    assert (row["scene"], row["backend"], row["particles"], row["steps"], row["repeats"], row["warmup"]) == \
        ("magic8ball", "cpu", 300, 5, 2, 1)
    # one timing per repeat, each positive and, being the core's clock around the steps, part
    # of this call's wall time (seconds, not milliseconds)
    secs = row["seconds"]
    assert len(secs) == 2 and all(math.isfinite(s) and s > 0 for s in secs)
    assert sum(secs) < wall
    # the rates are those of the median repeat
    assert row["steps_per_second"] == pytest.approx(5 / statistics.median(secs), rel=1e-12)
    assert row["particle_steps_per_second"] == pytest.approx(row["steps_per_second"] * 300, rel=1e-12)
    assert row["steps_per_second"] > 0
    assert row["command"] == "corpuscle " + " ".join(BENCH + ["--json", str(out)])
    assert datetime.datetime.fromisoformat(row["date"]).tzinfo is not None
    assert "OpenMP threads" in row["device"]
    # the table on stdout shows the same row
    lines = capsys.readouterr().out.splitlines()
    head = lines[0].split()
    assert head[:2] == ["backend", "particles"]
    cpu = [ln.split() for ln in lines if ln.startswith("cpu")]
    assert len(cpu) == 1 and cpu[0][1] == "300"
    at = head.index("steps/s")
    assert float(cpu[0][at].replace(",", "")) == pytest.approx(row["steps_per_second"], rel=1e-3, abs=0.06)
    assert float(cpu[0][head.index("init(s)")]) == pytest.approx(row["init_seconds"], abs=1e-3)


def test_bench_into_a_closed_pipe_exits_141_quietly():
    # `corpuscle bench ... | head -1` where the reader has gone: stdout is a pipe with no
    # reader, the first write fails, and the command stops with 141 (128 + SIGPIPE) and no
    # traceback, as Unix tools do
    proc = subprocess.Popen(corpuscle_command() + BENCH, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL)
    proc.stdout.close()  # before the child can write (it starts Python and runs the bench first)
    try:
        err = proc.stderr.read().decode(errors="replace")
        rc = proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert rc == 141, err
    assert err.strip() == "", err


def test_info_json_is_the_build_info():
    proc = subprocess.run(corpuscle_command() + ["info", "--json"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert data["version"] == corpuscle.__version__
    info = _core.build_info()
    assert data["build_info"] == json.loads(json.dumps(dict(info), default=str))
    # the compiled core is the same version as the package
    assert info["version"] == corpuscle.__version__
    assert isinstance(info["cuda_compiled"], bool) and isinstance(info["openmp"], bool)
    assert info["omp_threads"] >= 1
    if not info["gpus"]:
        assert info["gpu_error"]  # says why there is none


def test_info_text(capsys):
    assert main(["info"]) == 0
    lines = capsys.readouterr().out.splitlines()
    info = _core.build_info()

    def row(label):
        found = [ln.strip()[len(label):].strip() for ln in lines[1:] if ln.strip().startswith(label + " ")]
        assert len(found) == 1, (label, lines)
        return found[0]

    assert lines[0] == f"corpuscle {corpuscle.__version__}"
    assert row("core version") == info["version"]
    assert row("CUDA").startswith("compiled (architectures:" if info["cuda_compiled"] else "not compiled")
    assert row("OpenMP") == (f"yes, {_omp.describe(info['omp_threads'])}" if info["openmp"] else "no")
    gpu_lines = [ln.strip() for ln in lines if ln.strip().startswith("GPU ")]
    if info["gpus"]:
        assert len(gpu_lines) == len(info["gpus"]) + (1 if info["gpu_error"] else 0)
        for i, gpu in enumerate(info["gpus"]):
            assert gpu_lines[i].startswith(f"GPU {i}") and gpu["name"] in gpu_lines[i]
    else:
        assert len(gpu_lines) == 1 and gpu_lines[0].split()[1] == "none"


def test_bench_batches_report_scene_and_particle_steps(tmp_path, capsys):
    out = tmp_path / "batch.json"
    rc = main(["bench", "magic8ball", "--particles", "200", "--steps", "3", "--repeats", "2", "--warmup", "1",
               "--backend", "serial", "--no-progress", "--batch", "1", "3", "--json", str(out)])
    assert rc == 0
    rows = json.loads(out.read_text())
    assert [r["batch"] for r in rows] == [1, 3]
    for r in rows:
        assert r["particles"] == 200 * r["batch"]
        assert r["scene_steps_per_second"] == pytest.approx(r["steps_per_second"] * r["batch"])
        assert r["particle_steps_per_second"] == pytest.approx(r["steps_per_second"] * r["particles"])
    text = capsys.readouterr().out
    assert "scene-steps/s" in text.splitlines()[0] and "batch" in text.splitlines()[0]
    # bad values: exit code 2 and one line naming the option
    assert main(["bench", "magic8ball", "--batch", "0", "--backend", "serial"]) == 2
    assert "--batch must be a positive integer, got 0" in capsys.readouterr().err
    assert main(["bench", "wind-tunnel", "--batch", "2", "--backend", "serial"]) == 2
    assert "--batch: batches of scenes are magic8ball scenes" in capsys.readouterr().err


SWEEP = ["bench", "fluid-box", "--backend", "serial", "cpu", "--neighbors", "allpairs", "grid",
         "--particles", "128", "512", "--steps", "2", "--repeats", "1", "--warmup", "0", "--no-progress"]


def test_bench_sweep_speedup_tables_plot_and_max_step(tmp_path, capsys):
    # seed 002's tables: every backend and index over serial grid and over OpenMP grid at each size
    out, png = tmp_path / "rows.json", tmp_path / "sweep.png"
    assert main(SWEEP + ["--json", str(out), "--plot", str(png)]) == 0
    rows = json.loads(out.read_text())
    text = capsys.readouterr().out
    sizes = sorted({r["particles"] for r in rows})
    assert len(rows) == 8 and len(sizes) == 2
    assert "speedup over serial grid:" in text and "speedup over OpenMP grid:" in text
    over_serial = text.split("speedup over serial grid:")[1].split("speedup over OpenMP grid:")[0]
    line = next(ln for ln in over_serial.splitlines() if ln.startswith(f"| {sizes[1]:,} |"))
    cells = [c.strip() for c in line.strip("|").split("|")][1:]
    sps = {(r["backend"], r["neighbors"]): r["steps_per_second"] for r in rows if r["particles"] == sizes[1]}
    base = sps[("serial", "grid")]
    want = [sps[c] / base for c in (("serial", "allpairs"), ("cpu", "allpairs"), ("serial", "grid"), ("cpu", "grid"))]
    # (the table prints three significant digits: within half a unit of the third, 0.5%)
    assert [float(c.rstrip("x")) for c in cells] == pytest.approx(want, rel=5.01e-3)
    assert png.stat().st_size > 1000 and png.read_bytes()[:4] == b"\x89PNG"
    # --max-step: all pairs at 512 would take 16 times its step at 128 (O(N^2)): left out when
    # that passes the limit, while the grid (O(N)) stays
    t128 = next(r for r in rows if r["particles"] == sizes[0] and r["neighbors"] == "allpairs"
                and r["backend"] == "serial")["seconds"][0] / 2
    limit = 4 * t128  # (a margin of 4 for the two runs' timings)
    out2 = tmp_path / "rows2.json"
    assert main(SWEEP + ["--backend", "serial", "--json", str(out2), "--max-step", f"{limit:.6g}"]) == 0
    got = {(r["neighbors"], r["particles"]) for r in json.loads(out2.read_text())}
    assert ("allpairs", sizes[1]) not in got and ("allpairs", sizes[0]) in got and ("grid", sizes[1]) in got
    assert "left out: serial allpairs at 512" in capsys.readouterr().out


@pytest.mark.parametrize("bad, words", [(["--max-step", "0"], "--max-step"), (["--max-step", "soon"], "--max-step"),
                                        (["--plot", "/nonexistent-dir/p.png"], "/nonexistent-dir")])
def test_bench_sweep_bad_options_refused_before_running(bad, words):
    from cli_script import assert_one_line_error

    t0 = time.perf_counter()
    proc = subprocess.run(corpuscle_command() + SWEEP + bad, capture_output=True, text=True, timeout=60)
    assert_one_line_error(proc, words)
    assert time.perf_counter() - t0 < 30


def test_bench_start_time_times_the_flow_there_and_counts_the_relistings(tmp_path):
    # --start-time runs the scene to that time untimed: the timed steps start there (a dam break
    # already moving relists the lists far more often than the still column at t = 0)
    rows = {}
    for t in ("0", "0.1"):
        out = tmp_path / f"rows{t}.json"
        args = ["bench", "dam-break-2d", "--backend", "serial", "--neighbors", "lists", "--steps", "20",
                "--repeats", "2", "--warmup", "0", "--start-time", t, "--no-progress", "--json", str(out)]
        assert main(args) == 0
        rows[t] = json.loads(out.read_text())[0]
    still, moving = rows["0"], rows["0.1"]
    assert still["start_time"] == 0.0 and moving["start_time"] == 0.1
    # the steps to t = 0.1 were taken before the timing (there are more than a thousand)
    assert moving["steps_taken"] > still["steps_taken"] + 1000
    assert 0 <= still["timed_rebuilds"] < moving["timed_rebuilds"] <= 40
    # the warm-up steps are taken after the run to the start time (not no-ops at its end)
    out = tmp_path / "warm.json"
    assert main(["bench", "dam-break-2d", "--backend", "serial", "--neighbors", "lists", "--steps", "20",
                 "--repeats", "2", "--warmup", "30", "--start-time", "0.1", "--no-progress", "--json", str(out)]) == 0
    assert json.loads(out.read_text())[0]["steps_taken"] == moving["steps_taken"] + 30


@pytest.mark.parametrize("bad", [["--start-time", "-1"], ["--start-time", "later"], ["--start-time", "inf"]])
def test_bench_start_time_bad_values_refused(bad):
    from cli_script import assert_one_line_error

    proc = subprocess.run(corpuscle_command() + BENCH + bad, capture_output=True, text=True, timeout=60)
    assert_one_line_error(proc, "--start-time")


def test_bench_start_time_at_or_past_the_end_time_is_refused_at_once():
    # (it would otherwise run the scene far past its end, untimed, before any output)
    from cli_script import assert_one_line_error

    t0 = time.perf_counter()
    proc = subprocess.run(corpuscle_command() + ["bench", "dam-break-dsph", "--backend", "serial", "--start-time", "100",
                                                 "--no-progress"], capture_output=True, text=True, timeout=60)
    assert_one_line_error(proc, "run.end_time")
    assert time.perf_counter() - t0 < 30
    proc = subprocess.run(corpuscle_command() + ["bench", "dam-break-2d", "--backend", "serial", "--start-time", "0.2",
                                                 "--set", "run.end_time=0.2", "--no-progress"],
                          capture_output=True, text=True, timeout=60)
    assert_one_line_error(proc, "--start-time 0.2")


def test_run_summary_counts_the_relistings(tmp_path):
    out = tmp_path / "r.cps"
    proc = subprocess.run(corpuscle_command() + ["run", "dam-break-2d", "--backend", "serial", "--time", "0.05",
                                                 "--no-progress", "--out", str(out), "--json"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout.strip().splitlines()[-1])
    # the default index is lists; a run from the still column relists at its first step at least
    assert 1 <= s["relistings"] < s["steps"]
