#!/usr/bin/env bash
# Session 17, first call: the batchfast2 commits one at a time. This tree (A, main) and the
# trees ./tmp_p1 ... ./tmp_p5 (main plus the first k of the branch's five commits: 16-bit
# lists, load-ahead, one-pass relisting, stencil ranges, segment sort), built side by side;
# the gpu tests of A; the batch 4096 x 1000 and the single 8-ball on every tree, twice.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/s17a.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
V="${VARIANTS:-p1 p2 p3 p4 p5}"
for v in $V; do
  ( python3 -m pip install --no-build-isolation --no-deps --target /tmp/t_$v ./tmp_$v > "$OUT/build_$v.log" 2>&1; echo "built $v rc=$?" | tee -a "$log" ) &
done
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
say built
B="--backend cuda --no-progress"
other() { PYTHONPATH=/tmp/t_$1 timeout 60 python3 -m corpuscle.cli "${@:2}"; }
row() { head -2 | tail -1 | sed "s/^/$1 /" | tee -a "$log"; }
say gpu tests
timeout 120 python3 -m pytest -q -m gpu tests/test_sph_lists.py tests/test_sph_lanes.py tests/test_m8_variants.py -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests.log" | grep -v "^\.\+ *\[" | tail -8 | tee -a "$log"
say batch 4096 x 1000
for r in 1 2; do
  timeout 60 corpuscle bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 | row A
  for v in $V; do other $v bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 | row $v; done
done
say 8-ball single
timeout 30 corpuscle bench magic8ball $B --steps 2000 --repeats 3 | row A
for v in $V; do other $v bench magic8ball $B --steps 2000 --repeats 3 | row $v; done
say done
