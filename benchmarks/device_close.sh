#!/usr/bin/env bash
# The closing device call of the session: this tree (and BASE_TREE beside it, for the single
# 8-ball before/after), every gpu-marked test, the SPH box with and without neighbour lists,
# the batch of 8-balls at each lane width, the 2-D and 3-D wind tunnels, and the default 2-D
# run rendered. Results in $OUT/close.log (+ JSON and pictures). Needs .whl carried.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/close.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version,compute_cap --format=csv,noheader | tee -a "$log"
date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
if [ -n "${BASE_TREE:-}" ]; then
  ( python3 -m pip install --no-build-isolation --no-deps --target /tmp/tB "$BASE_TREE" > "$OUT/build_base.log" 2>&1; echo "built base rc=$?" ) &
fi
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
[ -d .whl ] && python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site
corpuscle info | head -3 | tee -a "$log"
say gpu tests
timeout 200 python3 -m pytest -q -m gpu $(grep -l "mark.gpu" tests/*.py) -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests.log" | grep -v "^\.\+ *\[" | tail -25 | tee -a "$log"
B="--backend cuda --no-progress"
say magic8ball single scene, base then new
for r in 1 2; do
  [ -d /tmp/tB ] && PYTHONPATH=/tmp/tB:${PYTHONPATH:-} timeout 30 python3 -m corpuscle.cli bench magic8ball $B --steps 2000 --repeats 5 | head -2 | tail -1 | sed "s/^/base /" | tee -a "$log"
  timeout 30 corpuscle bench magic8ball $B --steps 2000 --repeats 5 | head -2 | tail -1 | sed "s/^/new /" | tee -a "$log"
done
say batch 4096 x 1000 by lane width
[ -d /tmp/tB ] && PYTHONPATH=/tmp/tB:${PYTHONPATH:-} timeout 40 python3 -m corpuscle.cli bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 | head -2 | tail -1 | sed "s/^/base /" | tee -a "$log"
for w in 0 32 16 8; do
  timeout 40 corpuscle bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 --set sph.lanes=$w | head -2 | tail -1 | sed "s/^/lanes=$w /" | tee -a "$log"
done
timeout 40 corpuscle bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 --set sph.list_build=cells | head -2 | tail -1 | sed "s/^/list_build=cells /" | tee -a "$log"
say fluid box and dam break: grid vs lists
timeout 60 corpuscle bench fluid-box $B --particles 131072 --neighbors grid lists --steps 200 --repeats 3 | tee -a "$log"
timeout 90 corpuscle bench fluid-box $B --particles 1048576 --neighbors grid lists --steps 50 --repeats 3 --warmup 10 | tee -a "$log"
timeout 90 corpuscle bench dam-break-dsph $B --neighbors lists --steps 50 --repeats 3 --warmup 10 | tee -a "$log"
say wind tunnel 2-D and 3-D
timeout 40 corpuscle bench wind-tunnel $B --steps 200 --repeats 3 --warmup 50 | tee -a "$log"
timeout 40 corpuscle bench wind-tunnel $B --neighbors lbvh --steps 200 --repeats 3 --warmup 50 | head -2 | tail -1 | sed "s/^/lbvh /" | tee -a "$log"
for form in reflexive reflexive-warp; do
  timeout 40 corpuscle bench wind-tunnel $B --set contact.form=$form --steps 200 --repeats 3 --warmup 50 | head -2 | tail -1 | sed "s/^/$form /" | tee -a "$log"
done
timeout 90 corpuscle bench wind-tunnel $B --particles 16384,262144,1048576,4194304 --steps 200 --repeats 3 --warmup 50 | tee -a "$log"
timeout 60 corpuscle bench wind-tunnel-3d $B --steps 200 --repeats 3 --warmup 50 | tee -a "$log"
say wind tunnel default run, rendered
timeout 60 corpuscle run wind-tunnel --backend cuda --out /tmp/wt.cps --no-progress 2>&1 | tail -14 | tee -a "$log"
timeout 90 corpuscle render /tmp/wt.cps -o "$OUT/wind_tunnel.mp4" -q 2>&1 | tail -2 | tee -a "$log"
timeout 30 corpuscle render /tmp/wt.cps -o "$OUT/wind_tunnel_last.png" 2>&1 | tail -1 | tee -a "$log"
timeout 30 corpuscle render /tmp/wt.cps -o "$OUT/wind_tunnel_t10.png" --frame 50 2>&1 | tail -1 | tee -a "$log"
say wind tunnel validation on the GPU
timeout 150 corpuscle validate wind-tunnel --full --backend cuda 2>&1 | tail -30 | tee -a "$log"
timeout 60 corpuscle validate wind-tunnel --dim 3 --backend cuda 2>&1 | tail -22 | tee -a "$log"
say done
