"""Launching ``mpiexec -n R`` from a test (tests/mpi/): the distributed tests run real ranks in
fresh processes, as a user starts them.

They skip, with the reason, when mpi4py (the ``[mpi]`` extra, in ``test``) or an ``mpiexec`` is
missing. Open MPI refuses to start as root without ``--allow-run-as-root`` and more ranks than
cores without ``--oversubscribe`` (CI has 2 cores; containers run as root): both are passed to
Open MPI's launcher, and MPICH's (Hydra) needs neither.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def mpiexec() -> tuple[str, bool]:
    """The ``mpiexec`` to use and whether it is Open MPI's; skips the test when there is none."""
    pytest.importorskip("mpi4py", reason="mpi4py is not installed (pip install '.[mpi]')")
    beside = Path(sys.executable).with_name("mpiexec")
    exe = str(beside) if beside.exists() else shutil.which("mpiexec")
    if exe is None:
        pytest.skip("no mpiexec on PATH (pip install '.[mpi]' brings Open MPI's)")
    try:
        version = subprocess.run([exe, "--version"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.TimeoutExpired) as exc:
        pytest.skip(f"mpiexec does not run: {exc}")
    return exe, "Open MPI" in version or "OpenRTE" in version


def env() -> dict[str, str]:
    e = dict(os.environ)
    # the ranks import the corpuscle these tests import (an installed one, or a source tree with
    # its compiled core), not whatever the repository's python/ holds
    import corpuscle

    here = str(Path(corpuscle.__file__).resolve().parent.parent)
    e["PYTHONPATH"] = os.pathsep.join(p for p in (here, e.get("PYTHONPATH", "")) if p)
    # one thread a rank: the ranks share CI's 2 cores
    e.setdefault("OMP_NUM_THREADS", "1")
    e["OMPI_ALLOW_RUN_AS_ROOT"] = e["OMPI_ALLOW_RUN_AS_ROOT_CONFIRM"] = "1"
    e.setdefault("OMPI_MCA_rmaps_base_oversubscribe", "1")
    e.setdefault("PRTE_MCA_rmaps_default_mapping_policy", ":oversubscribe")
    return e


def launch(ranks: int, args: list[str], cwd: Path, timeout: float = 120.0) -> subprocess.CompletedProcess:
    """``mpiexec -n RANKS python -m ARGS...`` in ``cwd``; ARGS start with the module or script."""
    exe, openmpi = mpiexec()
    cmd = [exe, "-n", str(ranks)]
    if openmpi:
        cmd += ["--oversubscribe"]
        if hasattr(os, "geteuid") and os.geteuid() == 0:
            cmd += ["--allow-run-as-root"]
    cmd += [sys.executable, *args]
    return subprocess.run(cmd, cwd=cwd, env=env(), capture_output=True, text=True, timeout=timeout)


def corpuscle(ranks: int, args: list[str], cwd: Path, timeout: float = 120.0) -> subprocess.CompletedProcess:
    """``mpiexec -n RANKS corpuscle ARGS...``."""
    return launch(ranks, ["-m", "corpuscle", *args], cwd, timeout)


def single(args: list[str], cwd: Path, timeout: float = 120.0) -> subprocess.CompletedProcess:
    """``corpuscle ARGS...`` without mpiexec (one process, MPI never loaded)."""
    return subprocess.run([sys.executable, "-m", "corpuscle", *args], cwd=cwd, env=env(), capture_output=True,
                          text=True, timeout=timeout)
