#!/usr/bin/env bash
# Session 16, closing call: this tree (A: the batch's list walks one round at a time,
# kAhead = 1; the SPH box's automatic lanes by thread count) against BASE_TREE (f4d17f7) and
# B_TREE (A with kAhead = 4, the walks loading four rounds ahead), built side by side; the gpu
# tests of A; the 8-ball, the batch, the SPH box, the dam break and the wind tunnel.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/s16d.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
( python3 -m pip install --no-build-isolation --no-deps --target /tmp/tB "$BASE_TREE" > "$OUT/build_base.log" 2>&1; echo "built base rc=$?" | tee -a "$log" ) &
( python3 -m pip install --no-build-isolation --no-deps --target /tmp/tC "$B_TREE" > "$OUT/build_b.log" 2>&1; echo "built B rc=$?" | tee -a "$log" ) &
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
[ -d .whl ] && python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site
B="--backend cuda --no-progress"
other() { PYTHONPATH=$1:${PYTHONPATH:-} timeout 60 python3 -m corpuscle.cli "${@:2}"; }
row() { head -2 | tail -1 | sed "s/^/$1 /" | tee -a "$log"; }
say gpu tests
timeout 150 python3 -m pytest -q -m gpu $(grep -l "mark.gpu" tests/*.py) -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests.log" | grep -v "^\.\+ *\[" | tail -15 | tee -a "$log"
say batch 4096 x 1000
for r in 1 2; do
  other /tmp/tB bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 | row base
  timeout 60 corpuscle bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 | row A
  other /tmp/tC bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 | row B
done
say 8-ball single
for r in 1 2; do
  other /tmp/tB bench magic8ball $B --steps 2000 --repeats 5 | row base
  timeout 30 corpuscle bench magic8ball $B --steps 2000 --repeats 5 | row A
  other /tmp/tC bench magic8ball $B --steps 2000 --repeats 5 | row B
done
say SPH
other /tmp/tB bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | row base
timeout 60 corpuscle bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | row A
other /tmp/tB bench fluid-box $B --particles 1048576 --steps 50 --repeats 3 --warmup 10 | row base
timeout 90 corpuscle bench fluid-box $B --particles 1048576 --steps 50 --repeats 3 --warmup 10 | row A
timeout 90 corpuscle bench dam-break-dsph $B --steps 50 --repeats 3 --warmup 10 | row A
say wind tunnel
timeout 40 corpuscle bench wind-tunnel $B --steps 200 --repeats 3 --warmup 50 | row A
say done
