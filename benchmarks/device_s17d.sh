#!/usr/bin/env bash
# Session 17, review: this tree (B: WarpLanes walking the cells through SubWarpLanes<32>, one
# listing walk for every width) against ./tmp_a (A, main) built beside it; the gpu tests of the
# 8-ball, the batch and the SPH lists; the single 8-ball twice and the batch 4096 x 1000 on each.
set -uo pipefail
OUT="${OUT:-out}"; log="$OUT/s17d.log"
date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
( python3 -m pip install --no-build-isolation --no-deps --target /tmp/t_a ./tmp_a > "$OUT/build_a.log" 2>&1; echo "built A rc=$?" | tee -a "$log" ) &
python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1; echo "built B rc=$?" | tee -a "$log"
wait
timeout 100 python3 -m pytest -q -m gpu tests/test_m8*.py tests/test_batch*.py tests/test_sph_lists.py tests/test_sph_lanes.py tests/test_magic8ball*.py -p no:cacheprovider 2>&1 | tail -3 | tee -a "$log"
B="--backend cuda --no-progress"
row() { head -2 | tail -1 | sed "s/^/$1 /" | tee -a "$log"; }
for r in 1 2; do
  PYTHONPATH=/tmp/t_a timeout 30 python3 -m corpuscle.cli bench magic8ball $B --steps 2000 --repeats 3 | row A
  timeout 30 corpuscle bench magic8ball $B --steps 2000 --repeats 3 | row B
done
PYTHONPATH=/tmp/t_a timeout 60 python3 -m corpuscle.cli bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 | row A
timeout 60 corpuscle bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 | row B
