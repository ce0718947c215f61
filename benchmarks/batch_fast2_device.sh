#!/usr/bin/env bash
# The device calls for the batch speed work of branch batchfast2 (issue 8: 4,096 scenes of 1,000
# particles at >= 5e8 particle-steps/s on the H200), this tree against a base tree, in two
# calls of under 10 minutes each (the machine must stay warm between them: the builds live in
# its site-packages and /tmp/tB):
#   bash benchmarks/batch_fast2_device.sh build   # both trees built side by side, then the gpu
#                                                 # tests of the files the work touched
#   bash benchmarks/batch_fast2_device.sh bench   # 1. the single default scene (3,500 particles),
#       base then new, twice (must not be slower); 2. the batch 4,096 x 1,000, base then new,
#       twice; 3. the new tree with sph.list_build=scan, sph.lanes = 4 and 16, sph.skin = 0.15
#       and 0.1; 4. its 16-bit lists against 32-bit ones (benchmarks/batch_lists_ab.py); 5. its
#       stage profile of the batch (ms per step over 20 eager steps)
# BASE_TREE: the base tree's directory, e.g. `git archive f4d17f7 | (mkdir -p tmp_base && tar -x
# -C tmp_base)` then BASE_TREE=./tmp_base. Results appended to $OUT/fast2.log.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/fast2.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
phase="${1:-build}"
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"
git log --oneline -1 2>/dev/null | tee -a "$log"
export CORPUSCLE_CUDA_ARCHITECTURES="${CORPUSCLE_CUDA_ARCHITECTURES:-90}"

if [ "$phase" = build ]; then
  say build
  if [ -n "${BASE_TREE:-}" ]; then
    ( python3 -m pip install --no-build-isolation --no-deps --target /tmp/tB "$BASE_TREE" > "$OUT/build_base.log" 2>&1
      echo "built base rc=$?" | tee -a "$log" ) &
  fi
  ( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
  wait
  tail -3 "$OUT/build.log" | tee -a "$log"
  say gpu tests
  timeout 240 python3 -m pytest -q -m gpu tests/test_m8_variants.py tests/test_batch.py tests/test_batch_api.py \
    tests/test_magic8ball.py tests/test_neighbor_reuse.py -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests.log" | tail -8 | tee -a "$log"
  say done
  exit 0
fi

B="--backend cuda --no-progress"
base() { [ -d /tmp/tB ] && PYTHONPATH=/tmp/tB:${PYTHONPATH:-} timeout 60 python3 -m corpuscle.cli bench magic8ball $B "$@" | head -2 | tail -1 | sed "s/^/base /" | tee -a "$log"; }
new() { timeout 60 corpuscle bench magic8ball $B "$@" | head -2 | tail -1 | sed "s/^/new  /" | tee -a "$log"; }
T="--particles 1000 --batch 4096 --steps 100 --repeats 3"
say "single scene (3,500 particles)"
for r in 1 2; do base --steps 2000 --repeats 5; new --steps 2000 --repeats 5; done
say "batch 4096 x 1000"
for r in 1 2; do base $T; new $T; done
say "new: list_build=scan; lanes 4 and 16; skin 0.15 and 0.1"
new $T --set sph.list_build=scan
for w in 4 16; do new $T --set sph.lanes=$w; done
for sk in 0.15 0.1; do new $T --set sph.skin=$sk; done
say "new: 16-bit against 32-bit lists"
timeout 150 python3 benchmarks/batch_lists_ab.py 2>&1 | tail -4 | tee -a "$log"
say "new: stage profile"
timeout 90 python3 benchmarks/profile_kernels.py batch --profile --steps 20 2>&1 | tail -6 | tee -a "$log"
say done
