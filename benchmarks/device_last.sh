#!/usr/bin/env bash
# The session's last device call: this tree and BASE_TREE (a directory, e.g. ./tmp_base)
# built side by side; the gpu tests; the single 8-ball before/after; the batch; the SPH box's
# default (lists) and grid; the wind tunnel 2-D (with and without the inflow lattice) and 3-D;
# the default 2-D run rendered (960x540, every other frame, to come back under 16 MB).
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/last.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
if [ -n "${BASE_TREE:-}" ]; then
  ( python3 -m pip install --no-build-isolation --no-deps --target /tmp/tB "$BASE_TREE" > "$OUT/build_base.log" 2>&1; echo "built base rc=$?" | tee -a "$log" ) &
fi
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
[ -d .whl ] && python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site
say gpu tests
timeout 150 python3 -m pytest -q -m gpu $(grep -l "mark.gpu" tests/*.py) -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests.log" | grep -v "^\.\+ *\[" | tail -12 | tee -a "$log"
B="--backend cuda --no-progress"
say magic8ball single scene, base then new
for r in 1 2; do
  [ -d /tmp/tB ] && PYTHONPATH=/tmp/tB:${PYTHONPATH:-} timeout 30 python3 -m corpuscle.cli bench magic8ball $B --steps 2000 --repeats 5 | head -2 | tail -1 | sed "s/^/base /" | tee -a "$log"
  timeout 30 corpuscle bench magic8ball $B --steps 2000 --repeats 5 | head -2 | tail -1 | sed "s/^/new /" | tee -a "$log"
done
say batch 4096 x 1000
[ -d /tmp/tB ] && PYTHONPATH=/tmp/tB:${PYTHONPATH:-} timeout 40 python3 -m corpuscle.cli bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 | head -2 | tail -1 | sed "s/^/base /" | tee -a "$log"
timeout 40 corpuscle bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 | head -2 | tail -1 | sed "s/^/new /" | tee -a "$log"
timeout 40 corpuscle bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 --set sph.list_build=cells | head -2 | tail -1 | sed "s/^/cells /" | tee -a "$log"
say SPH box
timeout 60 corpuscle bench fluid-box $B --particles 131072 --neighbors lists grid --steps 200 --repeats 3 | head -3 | tee -a "$log"
timeout 60 corpuscle bench fluid-box $B --particles 1048576 --steps 50 --repeats 3 --warmup 10 | head -2 | tee -a "$log"
say wind tunnel
for r in 1 2; do timeout 40 corpuscle bench wind-tunnel $B --steps 200 --repeats 3 --warmup 50 | head -2 | tail -1 | sed "s/^/lattice /" | tee -a "$log"; done
timeout 40 corpuscle bench wind-tunnel $B --set inflow.lattice=false --steps 200 --repeats 3 --warmup 50 | head -2 | tail -1 | sed "s/^/random-height /" | tee -a "$log"
[ -d /tmp/tB ] && PYTHONPATH=/tmp/tB:${PYTHONPATH:-} timeout 40 python3 -m corpuscle.cli bench wind-tunnel $B --steps 200 --repeats 3 --warmup 50 | head -2 | tail -1 | sed "s/^/base /" | tee -a "$log"
timeout 40 corpuscle bench wind-tunnel-3d $B --steps 200 --repeats 3 --warmup 50 | head -2 | tail -1 | sed "s/^/3-D /" | tee -a "$log"
say wind tunnel default run, rendered
timeout 60 corpuscle run wind-tunnel --backend cuda --out /tmp/wt.cps --no-progress 2>&1 | grep -E "steps/s|C_L|recycled|pushouts" | tee -a "$log"
timeout 90 corpuscle render /tmp/wt.cps -o "$OUT/wind_tunnel.mp4" --size 960x540 --frames 0:101:2 -q 2>&1 | tail -2 | tee -a "$log"
timeout 30 corpuscle render /tmp/wt.cps -o "$OUT/wind_tunnel_last.png" 2>&1 | tail -1 | tee -a "$log"
ls -la "$OUT" | tee -a "$log"
say done
