#!/usr/bin/env bash
# Session 18, second call: the SPH pair pass's special functions. A = ./tmp_a (HEAD: the lanes
# build), S = this tree (the Fourtakas odd part by its series, no powers), E = ./tmp_e (S with
# Wendland's q = r / h by a stored 1 / h and one reciprocal of r^2 + eta^2 for mu and the
# diffusion), built side by side; the SPH gpu tests of S; the box and dsph on each; ncu of S's
# two longest launches in the box.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/s18b.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
TREES="a e"
for v in $TREES; do
  ( python3 -m pip install --no-build-isolation --no-deps --target /tmp/t_$v ./tmp_$v > "$OUT/build_$v.log" 2>&1; echo "built $v rc=$?" | tee -a "$log" ) &
done
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
say built
B="--backend cuda --no-progress"
run() { local t=$1; shift; if [ "$t" = s ]; then timeout 90 corpuscle "$@"; else PYTHONPATH=/tmp/t_$t timeout 90 python3 -m corpuscle.cli "$@"; fi; }
full() { tee -a "$OUT/bench_full.log" | grep -E "^(lists|grid)" | sed "s/^/$1 /" | tee -a "$log"; }
say gpu tests S
timeout 200 python3 -m pytest -q -m gpu tests/test_sph*.py -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests_sph.log" | grep -v "^\.\+ *\[" | tail -5 | tee -a "$log"
for r in 1 2; do
  for t in a s e; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | full "$t 131072"; done
  for t in a s e; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench dam-break-dsph $B --steps 50 --repeats 3 --warmup 10 | full "$t dsph"; done
done
for t in a s e; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench fluid-box $B --particles 1048576 --steps 50 --repeats 3 --warmup 10 | full "$t 1M"; done
say ncu S
timeout 240 python3 benchmarks/ncu_top.py fluid-box --top 2 --out "$OUT" 2>&1 | tail -14 | tee -a "$log"
say done
