"""``corpuscle info``: the version, the build's options and the usable GPUs."""

from __future__ import annotations

import argparse
import importlib

from .. import _json
from ._options import EXIT_OK, EXIT_USAGE, Command, err, one_line, register


def _configure_info(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.add_argument("--memory", metavar="SCENE", nargs="?", const="dam-break-dsph-building",
                   help="bytes per particle of an SPH scene (default: dam-break-dsph-building) with each index, and "
                        "the most particles the backend's memory holds so")
    p.add_argument("--backend", default=None, help="with --memory: the backend whose memory counts (default: cuda "
                                                   "when a GPU is usable, else cpu)")


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
    if args.memory is not None:
        return _memory(args, info)
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


def _memory(args: argparse.Namespace, info: dict) -> int:
    """`info --memory SCENE`: bytes per particle and the largest scene, per index."""
    from .. import _solution
    from ..scene import SceneError, load_scene

    backend = args.backend or ("cuda" if info.get("gpus") else "cpu")
    if backend not in ("cuda", "cpu", "serial"):
        err(f"error: --backend must be cuda, cpu or serial, got {backend!r}")
        return EXIT_USAGE
    try:
        from ..kinds import find
        from ..kinds._sph_box import SphBox

        scene = load_scene(args.memory)
        if not isinstance(find(scene.kind), SphBox):
            raise SceneError(f"--memory {args.memory}: not an SPH box scene (kind {scene.kind})")
        rows = _solution.memory_table(scene, backend)
    except (SceneError, ValueError, OSError) as exc:
        err(f"error: {one_line(exc)}")
        return EXIT_USAGE
    if args.json:
        print(_json.dumps({"scene": scene.name, "backend": backend, "rows": rows}))
        return EXIT_OK
    where = rows[0]["where"] if rows else ""
    have = rows[0]["memory"] if rows else None
    print(f"{scene.name} on {backend}" + (f" ({have / 1e9:.1f} GB {where})" if have else "") + ":")
    print(f"  {'index':<16} {'bytes/particle':>15} {'largest scene (particles)':>26}")
    for r in rows:
        name = r["index"] + (f" ({r['list_storage']})" if r["list_storage"] else "")
        most = f"{r['largest_particles']:,}" if r["largest_particles"] else "?"
        print(f"  {name:<16} {r['bytes_per_particle']:>15,.0f} {most:>26}")
    return EXIT_OK


register(Command("info", "show the version, build options and usable GPUs", _configure_info, _cmd_info))
