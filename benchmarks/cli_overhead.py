"""Where the CLI main job's time goes beside the bench's stepping (CUDA by default).

Builds the default scene several times and times, on the same GPU: one step() call for the
whole run, step() in the CLI's chunks without frames, with the frames downloaded, and with
them written by the frame sink (with the interpreter's default 5 ms switch interval, and
with 0.5 ms as the CLI sets), against `bench`. Prints one JSON line per variant.

Usage: python3 benchmarks/cli_overhead.py [--backend cuda] [--every 100] [--repeats 3]
"""
import argparse
import json
import os
import statistics
import sys
import tempfile
import time

from corpuscle import io
from corpuscle._frame_sink import FrameSink
from corpuscle.simulation import Simulation

ap = argparse.ArgumentParser()
ap.add_argument("--backend", default="cuda")
ap.add_argument("--every", type=int, default=100)
ap.add_argument("--repeats", type=int, default=3)
ap.add_argument("--end", type=float, default=5.0)
args = ap.parse_args()


def fresh():
    sim = Simulation.from_scene("magic8ball", backend=args.backend)
    sim.set_end_time(args.end)
    _ = sim.steps  # the scalars read once, as the CLI does before its loop
    return sim


def run(variant):
    sys.setswitchinterval(0.0005 if variant == "sink-switch" else 0.005)
    sim = fresh()
    host = {"step": 0.0, "frame": 0.0, "put": 0.0}
    d = tempfile.mkdtemp()
    writer = io.FrameWriter(os.path.join(d, "o.cps"), sim.header()) if variant.startswith("sink") else None
    sink = FrameSink(writer) if writer else None
    t0 = time.perf_counter()
    if variant == "one-call":
        sim.step(10**9)
    else:
        while True:
            now = int(sim.steps)
            k = (now // args.every + 1) * args.every - now
            a = time.perf_counter()
            taken = int(sim.step(k))
            b = time.perf_counter()
            host["step"] += b - a
            if taken == 0 or sim.check_health():
                break
            if variant in ("frames", "sink", "sink-switch"):
                rec = sim.frame()
                c = time.perf_counter()
                host["frame"] += c - b
                if sink:
                    sink.put(sim.steps, sim.time, sim.dt, rec, "frame")
                    host["put"] += time.perf_counter() - c
            if sim.time >= args.end:
                break
    if sink:
        sink.close()
        writer.close()
    wall = time.perf_counter() - t0
    return int(sim.steps), wall, host


out = {}
for variant in ("one-call", "chunks", "frames", "sink", "sink-switch"):
    rows = [run(variant) for _ in range(args.repeats)]
    steps = rows[0][0]
    walls = [r[1] for r in rows]
    w = statistics.median(walls)
    h = rows[walls.index(w)][2] if w in walls else rows[0][2]
    out[variant] = steps / w
    print(json.dumps({"variant": variant, "steps": steps, "wall_s": round(w, 5), "steps_per_second": round(steps / w),
                      "host_s": {k: round(v, 5) for k, v in h.items()}}))
sim = fresh()
print(json.dumps({"variant": "bench", "steps_per_second": round(2000 / sim.bench_steps(2000))}))
