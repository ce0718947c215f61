#!/usr/bin/env bash
# Issue 11's last pieces on the GPU machine, in one call (about 10 minutes): the LBVH with its
# traversal stack in shared memory (lbvh.stack entries per thread: 512 bytes a block per entry),
# against the grid, gather and reflexive; the airfoil's edge grid; and the MP4 of the default
# 2,097,152-particle run coloured by the kind's default (number density over 0 .. 4x the free
# stream's), in which the compressed layer ahead of and under the airfoil and its wake show.
#
#   OUT=out bash benchmarks/wind_tunnel_lbvh.sh
#   QUICK=1 OUT=out bash benchmarks/wind_tunnel_lbvh.sh    # tests and the benchmarks, no MP4
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"
mkdir -p "$OUT"
python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 || { tail -30 "$OUT/build.log"; exit 1; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee "$OUT/device.txt"
date -u +%Y-%m-%dT%H:%MZ | tee -a "$OUT/device.txt"
git rev-parse --short HEAD 2>/dev/null | tee -a "$OUT/device.txt"

# 1. the tests: CUDA against the CPU (the shared-memory stack at 10 and 128 entries, its
# overflow flag on the device), the stack, the airfoil grid and the render defaults
python3 -m pytest -q tests/test_wind_tunnel_gpu.py tests/test_lbvh_stack.py tests/test_polygon_grid.py \
  tests/test_render_wind_tunnel.py tests/test_wind_tunnel_index.py 2>&1 | tee "$OUT/tests.log" | tail -3

# 2. steps per second at 2,097,152 (the default), stage times by CUDA events: the grid (the
# reference: 2,577 steps/s on 2026-12-01), the tree at four stack depths (the default 32;
# the walks of the default scene need about 5), and the reflexive forms
B="corpuscle bench wind-tunnel --backend cuda --steps 200 --repeats 5 --warmup 50 --no-progress"
$B --json "$OUT/bench_grid.json" 2>&1 | tee "$OUT/bench.log"
for stack in 8 16 32 64; do
  $B --neighbors lbvh --set lbvh.stack=$stack --json "$OUT/bench_lbvh_stack$stack.json" 2>&1 | tee -a "$OUT/bench.log"
done
for form in reflexive reflexive-warp; do
  $B --neighbors grid,lbvh --set contact.form=$form --json "$OUT/bench_$form.json" 2>&1 | tee -a "$OUT/bench.log"
done
# the sizes, both indexes
corpuscle bench wind-tunnel --backend cuda --neighbors grid,lbvh --particles 16384,262144,2097152,4194304 \
  --steps 200 --repeats 3 --warmup 50 --json "$OUT/bench_sweep.json" --no-progress 2>&1 | tee -a "$OUT/bench.log"

# 3. the default run and its MP4 (render's defaults for the kind: no colour options needed)
if [ -z "${QUICK:-}" ]; then
  corpuscle run wind-tunnel --backend cuda --every 400 --out "$OUT/wind_tunnel_default.cps" 2>&1 | tail -12
  corpuscle render "$OUT/wind_tunnel_default.cps" -o "$OUT/wind_tunnel_default.mp4" 2>&1 | tail -2
  corpuscle render "$OUT/wind_tunnel_default.cps" -o "$OUT/wind_tunnel_default_last.png" 2>&1 | tail -2
  corpuscle render "$OUT/wind_tunnel_default.cps" -o "$OUT/wind_tunnel_default_t10.png" --frame 25 2>&1 | tail -2
  # the .cps (about 1.6 GB) stays on the machine: the pictures are what comes back
  mv "$OUT/wind_tunnel_default.cps" /tmp/ 2>/dev/null || true
fi
ls -la "$OUT"
