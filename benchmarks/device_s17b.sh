#!/usr/bin/env bash
# Session 17, second call: main (A) against ./tmp_s (S: main plus the batchfast2 commits that
# measured faster one at a time, the stencil ranges W at a time and the segment sort), built
# side by side; S's gpu tests; the batch 4096 x 1000 and the single 8-ball on both, twice; S's
# batch sweep at 1,000 particles a scene.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/s17b.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
( python3 -m pip install --no-build-isolation --no-deps --target /tmp/t_a . > "$OUT/build_a.log" 2>&1; echo "built A rc=$?" | tee -a "$log" ) &
( cd tmp_s && time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
say built
B="--backend cuda --no-progress"
A() { PYTHONPATH=/tmp/t_a timeout 60 python3 -m corpuscle.cli "$@"; }
S() { timeout 60 corpuscle "$@"; }
row() { head -2 | tail -1 | sed "s/^/$1 /" | tee -a "$log"; }
say gpu tests of S
(cd tmp_s && timeout 200 python3 -m pytest -q -m gpu $(grep -l "mark.gpu" tests/*.py) -p no:cacheprovider 2>&1) | tee "$OUT/gpu_tests.log" | grep -v "^\.\+ *\[" | tail -8 | tee -a "$log"
say batch 4096 x 1000
for r in 1 2; do
  A bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 | row A
  S bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 | row S
done
say 8-ball single
for r in 1 2; do
  A bench magic8ball $B --steps 2000 --repeats 3 | row A
  S bench magic8ball $B --steps 2000 --repeats 3 | row S
done
say S batch sweep
timeout 200 corpuscle bench magic8ball $B --particles 1000 --batch 1 64 1024 4096 16384 --steps 50 --repeats 3 2>&1 | tee -a "$log"
say done
