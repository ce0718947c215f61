"""Running under ``mpiexec``: the world communicator, the MPI library, and failures that stop
every rank (docs/distributed.md).

mpi4py is the optional ``[mpi]`` extra and is imported only when a launcher started this process
with more than one rank (read from the launchers' environment: Open MPI's ``OMPI_COMM_WORLD_SIZE``,
PMI's ``PMI_SIZE`` (MPICH's Hydra, Intel MPI, Slurm's ``srun --mpi=pmi2``), ``PMIX_SIZE``); a plain
run never loads MPI.
"""

from __future__ import annotations

import os
import sys
import time

# (size, rank) variables of the launchers, in the order they are trusted
_LAUNCHER_VARS = (
    ("OMPI_COMM_WORLD_SIZE", "OMPI_COMM_WORLD_RANK"),  # Open MPI's mpiexec / prterun
    ("PMI_SIZE", "PMI_RANK"),  # MPICH's Hydra, Intel MPI, srun --mpi=pmi2
    ("PMIX_SIZE", "PMIX_RANK"),  # some PMIx launchers
)


class MpiUnavailable(RuntimeError):
    """Launched with several ranks but mpi4py cannot be imported (a one-line input error, exit 2)."""

    exit_code = 2


def launched_size() -> int:
    """How many ranks the launcher started (1 when none did), from its environment only."""
    for size_var, _ in _LAUNCHER_VARS:
        v = os.environ.get(size_var)
        if v:
            try:
                return max(1, int(v))
            except ValueError:
                continue
    # Slurm's srun with a PMIx or PMI plug-in sets a rank but not always the size
    if (os.environ.get("PMIX_RANK") or os.environ.get("PMI_RANK")) and os.environ.get("SLURM_NTASKS"):
        try:
            return max(1, int(os.environ["SLURM_NTASKS"]))
        except ValueError:
            pass
    return 1


def launched_rank() -> int:
    """This process's rank as the launcher's environment says (0 when not launched)."""
    for size_var, rank_var in _LAUNCHER_VARS:
        if os.environ.get(size_var) and os.environ.get(rank_var):
            try:
                return int(os.environ[rank_var])
            except ValueError:
                continue
    for rank_var in ("PMIX_RANK", "PMI_RANK"):
        if os.environ.get(rank_var) and os.environ.get("SLURM_NTASKS"):
            try:
                return int(os.environ[rank_var])
            except ValueError:
                continue
    return 0


_WORLD = None


def world():
    """``MPI.COMM_WORLD`` when this process is one of several ranks, else None (MPI never loaded
    without a launcher's environment; loaded but None when MPI's own world has one rank).

    Raises :class:`MpiUnavailable` when the launcher started several ranks and mpi4py is missing."""
    global _WORLD
    if _WORLD is not None:
        return _WORLD or None
    if launched_size() <= 1:
        return None
    try:
        from mpi4py import MPI
    except ImportError as exc:
        raise MpiUnavailable(f"started as one of {launched_size()} MPI ranks but mpi4py cannot be imported "
                             f"({exc}); install the extra: pip install 'corpuscle[mpi]'") from None
    _WORLD = MPI.COMM_WORLD if MPI.COMM_WORLD.Get_size() > 1 else False
    return _WORLD or None


def rank_and_size(comm=None) -> tuple[int, int]:
    comm = comm if comm is not None else world()
    return (0, 1) if comm is None else (comm.Get_rank(), comm.Get_size())


def node_local_rank(comm) -> tuple[int, int]:
    """(rank, size) among the ranks sharing this node (MPI_COMM_TYPE_SHARED): the GPU a rank drives."""
    from mpi4py import MPI

    local = comm.Split_type(MPI.COMM_TYPE_SHARED, key=comm.Get_rank())
    try:
        return local.Get_rank(), local.Get_size()
    finally:
        local.Free()


def cuda_aware() -> bool | None:
    """Whether the loaded MPI library moves CUDA device memory itself (Open MPI's
    ``MPIX_Query_cuda_support``, MPICH's ``MPIX_GPU_query_support``): True / False, or None
    when the library says nothing (then device buffers are staged through pinned host memory)."""
    import ctypes

    try:
        lib = ctypes.CDLL(None)
    except OSError:
        return None
    f = getattr(lib, "MPIX_Query_cuda_support", None)
    if f is not None:
        f.restype = ctypes.c_int
        return bool(f())
    g = getattr(lib, "MPIX_GPU_query_support", None)
    if g is not None:  # MPICH: MPIX_GPU_SUPPORT_CUDA = 0
        out = ctypes.c_int(0)
        g.restype = ctypes.c_int
        if g(ctypes.c_int(0), ctypes.byref(out)) == 0:
            return bool(out.value)
    if lib_name_has("Open MPI") or lib_name_has("MPICH"):
        return False  # the extension is built only into CUDA-aware builds
    return None


def lib_name_has(text: str) -> bool:
    try:
        from mpi4py import MPI

        return text in MPI.Get_library_version()
    except Exception:  # noqa: BLE001 - any failure: not known
        return False


def describe() -> dict:
    """What `corpuscle info` says of MPI: mpi4py's version, the library, CUDA awareness, the launch.

    Imports mpi4py (which loads the MPI library without starting it) only when it is installed."""
    try:
        import mpi4py
    except ImportError:
        return {"available": False, "reason": "mpi4py not installed (pip install 'corpuscle[mpi]')",
                "ranks": launched_size()}
    mpi4py.rc.initialize = False  # do not start MPI to describe it
    try:
        from mpi4py import MPI

        lib = MPI.Get_library_version().strip().splitlines()[0]
        lib = lib.split(",")[0].strip()
        version = "%d.%d" % MPI.Get_version()
    except Exception as exc:  # noqa: BLE001 - a broken MPI install is reported, not raised
        return {"available": False, "reason": f"mpi4py {mpi4py.__version__} cannot load its MPI library: {exc}",
                "ranks": launched_size()}
    aware = cuda_aware()
    return {"available": True, "mpi4py": mpi4py.__version__, "library": lib, "standard": version,
            "cuda_aware": aware,
            "gpu_exchange": {True: "CUDA-aware MPI", False: "staged through pinned host buffers",
                             None: "staged through pinned host buffers (CUDA awareness unknown)"}[aware],
            "ranks": launched_size()}


def abort(comm, message: str, code: int) -> None:
    """Print one line for this rank and stop every rank (MPI_Abort): no rank is left waiting."""
    try:
        sys.stdout.flush()
    except Exception:  # noqa: BLE001
        pass
    sys.stderr.write(f"corpuscle: rank {comm.Get_rank()} of {comm.Get_size()}: {message}\n")
    sys.stderr.flush()
    # the launcher forwards a rank's output through its daemon, which the abort tears down: a
    # moment for the line to get out first (under load it was lost without this)
    time.sleep(0.3)
    comm.Abort(code)


# set once the ranks of a command have agreed its input is good: from then on an error on one
# rank aborts every rank (the others may be waiting for it in a collective)
_COLLECTIVE = False


class RankInputError(ValueError):
    """A check that failed on some rank, raised on every rank after :func:`agree` (rank 0 reports it)."""

    exit_code = 2

    def __init__(self, message: str, quiet: bool, exit_code: int = 2):
        super().__init__(message)
        self.quiet = quiet
        self.exit_code = exit_code


def agree(comm, check):
    """Run ``check()`` on every rank (the command's validation, the same on each), then agree:
    when it failed on any rank every rank raises :class:`RankInputError` with the first failing
    rank's message (printed once, by rank 0), so no rank goes on alone. Returns check's value.
    From here on an uncaught error on any rank aborts them all (:func:`collective_failure`)."""
    global _COLLECTIVE
    value, failure = None, None
    try:
        value = check()
    except Exception as exc:  # noqa: BLE001 - reported on every rank below
        failure = (" ".join(str(exc).split()) or type(exc).__name__, int(getattr(exc, "exit_code", 2)))
    failures = comm.allgather(failure)
    bad = [(r, f) for r, f in enumerate(failures) if f is not None]
    if bad:
        r, (message, code) = bad[0]
        if all(f == bad[0][1] for f in failures):  # the same on every rank: the input, not a rank
            text = message
        else:
            text = f"rank {r}: {message}"
        raise RankInputError(text, quiet=comm.Get_rank() != 0, exit_code=code)
    _COLLECTIVE = True
    return value


def in_collective() -> bool:
    return _COLLECTIVE
