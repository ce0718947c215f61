#!/usr/bin/env bash
# Session 18, fourth call: the list walk loading ahead. P = this tree (an index two entries and
# a position one entry ahead), P2 = ./tmp_p2 (an index three and a position two ahead),
# Q = ./tmp_q (P, and the next neighbour's PairVel line prefetched into L1), built side by side;
# every gpu test of P; the box and dsph on each; P's lane widths against the automatic ones.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/s18d.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
TREES="p2 q"
for v in $TREES; do
  ( python3 -m pip install --no-build-isolation --no-deps --target /tmp/t_$v ./tmp_$v > "$OUT/build_$v.log" 2>&1; echo "built $v rc=$?" | tee -a "$log" ) &
done
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
say built
B="--backend cuda --no-progress"
run() { local t=$1; shift; if [ "$t" = p ]; then timeout 90 corpuscle "$@"; else PYTHONPATH=/tmp/t_$t timeout 90 python3 -m corpuscle.cli "$@"; fi; }
full() { tee -a "$OUT/bench_full.log" | grep -E "^(lists|grid)" | sed "s/^/$1 /" | tee -a "$log"; }
say gpu tests P
timeout 240 python3 -m pytest -q -m gpu tests -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests_sph.log" | grep -v "^\.\+ *\[" | tail -5 | tee -a "$log"
for t in p p2 q; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | full "$t 131072"; done
for t in p p2 q; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench dam-break-dsph $B --steps 50 --repeats 3 --warmup 10 | full "$t dsph"; done
for t in p p2 q; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench fluid-box $B --particles 1048576 --steps 50 --repeats 3 --warmup 10 | full "$t 1M"; done
for l in 2 4; do echo "## p lanes $l" >> "$OUT/bench_full.log"; run p bench fluid-box $B --particles 131072 --steps 200 --repeats 3 --set sph.lanes=$l | full "p lanes=$l 131072"; done
for l in 2; do echo "## p lanes $l" >> "$OUT/bench_full.log"; run p bench fluid-box $B --particles 1048576 --steps 50 --repeats 3 --warmup 10 --set sph.lanes=$l | full "p lanes=$l 1M"; done
for l in 2; do echo "## p lanes $l" >> "$OUT/bench_full.log"; run p bench dam-break-dsph $B --steps 50 --repeats 3 --warmup 10 --set sph.lanes=$l | full "p lanes=$l dsph"; done
run p bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | full "p 131072 again"
say done
