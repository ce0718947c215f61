#!/usr/bin/env bash
# Session 18, fifth call: M = this tree (the walk loading ahead, the automatic lane width from
# 400,000 threads), Q4 = ./tmp_q4 (M, and the next neighbour's PairVel line prefetched into L1);
# the SPH gpu tests of M; the box at 129,600, 262,144 and 1M and dsph on each.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/s18e.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
( python3 -m pip install --no-build-isolation --no-deps --target /tmp/t_q4 ./tmp_q4 > "$OUT/build_q4.log" 2>&1; echo "built q4 rc=$?" | tee -a "$log" ) &
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
say built
B="--backend cuda --no-progress"
run() { local t=$1; shift; if [ "$t" = m ]; then timeout 90 corpuscle "$@"; else PYTHONPATH=/tmp/t_$t timeout 90 python3 -m corpuscle.cli "$@"; fi; }
full() { tee -a "$OUT/bench_full.log" | grep -E "^(lists|grid)" | sed "s/^/$1 /" | tee -a "$log"; }
say gpu tests M
timeout 120 python3 -m pytest -q -m gpu tests/test_sph*.py -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests_sph.log" | grep -v "^\.\+ *\[" | tail -5 | tee -a "$log"
for t in m q4; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | full "$t 131072"; done
for t in m q4; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench dam-break-dsph $B --steps 50 --repeats 3 --warmup 10 | full "$t dsph"; done
for t in m q4; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench fluid-box $B --particles 1048576 --steps 50 --repeats 3 --warmup 10 | full "$t 1M"; done
for l in 0 4; do echo "## m lanes $l" >> "$OUT/bench_full.log"; run m bench fluid-box $B --particles 262144 --steps 100 --repeats 3 --set sph.lanes=$l | full "m lanes=$l 262144"; done
say done
