#!/usr/bin/env bash
# Session 18, third call: A = ./tmp_a (HEAD: the lanes build), E = ./tmp_e (the Fourtakas odd
# part by its series, Wendland's q by a stored 1 / h, one reciprocal of r^2 + eta^2 for mu and
# the diffusion), EF = this tree (E, and the lanes build reading the padded positions),
# P = ./tmp_p (EF with the list walk loading an index two entries and a position one entry
# ahead), built side by side; every gpu test of EF; the box and dsph on each.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/s18c.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
TREES="a e p"
for v in $TREES; do
  ( python3 -m pip install --no-build-isolation --no-deps --target /tmp/t_$v ./tmp_$v > "$OUT/build_$v.log" 2>&1; echo "built $v rc=$?" | tee -a "$log" ) &
done
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
say built
B="--backend cuda --no-progress"
run() { local t=$1; shift; if [ "$t" = ef ]; then timeout 90 corpuscle "$@"; else PYTHONPATH=/tmp/t_$t timeout 90 python3 -m corpuscle.cli "$@"; fi; }
full() { tee -a "$OUT/bench_full.log" | grep -E "^(lists|grid)" | sed "s/^/$1 /" | tee -a "$log"; }
say gpu tests EF
timeout 240 python3 -m pytest -q -m gpu tests -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests_sph.log" | grep -v "^\.\+ *\[" | tail -5 | tee -a "$log"
for r in 1 2; do
  for t in a e ef p; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | full "$t 131072"; done
  for t in a e ef p; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench dam-break-dsph $B --steps 50 --repeats 3 --warmup 10 | full "$t dsph"; done
done
for t in a e ef p; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench fluid-box $B --particles 1048576 --steps 50 --repeats 3 --warmup 10 | full "$t 1M"; done
say done
