#!/usr/bin/env bash
# One device call for the batch speed work of branch batchfast2 (issue 8: 4,096 scenes of 1,000
# particles at >= 5e8 particle-steps/s on the H200): this tree and a base tree built side by
# side, then
#   1. the gpu tests of the files the work touched,
#   2. the single default scene (3,500 particles), base then new, twice (must not be slower),
#   3. the batch 4,096 x 1,000, base then new, twice; the new tree with sph.list_build=scan,
#      sph.lanes = 4 and 16, and sph.skin = 0.15 and 0.1,
#   4. the new tree's 16-bit lists against 32-bit ones (benchmarks/batch_lists_ab.py),
#   5. the new tree's stage profile of the batch (ms per step over 20 eager steps).
# Results in $OUT/fast2.log.
#   git archive f4d17f7 | (mkdir -p tmp_base && tar -x -C tmp_base)
#   BASE_TREE=./tmp_base bash benchmarks/batch_fast2_device.sh       # about 20 minutes with the builds
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/fast2.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"
git log --oneline -1 2>/dev/null | tee -a "$log"
export CORPUSCLE_CUDA_ARCHITECTURES="${CORPUSCLE_CUDA_ARCHITECTURES:-90}"
if [ -n "${BASE_TREE:-}" ]; then
  ( python3 -m pip install --no-build-isolation --no-deps --target /tmp/tB "$BASE_TREE" > "$OUT/build_base.log" 2>&1; echo "built base rc=$?" | tee -a "$log" ) &
fi
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
say gpu tests
timeout 300 python3 -m pytest -q -m gpu tests/test_m8_variants.py tests/test_batch.py tests/test_batch_api.py \
  tests/test_magic8ball.py tests/test_neighbor_reuse.py -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests.log" | tail -8 | tee -a "$log"
B="--backend cuda --no-progress"
base() { [ -d /tmp/tB ] && PYTHONPATH=/tmp/tB:${PYTHONPATH:-} timeout 60 python3 -m corpuscle.cli bench magic8ball $B "$@" | head -2 | tail -1 | sed "s/^/base /" | tee -a "$log"; }
new() { timeout 60 corpuscle bench magic8ball $B "$@" | head -2 | tail -1 | sed "s/^/new  /" | tee -a "$log"; }
say "single scene (3,500 particles)"
for r in 1 2; do base --steps 2000 --repeats 5; new --steps 2000 --repeats 5; done
say "batch 4096 x 1000"
for r in 1 2; do
  base --particles 1000 --batch 4096 --steps 100 --repeats 3
  new --particles 1000 --batch 4096 --steps 100 --repeats 3
done
say "new, list_build=scan"
new --particles 1000 --batch 4096 --steps 100 --repeats 3 --set sph.list_build=scan
say "new, other lane widths (the default at this size is 8)"
for w in 4 16; do new --particles 1000 --batch 4096 --steps 100 --repeats 3 --set sph.lanes=$w; done
say "new, a narrower skin (relisting is cheaper now; the default is 0.2)"
for sk in 0.15 0.1; do new --particles 1000 --batch 4096 --steps 100 --repeats 3 --set sph.skin=$sk; done
say "16-bit against 32-bit lists (new tree)"
timeout 200 python3 benchmarks/batch_lists_ab.py 2>&1 | tail -4 | tee -a "$log"
say "stage profile (new tree)"
timeout 90 python3 benchmarks/profile_kernels.py batch --profile --steps 20 2>&1 | tail -6 | tee -a "$log"
say done
