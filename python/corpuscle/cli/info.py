"""``corpuscle info``: the version, the build's options and the usable GPUs."""

from __future__ import annotations

import argparse
import importlib

from .. import _json
from ._options import EXIT_OK, EXIT_USAGE, Command, err, one_line, register


def _configure_info(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")


def _cmd_info(args: argparse.Namespace) -> int:
    from .. import __version__, _omp

    # the compiled core may be missing on a source checkout
    try:
        core = importlib.import_module("corpuscle._core")
    except ImportError as exc:
        err(f"error: the compiled core is not available ({one_line(exc)}); build it with `pip install .`")
        return EXIT_USAGE
    info = dict(core.build_info())
    from .. import _mpi

    if _mpi.launched_rank() != 0:  # under mpiexec: rank 0 speaks for the run
        return EXIT_OK
    mpi = _mpi.describe()
    if args.json:
        print(_json.dumps({"version": __version__, "build_info": info, "openmp_policy": _omp.policy(), "mpi": mpi}))
        return EXIT_OK
    # text report
    print(f"corpuscle {__version__}")
    print(f"  core version       {info.get('version')}")
    if info.get("cuda_compiled"):
        print(f"  CUDA               compiled (architectures: {info.get('cuda_architectures') or '?'})")
    else:
        print("  CUDA               not compiled (CPU-only build)")
    omp = f"yes, {_omp.describe(info.get('omp_threads'))}" if info.get("openmp") else "no"
    print(f"  OpenMP             {omp}")
    gpus = info.get("gpus") or []
    for i, gpu in enumerate(gpus):
        mem = gpu.get("memory_gib")
        mem_text = f", {mem:.1f} GiB" if isinstance(mem, (int, float)) else ""
        print(f"  GPU {i}              {gpu.get('name')} (compute {gpu.get('compute_capability')}{mem_text})")
    if mpi["available"]:
        gpu_path = f"; GPU exchange {mpi['gpu_exchange']}" if info.get("cuda_compiled") else ""
        print(f"  MPI                {mpi['library']} (MPI {mpi['standard']}, mpi4py {mpi['mpi4py']}), "
              f"{mpi['ranks']} rank{'s' if mpi['ranks'] != 1 else ''}{gpu_path}")
    else:
        print(f"  MPI                no: {mpi['reason']}")
    if info.get("gpu_error"):
        print(f"  GPU                none usable: {one_line(info['gpu_error'])}")
    elif not gpus:
        print("  GPU                none")
    return EXIT_OK


register(Command("info", "show the version, build options and usable GPUs", _configure_info, _cmd_info))
