#!/usr/bin/env bash
# The wind tunnel on the GPU machine (issue 11), in one call: build, the gpu-marked tests,
# the full-size free-molecular validation, the benchmark sweep over particle counts (CUDA
# events per stage), a polar and the MP4 of the default run. Results land in $OUT.
#
#   OUT=out bash benchmarks/wind_tunnel_sweep.sh            # everything (about 10 minutes)
#   QUICK=1 OUT=out bash benchmarks/wind_tunnel_sweep.sh    # tests, validation and the 2M bench only
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"
mkdir -p "$OUT"
python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 || { tail -30 "$OUT/build.log"; exit 1; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee "$OUT/device.txt"
date -u +%Y-%m-%dT%H:%MZ | tee -a "$OUT/device.txt"

# 1. CUDA against the CPU (gpu-marked) and the wind tunnel's own tests
python3 -m pytest -q -m gpu tests/test_backends.py 2>&1 | tee "$OUT/gpu_tests.log" | tail -3
python3 -m pytest -q tests/test_wind_tunnel.py tests/test_wind_tunnel_validation.py tests/test_wind_tunnel_polar.py \
  tests/test_wind_tunnel_index.py tests/test_wind_tunnel_gpu.py \
  2>&1 | tee "$OUT/wind_tunnel_tests.log" | tail -3

# 2. the validation at the GPU size (2,097,152 particles, stiffer contact, 1 s window; 11 runs of about 50,000 steps)
corpuscle validate wind-tunnel --full --backend cuda 2>&1 | tee "$OUT/validate_full.txt" | tail -25
corpuscle validate wind-tunnel --full --backend cuda --json > "$OUT/validate_full.json" 2>/dev/null || true

# 3. steps per second: the target is >= 2,500 steps/s at 2,097,152 particles (the default)
corpuscle bench wind-tunnel --backend cuda --steps 200 --repeats 5 --warmup 50 --json "$OUT/bench_2097152.json" \
  --no-progress 2>&1 | tee "$OUT/bench.log"
if [ -z "${QUICK:-}" ]; then
  # the sweep: every count with each index (one table, stage times per row)
  corpuscle bench wind-tunnel --backend cuda --neighbors grid,lbvh \
    --particles 16384,65536,262144,1048576,2097152,4194304 --steps 200 --repeats 3 --warmup 50 \
    --json "$OUT/bench_sweep.json" --no-progress 2>&1 | tee -a "$OUT/bench.log"
  # the CPU backends at the CPU default (131,072) for the same table
  corpuscle bench wind-tunnel --backend serial cpu --steps 20 --repeats 3 --warmup 5 \
    --json "$OUT/bench_cpu.json" --no-progress 2>&1 | tee -a "$OUT/bench.log"
  # the reflexive form (each pair once, atomics) at the target size, on both indexes
  for form in reflexive reflexive-warp; do
    corpuscle bench wind-tunnel --backend cuda --neighbors grid,lbvh --set contact.form=$form --steps 200 --repeats 3 \
      --warmup 50 --json "$OUT/bench_$form.json" --no-progress 2>&1 | tee -a "$OUT/bench.log"
  done
  # the all-pairs reference index (O(N^2)) at the smallest count
  corpuscle bench wind-tunnel --backend cuda --neighbors allpairs --particles 16384 --steps 50 --repeats 3 \
    --json "$OUT/bench_allpairs_16384.json" --no-progress 2>&1 | tee -a "$OUT/bench.log"
  # a collisionless gas (no index at all): the cost of the rest of the step
  corpuscle bench wind-tunnel --backend cuda --set contact.enabled=false --steps 200 --repeats 3 \
    --json "$OUT/bench_collisionless.json" --no-progress 2>&1 | tee -a "$OUT/bench.log"

  # 4. a polar of the default scene on the GPU (reduced run length: 20 s each at 2M particles is long)
  corpuscle polar wind-tunnel --aoa -10:20:5 --backend cuda --end-time 10 --out "$OUT/polar-e398" 2>&1 | tail -8

  # 5. the MP4 of the default run (the bow shock ahead of the leading edge): number density and pressure
  corpuscle run wind-tunnel --backend cuda --time 20 --every 400 --out /tmp/wt.cps \
    --render "$OUT/wind_tunnel_density.mp4" --render-color number_density 2>&1 | tail -3
  corpuscle render /tmp/wt.cps -o "$OUT/wind_tunnel_pressure.mp4" --color pressure 2>&1 | tail -2
fi
ls -la "$OUT"
