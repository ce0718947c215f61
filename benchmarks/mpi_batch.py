"""Scene-steps per second of a batch of Magic 8-Balls spread over MPI ranks (one GPU a rank:
the node-local rank's), for the multi-GPU scaling runs (benchmarks/mpi_scaling.sh, case `batch`).

    mpiexec -n R python3 benchmarks/mpi_batch.py [--scenes-per-rank 1024] [--particles 1000]
                                                 [--steps 100] [--repeats 3] [--backend cuda]

Weak scaling: every rank holds --scenes-per-rank scenes (or --scenes N in all: strong scaling).
Each repeat times --steps batched steps on every rank (the core's clock: CUDA events on a GPU)
after a barrier; the repeat's time is the slowest rank's, and the median of the repeats is
reported. Rank 0 prints one JSON line: ranks, scenes, particles a scene, steps, seconds,
scene_steps_per_s, particle_steps_per_s, the device and the date.
"""

from __future__ import annotations

import argparse
import datetime
import json
import statistics
import sys


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes-per-rank", type=int, default=1024)
    p.add_argument("--scenes", type=int, default=0, help="scenes in all (strong scaling); 0: per rank")
    p.add_argument("--particles", type=int, default=1000)
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--warmup", type=int, default=20)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--backend", default="cuda")
    a = p.parse_args()
    from corpuscle import Batch, _core, _mpi

    comm = _mpi.world()
    rank, size = _mpi.rank_and_size(comm)
    n = a.scenes or a.scenes_per_rank * size
    b = Batch.from_scene("magic8ball", n=n, backend=a.backend, particles=a.particles, settle=0.0, shake=[],
                         comm=comm)
    b.bench_steps(a.warmup)
    times = []
    for _ in range(a.repeats):
        if comm is not None:
            comm.Barrier()
        t = b.bench_steps(a.steps)
        times.append(t if comm is None else comm.allreduce(t, op=_max_op()))
    t = statistics.median(times)
    if rank == 0:
        info = dict(_core.build_info())
        gpus = info.get("gpus") or []
        device = gpus[0].get("name") if gpus and a.backend == "cuda" else "CPU"
        print(json.dumps({"ranks": size, "scenes": n, "particles": a.particles, "steps": a.steps, "seconds": t,
                          "scene_steps_per_s": n * a.steps / t, "particle_steps_per_s": n * a.particles * a.steps / t,
                          "backend": a.backend, "device": device,
                          "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%MZ")}))
    return 0


def _max_op():
    from mpi4py import MPI

    return MPI.MAX


if __name__ == "__main__":
    sys.exit(main())
