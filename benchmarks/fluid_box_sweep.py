"""The fluid-box sweep (seed 002's tables): 128 particles, then powers of 4 from 256 to
1,048,576 (and 4,194,304 on the GPU) x {serial allpairs, serial grid, OpenMP grid, CUDA allpairs, CUDA
grid, CUDA compact, CUDA lists}, through `corpuscle bench --json`, with the mean neighbour count and the
per-stage times (CUDA events) beside every figure; then the seed's speedup tables (over
serial and over OpenMP) and a PNG plot. All-pairs rows stop where one step would take longer
than --max-step seconds (O(N^2)).

    python benchmarks/fluid_box_sweep.py --out bench-out            # every backend found
    python benchmarks/fluid_box_sweep.py --out bench-out --cpu-only --max-particles 32768

Writes OUT/fluid_box_sweep.json (every row), OUT/fluid_box_sweep.md (tables) and
OUT/fluid_box_sweep.png.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys

from corpuscle import _bench_report

CONFIGS = [("serial", "allpairs"), ("serial", "grid"), ("cpu", "grid"),
           ("cuda", "allpairs"), ("cuda", "grid"), ("cuda", "compact"), ("cuda", "lists")]


def bench(scene, backend, index, n, steps, repeats, out, extra):
    path = out / f"row_{backend}_{index}_{n}.json"
    cmd = [sys.executable, "-m", "corpuscle", "bench", scene, "--backend", backend, "--neighbors", index,
           "--particles", str(n), "--steps", str(steps), "--repeats", str(repeats), "--warmup", "5",
           "--json", str(path), "--no-progress", *extra]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        print(f"  {backend} {index} {n}: failed: {p.stderr.strip()[-300:]}", flush=True)
        return None
    return json.loads(path.read_text())[0]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="fluid-box-sweep", help="output folder")
    ap.add_argument("--scene", default="fluid-box")
    ap.add_argument("--cpu-only", action="store_true")
    ap.add_argument("--max-particles", type=int, default=4_194_304)
    ap.add_argument("--max-step", type=float, default=2.0, help="skip sizes past a step of this many seconds")
    ap.add_argument("--stages", action="store_true", help="per-stage times on the CPU as well")
    args = ap.parse_args()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # 128, then the powers of 4 from 256 to 1,048,576 (and 4,194,304 on the GPU)
    sizes = [n for n in [128] + [4 ** k for k in range(4, 12)] if n <= args.max_particles]
    rows = []
    for backend, index in CONFIGS:
        if args.cpu_only and backend == "cuda":
            continue
        for n in sizes:
            if backend != "cuda" and n > 1_048_576:
                break
            # a handful of steps for the big / slow ones, more for the quick ones
            prev = [r for r in rows if r["backend"] == backend and r["neighbors"] == index]
            step_s = 1.0 / prev[-1]["steps_per_second"] if prev else 0.0
            if prev and step_s * 4 * (4 if index == "allpairs" else 1) > args.max_step:
                break
            steps = (200 if step_s < 0.01 else 20) if backend == "cuda" else (50 if step_s < 0.005 else 10)
            extra = ["--stages"] if args.stages and backend != "cuda" else []
            r = bench(args.scene, backend, index, n, steps, 3, out, extra)
            if r is None:
                break
            rows.append(r)
            print(f"{backend:7} {index:9} {r['particles']:>9,} fluid + {r.get('wall_particles', 0):>9,} wall  "
                  f"{r['steps_per_second']:10.1f} steps/s  {r['particle_steps_per_second']:.3g} p-steps/s  "
                  f"{r.get('mean_neighbors', float('nan')):6.1f} nbrs", flush=True)
    (out / "fluid_box_sweep.json").write_text(json.dumps(rows, indent=2) + "\n")
    tables(rows, out / "fluid_box_sweep.md")
    plot(rows, out / "fluid_box_sweep.png")
    return 0


def tables(rows, path):
    """The steps/s table, the seed's speedup tables and the stage times (corpuscle._bench_report)."""
    lines = _bench_report.steps_table(rows) + [""] + _bench_report.speedup_tables(rows)
    stage_rows = [r for r in rows if r.get("stages")]
    if stage_rows:
        lines += ["", "stages (ms per step):", ""]
        for r in stage_rows:
            lines.append(f"- {r['backend']} {r['neighbors']} {r['particles']:,}: " +
                         ", ".join(f"{k} {v:.4g}" for k, v in r["stages"].items()))
    path.write_text("\n".join(lines) + "\n")
    print(path.read_text())


def plot(rows, path):
    _bench_report.plot(rows, path, title="corpuscle fluid-box")


if __name__ == "__main__":
    sys.exit(main())
