#!/usr/bin/env bash
# The 3-D wind tunnel (wind-tunnel-3d, issue 11) on the GPU machine, in one call: build, its
# gpu-marked tests (CUDA against the CPU), the 3-D free-molecular validation at CI size and at
# the GPU size, the benchmark (the default 2,097,152 particles and a sweep, grid and lbvh,
# gather and reflexive), a short default run rendered to MP4. Results land in $OUT.
#
#   OUT=out bash benchmarks/wind_tunnel_3d.sh            # everything (about 10 minutes)
#   QUICK=1 OUT=out bash benchmarks/wind_tunnel_3d.sh    # tests, CI validation and the 2M bench only
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"
mkdir -p "$OUT"
python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 || { tail -30 "$OUT/build.log"; exit 1; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee "$OUT/device.txt"
date -u +%Y-%m-%dT%H:%MZ | tee -a "$OUT/device.txt"

# 1. the 3-D kind's tests, the gpu-marked ones included (CUDA against the CPU)
python3 -m pytest -q tests/test_wind_tunnel_3d.py 2>&1 | tee "$OUT/wind_tunnel_3d_tests.log" | tail -3

# 2. the 3-D validation: CI size on CUDA, then the GPU size (2,097,152 particles, 1 s windows)
corpuscle validate wind-tunnel --dim 3 --backend cuda 2>&1 | tee "$OUT/validate_3d.txt" | tail -20
if [ -z "${QUICK:-}" ]; then
  corpuscle validate wind-tunnel --dim 3 --full --backend cuda 2>&1 | tee "$OUT/validate_3d_full.txt" | tail -20
fi

# 3. steps per second at the CUDA default (2,097,152 particles), per stage
corpuscle bench wind-tunnel-3d --backend cuda --steps 200 --repeats 5 --warmup 50 --json "$OUT/bench3d_2097152.json" \
  --no-progress 2>&1 | tee "$OUT/bench3d.log"
if [ -z "${QUICK:-}" ]; then
  corpuscle bench wind-tunnel-3d --backend cuda --neighbors grid,lbvh \
    --particles 16384,131072,1048576,2097152,4194304 --steps 200 --repeats 3 --warmup 50 \
    --json "$OUT/bench3d_sweep.json" --no-progress 2>&1 | tee -a "$OUT/bench3d.log"
  for form in reflexive reflexive-warp; do
    corpuscle bench wind-tunnel-3d --backend cuda --neighbors grid,lbvh --set contact.form=$form --steps 200 \
      --repeats 3 --warmup 50 --json "$OUT/bench3d_$form.json" --no-progress 2>&1 | tee -a "$OUT/bench3d.log"
  done
  # the CPU backends at their default (8,192) for the table
  corpuscle bench wind-tunnel-3d --backend serial cpu --steps 50 --repeats 3 --warmup 5 \
    --json "$OUT/bench3d_cpu.json" --no-progress 2>&1 | tee -a "$OUT/bench3d.log"
  # 4. the default run (10 s) recorded and rendered: number density, with the extruded airfoil
  corpuscle run wind-tunnel-3d --backend cuda --every 250 --out /tmp/wt3d.cps \
    --render "$OUT/wind_tunnel_3d_density.mp4" --render-color number_density 2>&1 | tail -6
  corpuscle render /tmp/wt3d.cps -o "$OUT/wind_tunnel_3d_pressure.png" --color pressure 2>&1 | tail -1
fi
# 5. the 2-D kind after the templating (its bench before/after: 2,577 steps/s at 2M on main)
corpuscle bench wind-tunnel --backend cuda --steps 200 --repeats 5 --warmup 50 --json "$OUT/bench2d_2097152.json" \
  --no-progress 2>&1 | tee "$OUT/bench2d.log"
ls -la "$OUT"
