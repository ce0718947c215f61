#!/usr/bin/env bash
# The SPH box's `lists` pair pass with G lanes per particle (sph.lanes) and the sort, reorder
# keys and cell marks skipped on the steps that do not relist (a conditional node of the
# captured CUDA graph; CORPUSCLE_GRAPH_CONDITIONALS=0 runs them every step, as before): issue
# 9, branch sphlanes. Builds nothing (run it on a tree built with CUDA). Before/after in one
# call: "before" is sph.lanes=1 with the conditionals off (the old kernel and the old step),
# then the conditionals alone, then each width with them. fluid-box at 131,072 and 1,048,576
# particles, the DualSPHysics-matched dam break, and the gpu tests of the lists index. Results
# (JSON rows, logs) in $OUT. About 4 to 6 minutes on an H200.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"
mkdir -p "$OUT"
log="$OUT/sph_lanes.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version,compute_cap --format=csv,noheader | tee -a "$log"

say gpu tests: lanes, lists, box
python3 -m pytest -q -m gpu tests/test_sph_lanes.py tests/test_sph_lists.py tests/test_sph_box.py -p no:cacheprovider \
  2>&1 | tee "$OUT/gpu_tests.log" | tail -8 | tee -a "$log"

bench() {  # name particles steps warmup [extra args]
  local name=$1 n=$2 steps=$3 warm=$4
  shift 4
  corpuscle bench fluid-box --backend cuda --particles "$n" --neighbors lists --steps "$steps" --repeats 3 \
    --warmup "$warm" --no-progress --json "$OUT/$name.json" "$@" | tee -a "$log"
}

for n in 131072 1048576; do
  if [ "$n" = 131072 ]; then steps=200; warm=20; else steps=50; warm=10; fi
  say "fluid-box $n: before (lanes 1, sorting every step)"
  CORPUSCLE_GRAPH_CONDITIONALS=0 bench "fb${n}_before" "$n" $steps $warm --set sph.lanes=1
  say "fluid-box $n: lanes 1, sort skipped when not relisting"
  bench "fb${n}_g1" "$n" $steps $warm --set sph.lanes=1
  for g in 2 4 8; do
    say "fluid-box $n: lanes $g, sort skipped when not relisting"
    bench "fb${n}_g$g" "$n" $steps $warm --set sph.lanes=$g
  done
  say "fluid-box $n: lanes 4, sorting every step (the lanes alone)"
  CORPUSCLE_GRAPH_CONDITIONALS=0 bench "fb${n}_g4_sorting" "$n" $steps $warm --set sph.lanes=4
  say "fluid-box $n: the defaults"
  bench "fb${n}_default" "$n" $steps $warm
done

say "dam-break-dsph 1.04 M: before and the defaults"
CORPUSCLE_GRAPH_CONDITIONALS=0 corpuscle bench dam-break-dsph --backend cuda --neighbors lists --set sph.lanes=1 \
  --steps 50 --repeats 3 --warmup 10 --no-progress --json "$OUT/dsph_before.json" | tee -a "$log"
corpuscle bench dam-break-dsph --backend cuda --neighbors lists --steps 50 --repeats 3 --warmup 10 --no-progress \
  --json "$OUT/dsph_default.json" | tee -a "$log"

say done
