"""The OpenMP runtime's thread count and wait policy (corpuscle/_omp.py): the cgroup quota and
affinity parsing on fabricated inputs, the user's settings winning, the runtime really reading
ours, and (slow) the `cpu` backend keeping up with `serial` on a machine with other work."""
import json
import os
import statistics
import subprocess
import sys
import textwrap

import pytest

from corpuscle import _omp
from corpuscle._testing import openmp as _has_openmp

_OMP_KEYS = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "OMP_NUM_THREADS", "CORPUSCLE_OMP_SET", "OMP_DISPLAY_ENV")


def _clean_env(**extra):
    env = {k: v for k, v in os.environ.items() if k not in _OMP_KEYS}
    env.update(extra)
    return env


@pytest.fixture
def keep_policy(monkeypatch):
    monkeypatch.setattr(_omp, "_policy", _omp._policy)


def test_parse_cpu_max():
    assert _omp.parse_cpu_max("max 100000\n") is None
    assert _omp.parse_cpu_max("150000 100000\n") == 1.5
    assert _omp.parse_cpu_max("50000 100000") == 0.5
    assert _omp.parse_cpu_max("200000 50000") == 4.0
    assert _omp.parse_cpu_max("") is None
    assert _omp.parse_cpu_max("lots 100000") is None


def test_parse_cfs():
    assert _omp.parse_cfs("-1\n", "100000\n") is None
    assert _omp.parse_cfs("300000\n", "100000\n") == 3.0
    assert _omp.parse_cfs("", "100000") is None


def _write(path, text):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def test_cgroup_v2_quota_is_the_tightest_of_the_group_and_its_parents(tmp_path):
    _write(tmp_path / "cgroup.controllers", "cpu memory\n")
    _write(tmp_path / "cpu.max", "max 100000\n")
    _write(tmp_path / "a" / "cpu.max", "max 100000\n")
    _write(tmp_path / "a" / "b" / "cpu.max", "250000 100000\n")
    assert _omp.cgroup_cpu_limit(str(tmp_path), "0::/a/b\n") == 2.5
    _write(tmp_path / "a" / "cpu.max", "100000 100000\n")  # the parent is tighter
    assert _omp.cgroup_cpu_limit(str(tmp_path), "0::/a/b\n") == 1.0
    # inside a container the group's path is not under the mount: the mount's own limit
    _write(tmp_path / "cpu.max", "300000 100000\n")
    assert _omp.cgroup_cpu_limit(str(tmp_path), "0::/elsewhere/c\n") == 3.0
    # v2 mounted under unified/ (hybrid hierarchy), no limit anywhere
    hybrid = tmp_path / "hybrid"
    _write(hybrid / "unified" / "cgroup.controllers", "cpu\n")
    _write(hybrid / "unified" / "cpu.max", "max 100000\n")
    assert _omp.cgroup_cpu_limit(str(hybrid), "0::/\n") is None


def test_cgroup_v1_quota(tmp_path):
    _write(tmp_path / "cpu,cpuacct" / "x" / "cpu.cfs_quota_us", "300000\n")
    _write(tmp_path / "cpu,cpuacct" / "x" / "cpu.cfs_period_us", "100000\n")
    _write(tmp_path / "cpu,cpuacct" / "cpu.cfs_quota_us", "-1\n")
    _write(tmp_path / "cpu,cpuacct" / "cpu.cfs_period_us", "100000\n")
    proc = "4:memory:/x\n3:cpu,cpuacct:/x\n0::/\n"
    assert _omp.cgroup_cpu_limit(str(tmp_path), proc) == 3.0
    assert _omp.cgroup_cpu_limit(str(tmp_path), "3:cpu,cpuacct:/\n") is None
    assert _omp.cgroup_cpu_limit(str(tmp_path / "none"), proc) is None


def test_choose_threads():
    assert _omp.choose_threads(64, 2.0) == 2
    assert _omp.choose_threads(64, 1.5) == 1  # a thread past the quota stalls every barrier
    assert _omp.choose_threads(64, 0.5) == 1
    assert _omp.choose_threads(4, None) == 4
    assert _omp.choose_threads(4, 8.0) == 4
    assert _omp.choose_threads(0, None) == 1


def test_configure_sets_only_what_the_user_left_unset(keep_policy):
    env = {}
    p = _omp.configure(env, affinity_cpus=64, quota_cpus=2.0, runtime_loaded=False)
    assert env["OMP_NUM_THREADS"] == "2" and env["GOMP_SPINCOUNT"] == str(_omp.SPIN_COUNT)
    assert p["threads_set"] == 2 and p["spin_set"] == _omp.SPIN_COUNT
    assert "set by corpuscle" in _omp.describe(2)
    # a child process inherits them and still counts them as corpuscle's
    child = dict(env)
    p = _omp.configure(child, affinity_cpus=64, quota_cpus=2.0, runtime_loaded=False)
    assert p["threads_set"] == 2 and p["spin_set"] == _omp.SPIN_COUNT and child == env
    # no quota below the affinity mask: the runtime's own thread count
    env = {}
    _omp.configure(env, affinity_cpus=4, quota_cpus=None, runtime_loaded=False)
    assert "OMP_NUM_THREADS" not in env and env["GOMP_SPINCOUNT"] == str(_omp.SPIN_COUNT)
    # the user's settings win
    for user in ({"OMP_WAIT_POLICY": "active"}, {"GOMP_SPINCOUNT": "300000"}, {"OMP_NUM_THREADS": "7"}):
        env = dict(user)
        p = _omp.configure(env, affinity_cpus=64, quota_cpus=2.0, runtime_loaded=False)
        for k, v in user.items():
            assert env[k] == v
        assert ("GOMP_SPINCOUNT" in env) == ("OMP_WAIT_POLICY" not in user)
        assert "(yours)" in _omp.describe(2)
    # a runtime already loaded reads nothing more: nothing is set, and info says so
    env = {}
    p = _omp.configure(env, affinity_cpus=64, quota_cpus=2.0, runtime_loaded=True)
    assert env == {} and p["threads_set"] is None and p["spin_set"] is None
    assert "loaded before corpuscle" in _omp.describe(64)


@pytest.mark.skipif(not _has_openmp(), reason="built without OpenMP")
def test_the_runtime_reads_the_policy_set_at_import():
    code = "import corpuscle._core"
    out = subprocess.run([sys.executable, "-c", code], env=_clean_env(OMP_DISPLAY_ENV="verbose"),
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    if "GOMP_SPINCOUNT = " not in out.stderr:
        pytest.skip("the OpenMP runtime is not GCC's libgomp")
    assert f"GOMP_SPINCOUNT = '{_omp.SPIN_COUNT}'" in out.stderr
    out = subprocess.run([sys.executable, "-c", code], env=_clean_env(OMP_DISPLAY_ENV="verbose", GOMP_SPINCOUNT="12345"),
                         capture_output=True, text=True, timeout=120)
    assert "GOMP_SPINCOUNT = '12345'" in out.stderr


def test_info_reports_threads_and_wait_policy():
    proc = subprocess.run([sys.executable, "-m", "corpuscle", "info", "--json"], env=_clean_env(), capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    pol = data["openmp_policy"]
    assert pol["spin_set"] == _omp.SPIN_COUNT and pol["affinity_cpus"] == len(os.sched_getaffinity(0))
    proc = subprocess.run([sys.executable, "-m", "corpuscle", "info"], env=_clean_env(OMP_WAIT_POLICY="passive"),
                          capture_output=True, text=True, timeout=120)
    row = [ln for ln in proc.stdout.splitlines() if ln.strip().startswith("OpenMP")]
    if data["build_info"]["openmp"]:
        assert "wait: OMP_WAIT_POLICY=passive (yours)" in row[0], row


# serial and cpu stepped in turn in one process, the median rate of each over the rounds
_RACE = textwrap.dedent("""
    import statistics, sys, time
    import corpuscle
    sims = {b: corpuscle.Simulation.from_scene("magic8ball", backend=b, particles=1000) for b in ("serial", "cpu")}
    for s in sims.values():
        s.step(10)
    rate = {b: [] for b in sims}
    for _ in range(7):
        for b, s in sims.items():
            t = time.perf_counter(); s.step(20); rate[b].append(20 / (time.perf_counter() - t))
    print(statistics.median(rate["cpu"]) / statistics.median(rate["serial"]))
""")


@pytest.mark.slow
@pytest.mark.skipif(not _has_openmp(), reason="built without OpenMP")
def test_cpu_keeps_up_with_serial_on_a_busy_machine():
    """With a busy loop on every CPU the `cpu` backend steps at least 0.8x as fast as `serial`
    (libgomp's own spin-waits made it 0.35x on 2 cores)."""
    ncpu = len(os.sched_getaffinity(0))
    busy = [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(ncpu)]
    try:
        out = subprocess.run([sys.executable, "-c", _RACE], env=_clean_env(), capture_output=True, text=True,
                             timeout=120)
    finally:
        for p in busy:
            p.kill()
        for p in busy:
            p.wait()
    assert out.returncode == 0, out.stderr
    ratio = float(out.stdout.split()[-1])
    assert ratio >= 0.8, ratio
