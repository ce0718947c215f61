"""Nsight Compute's full report of the longest kernel in a few steps of one configuration.

Runs `ncu` twice over benchmarks/profile_kernels.py CASE: first the durations of every launch
(to find the longest one in the last profiled step), then `--set full` on that launch alone.

Usage: python3 benchmarks/ncu_top.py CASE [--out DIR] [--top K]
"""
import argparse
import csv
import io
import os
import subprocess
import sys

ap = argparse.ArgumentParser()
ap.add_argument("case")
ap.add_argument("--out", default=".")
ap.add_argument("--top", type=int, default=1, help="profile the K longest kernels")
ap.add_argument("--steps", type=int, default=2)
ap.add_argument("--warmup", type=int, default=10)
ap.add_argument("--extra", default="", help="extra profile_kernels.py arguments")
args = ap.parse_args()
here = os.path.dirname(os.path.abspath(__file__))
prog = [sys.executable, os.path.join(here, "profile_kernels.py"), args.case, "--steps", str(args.steps),
        "--warmup", str(args.warmup)] + args.extra.split()
ncu = ["ncu", "--clock-control", "none", "--cache-control", "none"]
r = subprocess.run(ncu + ["--csv", "--metrics", "gpu__time_duration.sum"] + prog, capture_output=True, text=True)
lines = [ln for ln in r.stdout.splitlines() if ln.startswith('"')]
rows = list(csv.DictReader(io.StringIO("\n".join(lines))))
if not rows:
    print(r.stdout[-3000:], r.stderr[-3000:])
    sys.exit(1)
launches = {}
for row in rows:
    launches[int(row["ID"])] = (row["Kernel Name"], float(row["Metric Value"].replace(",", "")), row["Metric Unit"])
ids = sorted(launches)
tail = ids[len(ids) // 2:]  # the later steps (after warm-up)
tail.sort(key=lambda i: -launches[i][1])
for i in tail[:12]:
    print(f"{args.case} launch {i}: {launches[i][1]:10.1f} {launches[i][2]}  {launches[i][0][:160]}")
for rank, i in enumerate(tail[:args.top]):
    path = os.path.join(args.out, f"ncu_{args.case}_{rank}.txt")
    r2 = subprocess.run(ncu + ["--set", "full", "--launch-skip", str(i), "--launch-count", "1", "--print-details", "all"]
                        + prog, capture_output=True, text=True)
    with open(path, "w") as f:
        f.write(r2.stdout[-200000:])
        f.write(r2.stderr[-5000:])
    print("wrote", path)
