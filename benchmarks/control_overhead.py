"""Stepping with and without a control change every step (Simulation.set_control before each
step(1)), on one backend: steps/s of both and their ratio. The aim: a
control set every step costs no more than 1.2x stepping without it.

    python3 benchmarks/control_overhead.py --backend cuda --steps 2000
"""
import argparse
import json
import math
import statistics
import time

import corpuscle


def rate(sim, steps, control):
    t0 = time.perf_counter()
    for k in range(steps):
        if control:
            a = 3.0 * math.sin(0.01 * k)
            sim.set_control(acceleration=(a, 0.0, 0.0), torque=(0.0, 0.0, 0.001 * a))
        sim.step(1)
    return steps / (time.perf_counter() - t0)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--backend", default="cuda")
    ap.add_argument("--particles", type=int, default=3500)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    sim = corpuscle.Simulation.from_scene("magic8ball", backend=args.backend, particles=args.particles)
    sim.set_end_time(math.inf)
    sim.step(200)
    plain, ctl = [], []
    for _ in range(args.repeats):
        plain.append(rate(sim, args.steps, False))
        ctl.append(rate(sim, args.steps, True))
    row = {"backend": args.backend, "particles": args.particles, "steps": args.steps,
           "steps_per_second_plain": statistics.median(plain), "steps_per_second_control": statistics.median(ctl)}
    row["cost_ratio"] = row["steps_per_second_plain"] / row["steps_per_second_control"]
    print(json.dumps(row))


if __name__ == "__main__":
    main()
