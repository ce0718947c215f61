#!/usr/bin/env bash
# Session 16, the merged tree (sphlanes + batchfast2 + the wind tunnel's changes) against
# BASE_TREE (f4d17f7, the session's start) in one call: every gpu test; the 8-ball single
# scene and the batch; the SPH box (lanes, the skipped sort) and the DualSPHysics-matched dam
# break; the wind tunnel's default (elastic gas) bench, 3-D, and its default run recorded and
# rendered. Results in $OUT/s16c.log.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/s16c.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
if [ -n "${BASE_TREE:-}" ]; then
  ( python3 -m pip install --no-build-isolation --no-deps --target /tmp/tB "$BASE_TREE" > "$OUT/build_base.log" 2>&1; echo "built base rc=$?" | tee -a "$log" ) &
fi
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
grep -E " error" -A3 "$OUT/build.log" | head -30 | tee -a "$log"
[ -d .whl ] && python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site
B="--backend cuda --no-progress"
base() { PYTHONPATH=/tmp/tB:${PYTHONPATH:-} timeout "$1" python3 -m corpuscle.cli "${@:2}"; }
row() { head -2 | tail -1 | sed "s/^/$1 /" | tee -a "$log"; }
say gpu tests
timeout 200 python3 -m pytest -q -m gpu $(grep -l "mark.gpu" tests/*.py) -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests.log" | grep -v "^\.\+ *\[" | tail -25 | tee -a "$log"
say 8-ball single scene
for r in 1 2; do
  base 30 bench magic8ball $B --steps 2000 --repeats 5 | row base
  timeout 30 corpuscle bench magic8ball $B --steps 2000 --repeats 5 | row new
done
say batch 4096 x 1000
for r in 1 2; do
  base 60 bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 | row base
  timeout 60 corpuscle bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 | row new
done
for w in 4; do timeout 60 corpuscle bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 --set sph.lanes=$w | row "lanes=$w"; done
timeout 60 corpuscle bench magic8ball $B --particles 1000 --batch 16384 --steps 50 --repeats 3 | row "16384 new"
timeout 60 corpuscle bench magic8ball $B --particles 3500 --batch 1024 --steps 50 --repeats 3 | row "1024x3500 new"
say SPH box 131072
base 60 bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | row base
timeout 60 corpuscle bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | row new
CORPUSCLE_GRAPH_CONDITIONALS=0 timeout 60 corpuscle bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | row "new-no-conditionals"
for g in 1 2 8; do timeout 60 corpuscle bench fluid-box $B --particles 131072 --steps 200 --repeats 3 --set sph.lanes=$g | row "lanes=$g"; done
say SPH box 1M and dam break
base 90 bench fluid-box $B --particles 1048576 --steps 50 --repeats 3 --warmup 10 | row base
timeout 90 corpuscle bench fluid-box $B --particles 1048576 --steps 50 --repeats 3 --warmup 10 | row new
for g in 1 2 8; do timeout 90 corpuscle bench fluid-box $B --particles 1048576 --steps 50 --repeats 3 --warmup 10 --set sph.lanes=$g | row "lanes=$g"; done
base 90 bench dam-break-dsph $B --steps 50 --repeats 3 --warmup 10 | row base
timeout 90 corpuscle bench dam-break-dsph $B --steps 50 --repeats 3 --warmup 10 | row new
say wind tunnel
timeout 40 corpuscle bench wind-tunnel $B --steps 200 --repeats 3 --warmup 50 | row default
timeout 40 corpuscle bench wind-tunnel-3d $B --steps 200 --repeats 3 --warmup 50 | row 3-D
timeout 80 corpuscle run wind-tunnel --backend cuda --out /tmp/wt.cps --no-progress 2>&1 | grep -E "steps/s|C_L|pushouts|recycled" | tee -a "$log"
timeout 120 corpuscle render /tmp/wt.cps -o "$OUT/wind_tunnel.mp4" --size 960x540 --frames 0:101:2 -q 2>&1 | tail -2 | tee -a "$log"
timeout 30 corpuscle render /tmp/wt.cps -o "$OUT/wind_tunnel_last.png" -q 2>&1 | tail -1 | tee -a "$log"
timeout 30 corpuscle render /tmp/wt.cps -o "$OUT/wind_tunnel_t10.png" --frame 50 -q 2>&1 | tail -1 | tee -a "$log"
rm -f /tmp/wt.cps
timeout 60 corpuscle run wind-tunnel-3d --backend cuda --time 5 --out /tmp/wt3.cps --no-progress 2>&1 | grep -E "steps/s|C_L|pushouts" | tee -a "$log"
rm -f /tmp/wt3.cps
say done
