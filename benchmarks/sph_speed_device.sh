#!/usr/bin/env bash
# The SPH box's pair pass on the device (issue 9, "Benchmark and target"): builds nothing (run
# it on a tree already built with CUDA). Times `corpuscle bench fluid-box --backend cuda` at
# 131,072 and 1,048,576 particles for grid, compact and lists (skins 0.05, 0.1 (the default)
# and 0.2), the DualSPHysics-matched dam break (dam-break-dsph, 1.04 M fluid particles) with
# grid and lists, Nsight Compute's full report of the lists pair pass (benchmarks/ncu_top.py),
# and the gpu tests of the lists index. Results (JSON rows, logs, ncu report) in $OUT. About 3
# to 4 minutes on an H200.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"
mkdir -p "$OUT"
log="$OUT/sph_speed.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version,compute_cap --format=csv,noheader | tee -a "$log"

say gpu tests of the lists index
python3 -m pytest -q -m gpu tests/test_sph_lists.py -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests_lists.log" | tail -8

say fluid-box 131072: grid, compact, lists
corpuscle bench fluid-box --backend cuda --particles 131072 --neighbors grid compact lists --steps 200 --repeats 3 \
  --no-progress --json "$OUT/fluid_box_131072.json" | tee -a "$log"
for skin in 0.05 0.2; do
  say fluid-box 131072: lists, sph.skin=$skin
  corpuscle bench fluid-box --backend cuda --particles 131072 --neighbors lists --set sph.skin=$skin --steps 200 \
    --repeats 3 --no-progress --json "$OUT/fluid_box_131072_skin$skin.json" | tee -a "$log"
done

say fluid-box 1048576: grid, compact, lists
corpuscle bench fluid-box --backend cuda --particles 1048576 --neighbors grid compact lists --steps 50 --repeats 3 \
  --warmup 10 --no-progress --json "$OUT/fluid_box_1048576.json" | tee -a "$log"
for skin in 0.05 0.2; do
  say fluid-box 1048576: lists, sph.skin=$skin
  corpuscle bench fluid-box --backend cuda --particles 1048576 --neighbors lists --set sph.skin=$skin --steps 50 \
    --repeats 3 --warmup 10 --no-progress --json "$OUT/fluid_box_1048576_skin$skin.json" | tee -a "$log"
done

say dam-break-dsph 1.04 M: grid, lists
corpuscle bench dam-break-dsph --backend cuda --neighbors grid lists --steps 50 --repeats 3 --warmup 10 --no-progress \
  --json "$OUT/dsph_1040000.json" | tee -a "$log"

say ncu: the lists pair pass at 131072
python3 benchmarks/ncu_top.py fluid-box --out "$OUT" --extra="--neighbors lists" 2>&1 | tail -20 | tee -a "$log"

say done
