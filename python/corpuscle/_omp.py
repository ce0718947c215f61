"""The OpenMP runtime's thread count and wait policy for the `cpu` backend, set at import.

The runtime (GCC's libgomp) reads its environment once, when it is loaded: at the first
import of the compiled core. Its defaults suit a machine that runs nothing else:

- one thread per CPU of the affinity mask, whatever the container's CPU quota (a `docker
  --cpus=2` container on a 64-core host gets 64 threads that the quota then stalls);
- a thread that waits (at the barrier that ends a parallel region, or for the next region)
  spins about 300,000 times before it sleeps. A step is dozens of short regions, so on a busy
  machine each waiting thread burns the time slices that the thread with work, or the other
  programs, need: the `cpu` backend ran 0.35x serial on a 2-core machine with other work.

So `import corpuscle` (this module's :func:`configure`) sets, before the runtime is loaded and
only where the user has not set them:

- ``GOMP_SPINCOUNT`` = :data:`SPIN_COUNT`: a wait spins a few tens of microseconds (long enough
  to bridge the gaps between the regions of one step on an idle machine), then sleeps;
- ``OMP_NUM_THREADS`` = the CPUs of the affinity mask capped by the cgroup CPU quota (v2
  ``cpu.max``, v1 ``cpu.cfs_quota_us``), rounded down, at least 1, when the quota is smaller.

A user's ``OMP_WAIT_POLICY``, ``GOMP_SPINCOUNT`` or ``OMP_NUM_THREADS`` wins. The load of other
programs is not read (a load average is a minute old and counts this process): the short spin
already makes a busy machine cost about what it would cost the serial backend. Results do not
depend on any of this (the CPU backend's results are the same for every thread count).
`corpuscle info` prints :func:`describe`.
"""
from __future__ import annotations

import math
import os

SPIN_COUNT = 3000
_WAIT_KEYS = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")
_MARK = "CORPUSCLE_OMP_SET"  # the variables configure() set (KEY=VALUE,...), for child processes

# what configure() found and did: read by describe() (None until configure has run)
_policy: dict | None = None


def parse_cpu_max(text: str) -> float | None:
    """CPUs allowed by a cgroup v2 ``cpu.max`` ("QUOTA PERIOD" or "max PERIOD"); None: no limit
    or unreadable."""
    parts = text.split()
    if not parts or parts[0] == "max":
        return None
    try:
        quota = float(parts[0])
        period = float(parts[1]) if len(parts) > 1 else 100000.0
    except ValueError:
        return None
    return quota / period if quota > 0 and period > 0 else None


def parse_cfs(quota_text: str, period_text: str) -> float | None:
    """CPUs allowed by cgroup v1 ``cpu.cfs_quota_us`` / ``cpu.cfs_period_us`` (-1: no limit)."""
    try:
        quota, period = float(quota_text.strip()), float(period_text.strip())
    except ValueError:
        return None
    return quota / period if quota > 0 and period > 0 else None


def _read(path: str) -> str | None:
    try:
        with open(path, encoding="ascii", errors="replace") as f:
            return f.read()
    except OSError:
        return None


def cgroup_cpu_limit(root: str = "/sys/fs/cgroup", proc_cgroup: str | None = None) -> float | None:
    """The tightest CPU quota over this process's cgroup and its parents (v2, or v1's cpu
    controller), in CPUs; None when there is none. `root` and `proc_cgroup` (the text of
    /proc/self/cgroup) may be given, for tests."""
    if proc_cgroup is None:
        proc_cgroup = _read("/proc/self/cgroup") or ""
    v2_path, v1_path, v1_dir = None, None, "cpu"
    for line in proc_cgroup.splitlines():
        fields = line.split(":", 2)
        if len(fields) != 3:
            continue
        if fields[0] == "0" and fields[1] == "":
            v2_path = fields[2]
        elif "cpu" in fields[1].split(","):
            v1_path, v1_dir = fields[2], fields[1]
    limits: list[float] = []

    def walk(base: str, rel: str, read_limit) -> None:
        rel = rel.strip().strip("/")
        parts = rel.split("/") if rel else []
        # the cgroup's own directory and every parent up to the mount (inside a container
        # the mount is the cgroup itself, and the path may not exist under it: then the root)
        for k in range(len(parts), -1, -1):
            d = os.path.join(base, *parts[:k])
            lim = read_limit(d)
            if lim is not None:
                limits.append(lim)

    if v2_path is not None:
        for base in (root, os.path.join(root, "unified")):
            if os.path.exists(os.path.join(base, "cgroup.controllers")):
                walk(base, v2_path, lambda d: parse_cpu_max(_read(os.path.join(d, "cpu.max")) or "max"))
                break
    if v1_path is not None:
        for name in (v1_dir, "cpu", "cpu,cpuacct", "cpuacct,cpu"):
            base = os.path.join(root, name)
            if os.path.isdir(base):
                walk(base, v1_path, lambda d: parse_cfs(_read(os.path.join(d, "cpu.cfs_quota_us")) or "-1",
                                                        _read(os.path.join(d, "cpu.cfs_period_us")) or "0"))
                break
    return min(limits) if limits else None


def choose_threads(affinity_cpus: int, quota_cpus: float | None) -> int:
    """Threads for the OpenMP runtime: the affinity mask's CPUs, capped by the quota rounded
    down (a thread more than the quota stalls every barrier once the quota runs out), >= 1."""
    n = max(1, int(affinity_cpus))
    if quota_cpus is not None and quota_cpus > 0:
        n = min(n, max(1, math.floor(quota_cpus + 1e-9)))
    return n


def _affinity_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _runtime_loaded() -> bool:
    """Whether an OpenMP runtime is already in this process (then its settings are fixed)."""
    maps = _read("/proc/self/maps") or ""
    return any(name in maps for name in ("libgomp", "libomp", "libiomp"))


def configure(environ=None, affinity_cpus: int | None = None, quota_cpus: float | None = ...,
              runtime_loaded: bool | None = None) -> dict:
    """Set the runtime's environment where the user has not (see the module's doc); returns
    (and keeps, for describe) what was found and set. The arguments are for tests."""
    global _policy
    env = os.environ if environ is None else environ
    affinity = _affinity_cpus() if affinity_cpus is None else affinity_cpus
    quota = cgroup_cpu_limit() if quota_cpus is ... else quota_cpus
    loaded = _runtime_loaded() if runtime_loaded is None else runtime_loaded
    policy = {"affinity_cpus": affinity, "quota_cpus": quota, "runtime_loaded_before": loaded,
              "threads_set": None, "spin_set": None}
    # a process started by one that imported corpuscle inherits what it set: still ours
    ours = dict(kv.split("=", 1) for kv in env.get(_MARK, "").split(",") if "=" in kv)
    for k, v in ours.items():
        if env.get(k) == v:
            del env[k]
    if not loaded:
        if "OMP_NUM_THREADS" not in env:
            n = choose_threads(affinity, quota)
            if n < affinity:
                env["OMP_NUM_THREADS"] = str(n)
                policy["threads_set"] = n
        if not any(k in env for k in _WAIT_KEYS):
            env["GOMP_SPINCOUNT"] = str(SPIN_COUNT)
            policy["spin_set"] = SPIN_COUNT
    else:
        env.update({k: v for k, v in ours.items() if k not in env})  # leave them as they were
    mark = ",".join(f"{k}={env[k]}" for k, n in (("OMP_NUM_THREADS", policy["threads_set"]),
                                                   ("GOMP_SPINCOUNT", policy["spin_set"])) if n is not None)
    if mark:
        env[_MARK] = mark
    else:
        env.pop(_MARK, None)
    policy["wait"] = {k: env[k] for k in _WAIT_KEYS if k in env}
    policy["omp_num_threads"] = env.get("OMP_NUM_THREADS")
    _policy = policy
    return policy


def policy() -> dict:
    """What configure() found and set (configure runs at `import corpuscle`)."""
    return dict(_policy) if _policy is not None else configure()


def describe(threads: int) -> str:
    """One line for `corpuscle info`: the threads the runtime uses and why, and its wait policy."""
    p = policy()
    quota = p["quota_cpus"]
    why = f"{p['affinity_cpus']} CPUs in the affinity mask"
    if quota is not None:
        why += f", cgroup quota {quota:g} CPUs"
    if p["threads_set"] is not None:
        why += ": OMP_NUM_THREADS set by corpuscle"
    elif p["omp_num_threads"] is not None:
        why += f": OMP_NUM_THREADS={p['omp_num_threads']} (yours)"
    if p["runtime_loaded_before"]:
        wait = "the runtime's own (an OpenMP runtime was loaded before corpuscle)"
    elif p["spin_set"] is not None:
        wait = f"spin {p['spin_set']} then sleep (GOMP_SPINCOUNT set by corpuscle)"
    else:
        wait = ", ".join(f"{k}={v}" for k, v in p["wait"].items()) + " (yours)"
    return f"{threads} thread{'' if threads == 1 else 's'} ({why}); wait: {wait}"
