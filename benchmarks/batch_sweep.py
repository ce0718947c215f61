"""Batches of 8-balls: steps/s, scene-steps/s and particle-steps/s over the batch size B and
the particles per scene, the speedup over running the scenes one after another, and the
cost of resetting a share of the scenes against one batched step.

    python benchmarks/batch_sweep.py --backend cuda --json batch_sweep.json
    python benchmarks/batch_sweep.py --backend cpu --batches 1 4 16 --particles 300 --steps 20   # small, here

Timings: the core's clock (CUDA events on the GPU) after a warm-up, the median of
--repeats; the reset is timed on the host around Batch.reset (a synchronised call: one
upload of the chosen scenes' turns, two kernels), and as the extra time of the step that
follows it (that step sorts and relists the restored scenes). A configuration that does not
fit in memory is reported as skipped.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

import numpy as np

from corpuscle import Batch, Simulation
from corpuscle._errors import MemoryNeedError


def median_time(fn, repeats: int) -> float:
    return statistics.median(fn() for _ in range(repeats))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--backend", default="cuda")
    p.add_argument("--batches", type=int, nargs="+", default=[1, 16, 64, 256, 1024, 4096, 16384])
    p.add_argument("--particles", type=int, nargs="+", default=[1000, 500, 3500])
    p.add_argument("--steps", type=int, default=200, help="steps per timed repeat")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--reset-share", type=float, default=0.1, help="share of the scenes reset (default 0.1)")
    p.add_argument("--settle", type=float, default=0.0,
                   help="simulated seconds each batch settles before the timing (default 0: timed from the "
                        "Poisson-disk start, as the single-scene bench; a settled batch rebuilds its lists less often)")
    p.add_argument("--max-seconds", type=float, default=60.0, help="skip a configuration whose step would take longer")
    p.add_argument("--json", default="")
    a = p.parse_args(argv)
    rows = []

    def save():  # after every row: a run cut short by a timeout keeps what it measured
        if a.json:
            with open(a.json, "w", encoding="utf-8") as f:
                json.dump(rows, f, indent=2)

    print(f"{'particles':>9} {'B':>6} {'steps/s':>10} {'scene-steps/s':>14} {'particle-steps/s':>17} "
          f"{'speedup':>8} {'step ms':>8} {'reset ms':>9} {'reset+step ms':>13}", flush=True)
    for n in a.particles:
        # the scenes one after another: one scene's steps/s
        single = Simulation.from_scene("magic8ball", backend=a.backend, particles=n, shake=[])
        single.step(20)
        t1 = median_time(lambda: single.bench_steps(a.steps), a.repeats) / a.steps
        del single
        for B in a.batches:
            row = {"particles": n, "batch": B, "backend": a.backend, "single_step_seconds": t1, "settle": a.settle}
            try:
                t0 = time.perf_counter()
                b = Batch.from_scene("magic8ball", n=B, backend=a.backend, particles=n, settle=a.settle, shake=[])
                row["init_seconds"] = time.perf_counter() - t0
            except MemoryNeedError as exc:
                row["skipped"] = str(exc)
                rows.append(row)
                save()
                print(f"{n:>9} {B:>6} skipped: {exc}", flush=True)
                continue
            b.step(10)
            # a first estimate bounds the timed steps
            est = b.bench_steps(2) / 2
            steps = max(2, min(a.steps, int(a.max_seconds / max(est, 1e-9) / max(a.repeats, 1))))
            t = median_time(lambda: b.bench_steps(steps), a.repeats) / steps
            # reset a share of the scenes: the call itself, and the step after it
            k = max(1, int(round(a.reset_share * B)))
            rng = np.random.default_rng(0)
            resets, after = [], []
            for _ in range(a.repeats):
                mask = np.zeros(B, dtype=bool)
                mask[rng.choice(B, k, replace=False)] = True
                t0 = time.perf_counter()
                b.reset(mask)
                resets.append(time.perf_counter() - t0)
                after.append(b.bench_steps(1))
            r, ra = statistics.median(resets), statistics.median(after)
            row.update({"steps": steps, "step_seconds": t, "steps_per_second": 1 / t, "scene_steps_per_second": B / t,
                        "particle_steps_per_second": B * n / t, "speedup_over_sequential": B * t1 / t,
                        "reset_scenes": k, "reset_seconds": r, "step_after_reset_seconds": ra,
                        "reset_cost_over_step": (r + ra - t) / t})
            rows.append(row)
            save()
            print(f"{n:>9} {B:>6} {1 / t:>10.1f} {B / t:>14.4g} {B * n / t:>17.4g} {B * t1 / t:>8.1f} "
                  f"{1e3 * t:>8.3f} {1e3 * r:>9.3f} {1e3 * (r + ra):>13.3f}", flush=True)
            del b
    save()
    return 0


if __name__ == "__main__":
    sys.exit(main())
