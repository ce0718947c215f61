"""The batch's neighbour lists at 16 bits against 32 (the same run bit for bit, so only the
speed differs): one Batch's parameters and start state stepped by the core twice, with
`wide_lists` 0 (16-bit scene-local numbers, the default where they fit) and 1 (32-bit slots).

Usage: python3 benchmarks/batch_lists_ab.py [--backend cuda] [--n 4096] [--particles 1000]
         [--steps 100] [--repeats 3] [--warmup 20]
Prints steps/s and particle-steps/s for each width (the median of the repeats).
"""
import argparse
import gc
import statistics

ap = argparse.ArgumentParser()
ap.add_argument("--backend", default="cuda")
ap.add_argument("--n", type=int, default=4096)
ap.add_argument("--particles", type=int, default=1000)
ap.add_argument("--steps", type=int, default=100)
ap.add_argument("--repeats", type=int, default=3)
ap.add_argument("--warmup", type=int, default=20)
args = ap.parse_args()

from corpuscle import Batch, _core  # noqa: E402

b = Batch.from_scene("magic8ball", n=args.n, backend=args.backend, particles=args.particles, settle=0.0)
params = dict(b.params)
arrays = {"position": b.field("position", copy=True), "velocity": b.field("velocity", copy=True)}
del b
gc.collect()
for wide in (0, 1, 0, 1):
    sim = _core.Simulation("magic8ball", args.backend, "lists", {**params, "wide_lists": wide}, arrays)
    assert sim.scalars(0)["narrow_lists"] == 1 - wide
    sim.set_end_time(float("inf"))
    sim.step(args.warmup)
    t = statistics.median(float(sim.bench(args.steps)) for _ in range(args.repeats))
    n = args.n * args.particles
    print(f"{'32' if wide else '16'}-bit lists: {args.steps / t:8.1f} steps/s  {n * args.steps / t:.3e} particle-steps/s")
    del sim
    gc.collect()
