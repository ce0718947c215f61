#!/usr/bin/env bash
# Session 17, third call: the SPH box's 3-D V_j. A = ./tmp_a (main: V_j = m / rho_j, an IEEE
# division on the device), C = this tree (V_j by the fast division), D = ./tmp_d (C with the
# density diffusion's term taking m_j and rho_j, one fast division for V_j and its
# denominator), built side by side; the SPH gpu tests of C and D; fluid-box 129,600 and
# 1,056,321 and dam-break-dsph on each.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/s17c.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
for v in a d; do
  ( python3 -m pip install --no-build-isolation --no-deps --target /tmp/t_$v ./tmp_$v > "$OUT/build_$v.log" 2>&1; echo "built $v rc=$?" | tee -a "$log" ) &
done
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
say built
B="--backend cuda --no-progress"
run() { local t=$1; shift; if [ "$t" = c ]; then timeout 90 corpuscle "$@"; else PYTHONPATH=/tmp/t_$t timeout 90 python3 -m corpuscle.cli "$@"; fi; }
row() { head -2 | tail -1 | sed "s/^/$1 /" | tee -a "$log"; }
say gpu tests C
timeout 120 python3 -m pytest -q -m gpu tests/test_sph*.py -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests_c.log" | grep -v "^\.\+ *\[" | tail -5 | tee -a "$log"
say gpu tests D
(cd tmp_d && PYTHONPATH=/tmp/t_d timeout 120 python3 -m pytest -q -m gpu tests/test_sph*.py -p no:cacheprovider 2>&1) | tee "$OUT/gpu_tests_d.log" | grep -v "^\.\+ *\[" | tail -5 | tee -a "$log"
for r in 1 2; do
  say round $r
  for t in a c d; do run $t bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | row "$t 129600"; done
  for t in a c d; do run $t bench dam-break-dsph $B --steps 50 --repeats 3 --warmup 10 | row "$t dsph"; done
done
for t in a c d; do run $t bench fluid-box $B --particles 1048576 --steps 50 --repeats 3 --warmup 10 | row "$t 1M"; done
say done
