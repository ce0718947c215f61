#!/usr/bin/env bash
# One device call for the batch speed of issue 8 (target: 4,096 scenes of 1,000 particles at
# >= 5e8 particle-steps/s on the H200): build this tree with CUDA, then at the target size
#   1. the lane widths of the pair passes (sph.lanes = 32, 16, 8; the default 0 gives 8 there),
#   2. the list rebuild by cells against the scan (sph.list_build; auto scans at 1,000),
#   3. the skin (sph.skin = 0.3 against the default 0.2),
# each `corpuscle bench magic8ball --backend cuda --particles 1000 --batch 4096 --steps 100
# --repeats 3`, then
#   4. the single default scene (engine target >= 22,000 steps/s: auto keeps 32 lanes and cells),
#      and the batch's stage profile at the defaults,
#   5. Nsight Compute's full report of the longest batch launch (benchmarks/ncu_top.py),
#   6. the gpu tests of the files this work touched.
# Results in $OUT: speed.log (the summary), bench_*.json, build.log, ncu_batch_0.txt, gpu_tests.log.
#   bash benchmarks/batch_speed_device.sh          # about 4 minutes on the H200
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"
mkdir -p "$OUT"
log="$OUT/speed.log"
say() { echo "== $*" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version,compute_cap --format=csv,noheader | tee -a "$log"
date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
git log --oneline -1 2>/dev/null | tee -a "$log"
say build
( time CORPUSCLE_CUDA_ARCHITECTURES="${CORPUSCLE_CUDA_ARCHITECTURES:-90}" python3 -m pip install --no-build-isolation --no-deps . ) \
  > "$OUT/build.log" 2>&1 || { tail -40 "$OUT/build.log" | tee -a "$log"; exit 1; }
grep real "$OUT/build.log" | tee -a "$log"

batch() {  # batch NAME [--set ...]: the target size, 100 steps x 3 repeats
  local name="$1"; shift
  timeout 60 corpuscle bench magic8ball --backend cuda --particles 1000 --batch 4096 --steps 100 --repeats 3 \
    --warmup 10 --no-progress --json "$OUT/bench_$name.json" "$@" 2>&1 | tail -4 | tee -a "$log"
}
best_lanes() {  # the width whose bench_lanes*.json reports the most particle-steps/s
  python3 - "$OUT" <<'EOF'
import glob, json, os, sys
best = (0.0, 32)
for f in glob.glob(os.path.join(sys.argv[1], "bench_lanes*.json")):
    rows = json.load(open(f))
    rate = max(float(r.get("particle_steps_per_second") or 0.0) for r in rows)
    best = max(best, (rate, int(os.path.basename(f)[len("bench_lanes"):-len(".json")])))
print(best[1])
EOF
}

say "1. lane widths at 4,096 x 1,000"
for w in 32 16 8; do
  echo "-- sph.lanes = $w" | tee -a "$log"
  batch "lanes$w" --set sph.lanes=$w
done
W=$(best_lanes)
say "fastest width: $W"
say "2. list rebuild by the cells (the scan is the default at 1,000)"
batch "cells" --set sph.lanes=$W --set sph.list_build=cells
say "3. skin (sph.lanes = $W)"
for s in 0.3; do
  echo "-- sph.skin = $s" | tee -a "$log"
  batch "skin$s" --set sph.lanes=$W --set sph.skin=$s
done
say "4. the single default scene (3,500 particles)"
timeout 40 corpuscle bench magic8ball --backend cuda --steps 2000 --repeats 5 --no-progress --json "$OUT/bench_single.json" \
  2>&1 | tail -3 | tee -a "$log"
say "4b. the batch's stage profile (defaults; ms per step over 20 eager steps)"
timeout 60 python3 benchmarks/profile_kernels.py batch --profile --steps 20 2>&1 | tail -6 | tee -a "$log"
say "5. ncu: the longest batch launch"
timeout 90 python3 benchmarks/ncu_top.py batch --out "$OUT" 2>&1 | tail -14 | tee -a "$log"
say "6. gpu tests"
timeout 120 python3 -m pytest -q -m gpu tests/test_m8_variants.py tests/test_neighbor_reuse.py tests/test_batch_api.py \
  tests/test_neighbors.py -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests.log" | tail -15 | tee -a "$log"
date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
