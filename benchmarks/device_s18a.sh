#!/usr/bin/env bash
# Session 18, first call: the SPH lists' build with lanes. A = ./tmp_a (main: a thread a slot),
# C = this tree (8 lanes a slot), w4 / w16 / w32 = ./tmp_wN (the same with N lanes), built side
# by side; the gpu tests of C; fluid-box 131,072 and 1,048,576 and dam-break-dsph on each.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/s18a.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
TREES="a w4 w16 w32"
for v in $TREES; do
  ( python3 -m pip install --no-build-isolation --no-deps --target /tmp/t_$v ./tmp_$v > "$OUT/build_$v.log" 2>&1; echo "built $v rc=$?" | tee -a "$log" ) &
done
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
say built
B="--backend cuda --no-progress"
run() { local t=$1; shift; if [ "$t" = c ]; then timeout 90 corpuscle "$@"; else PYTHONPATH=/tmp/t_$t timeout 90 python3 -m corpuscle.cli "$@"; fi; }
full() { tee -a "$OUT/bench_full.log" | grep -E "^(lists|grid)" | sed "s/^/$1 /" | tee -a "$log"; }
say gpu tests C
timeout 200 python3 -m pytest -q -m gpu tests/test_sph*.py -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests_sph.log" | grep -v "^\.\+ *\[" | tail -5 | tee -a "$log"
for t in a c w4 w16 w32; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | full "$t 131072"; done
for t in a c w4 w16 w32; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench dam-break-dsph $B --steps 50 --repeats 3 --warmup 10 | full "$t dsph"; done
for t in a c w4 w16 w32; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench fluid-box $B --particles 1048576 --steps 50 --repeats 3 --warmup 10 | full "$t 1M"; done
say round 2
for t in a c; do run $t bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | full "$t 131072"; done
for t in a c; do run $t bench dam-break-dsph $B --steps 50 --repeats 3 --warmup 10 | full "$t dsph"; done
say gpu tests all C
timeout 240 python3 -m pytest -q -m gpu tests -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests_all.log" | grep -v "^\.\+ *\[" | tail -5 | tee -a "$log"
say done
