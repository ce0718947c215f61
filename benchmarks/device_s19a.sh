#!/usr/bin/env bash
# Next session's first call: two branches' SPH pair-loop changes against main, one call.
# M = this tree (main); R = ./tmp_rec (branch sphrecord: the neighbour's padded position and
# PairVel in one 32-byte record); R10 / R12 = ./tmp_r10, ./tmp_r12 (R with 10 / 12 pair blocks a
# multiprocessor: the pair pass waits on memory at 50% occupancy, 55 registers); P2 = ./tmp_p2
# (branch sphpair2 = R and the walk finding two entries, then visiting both). Make them first:
#   mkdir tmp_rec tmp_p2; git archive sphrecord | tar -x -C tmp_rec; git archive sphpair2 | tar -x -C tmp_p2
#   for b in 10 12; do mkdir tmp_r$b; git archive sphrecord | tar -x -C tmp_r$b
#     sed -i "s/kPairBlocksPerSM = 8;/kPairBlocksPerSM = $b;/" tmp_r$b/cpp/include/corpuscle/scenes/sph/pipeline.h; done
# Built side by side; every gpu test of R and P2; the box at 129,600 and 1M and dam-break-dsph
# on each, two rounds. (Remove the tmp_* trees before committing.)
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/s19a.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
TREES="rec r10 r12 p2"
for v in $TREES; do
  ( python3 -m pip install --no-build-isolation --no-deps --target /tmp/t_$v ./tmp_$v > "$OUT/build_$v.log" 2>&1; echo "built $v rc=$?" | tee -a "$log" ) &
done
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
say built
B="--backend cuda --no-progress"
run() { local t=$1; shift; if [ "$t" = m ]; then timeout 90 corpuscle "$@"; else PYTHONPATH=/tmp/t_$t timeout 90 python3 -m corpuscle.cli "$@"; fi; }
full() { tee -a "$OUT/bench_full.log" | grep -E "^(lists|grid)" | sed "s/^/$1 /" | tee -a "$log"; }
for t in rec p2; do
  say gpu tests $t
  (cd tmp_$t && PYTHONPATH=/tmp/t_$t timeout 150 python3 -m pytest -q -m gpu tests -p no:cacheprovider 2>&1) | tee "$OUT/gpu_tests_$t.log" | grep -v "^\.\+ *\[" | tail -3 | tee -a "$log"
done
for r in 1 2; do
  say round $r
  for t in m rec r10 r12 p2; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | full "$t 131072"; done
  for t in m rec r10 r12 p2; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench dam-break-dsph $B --steps 50 --repeats 3 --warmup 10 | full "$t dsph"; done
  for t in m rec r10 r12 p2; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench fluid-box $B --particles 1048576 --steps 50 --repeats 3 --warmup 10 | full "$t 1M"; done
done
say done
