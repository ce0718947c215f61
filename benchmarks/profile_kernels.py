"""A few steps of one configuration on CUDA, for `ncu` (kernel durations) or for the core's
stage profile (CUDA events between the stages of eager steps).

Usage:
  python3 benchmarks/profile_kernels.py CASE [--steps K] [--profile]
  ncu --metrics gpu__time_duration.sum --csv python3 benchmarks/profile_kernels.py CASE

CASE: batch (4,096 8-balls of 1,000 particles), magic8ball (the default scene),
wind-tunnel (2,097,152 particles), fluid-box (131,072 particles).
"""
import argparse

ap = argparse.ArgumentParser()
ap.add_argument("case", choices=["batch", "magic8ball", "wind-tunnel", "fluid-box"])
ap.add_argument("--steps", type=int, default=5)
ap.add_argument("--warmup", type=int, default=30)
ap.add_argument("--profile", action="store_true", help="print the core's stage profile instead")
ap.add_argument("--neighbors", default=None, help="fluid-box: the neighbour index (default: the kind's)")
ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="fluid-box: a scene override")
args = ap.parse_args()

from corpuscle import Batch, Simulation  # noqa: E402

if args.case == "batch":
    sim = Batch.from_scene("magic8ball", n=4096, backend="cuda", particles=1000, settle=0.0)
elif args.case == "magic8ball":
    sim = Simulation.from_scene("magic8ball", backend="cuda")
elif args.case == "wind-tunnel":
    sim = Simulation.from_scene("wind-tunnel", backend="cuda")
else:
    over = {k: float(v) for k, v in (t.split("=", 1) for t in args.set)}
    sim = Simulation.from_scene("fluid-box", backend="cuda", particles=131072, neighbors=args.neighbors,
                                overrides=over or None)
sim.core.set_end_time(1e30)
sim.step(args.warmup)
if args.profile:
    for name, ms in dict(sim.core.profile(args.steps)).items():
        print(f"{args.case:12s} {name:28s} {ms:9.4f} ms")
else:
    sim.step(args.steps)
