#!/usr/bin/env bash
# Session 16, first device call: this tree and BASE_TREE built side by side; every gpu test;
# the wind tunnel (32-bit grid keys, the contact pass fused with the step's sums, the conveyor
# in one launch) before/after with stage times; the SPH box and the 8-ball before/after; the
# shock layer's stand-off at two restitutions (benchmarks/bow_shock.py).
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/s16a.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
if [ -n "${BASE_TREE:-}" ]; then
  ( python3 -m pip install --no-build-isolation --no-deps --target /tmp/tB "$BASE_TREE" > "$OUT/build_base.log" 2>&1; echo "built base rc=$?" | tee -a "$log" ) &
fi
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
grep -E "error" -A3 "$OUT/build.log" | head -40 | tee -a "$log"
[ -d .whl ] && python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site
B="--backend cuda --no-progress"
base() { PYTHONPATH=/tmp/tB:${PYTHONPATH:-} timeout "$1" python3 -m corpuscle.cli "${@:2}"; }
say wind tunnel base / new
for r in 1 2; do
  base 40 bench wind-tunnel $B --steps 200 --repeats 3 --warmup 50 | head -2 | tail -1 | sed "s/^/base /" | tee -a "$log"
  timeout 40 corpuscle bench wind-tunnel $B --steps 200 --repeats 3 --warmup 50 | head -2 | tail -1 | sed "s/^/new /" | tee -a "$log"
done
timeout 40 corpuscle bench wind-tunnel $B --steps 200 --repeats 3 --warmup 50 --stages 2>&1 | tail -12 | tee -a "$log"
base 40 bench wind-tunnel $B --steps 200 --repeats 3 --warmup 50 --stages 2>&1 | tail -12 | sed "s/^/base /" | tee -a "$log"
timeout 40 corpuscle bench wind-tunnel-3d $B --steps 200 --repeats 3 --warmup 50 | head -2 | tail -1 | sed "s/^/3-D new /" | tee -a "$log"
timeout 40 corpuscle bench wind-tunnel $B --particles 4194304 --steps 100 --repeats 3 --warmup 20 | head -2 | tail -1 | sed "s/^/4M new /" | tee -a "$log"
say SPH box base / new
base 60 bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | head -2 | tail -1 | sed "s/^/base /" | tee -a "$log"
timeout 60 corpuscle bench fluid-box $B --particles 131072 --steps 200 --repeats 3 | head -2 | tail -1 | sed "s/^/new /" | tee -a "$log"
say 8-ball base / new
base 30 bench magic8ball $B --steps 2000 --repeats 5 | head -2 | tail -1 | sed "s/^/base /" | tee -a "$log"
timeout 30 corpuscle bench magic8ball $B --steps 2000 --repeats 5 | head -2 | tail -1 | sed "s/^/new /" | tee -a "$log"
say gpu tests
timeout 240 python3 -m pytest -q -m gpu $(grep -l "mark.gpu" tests/*.py) -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests.log" | grep -v "^\.\+ *\[" | tail -25 | tee -a "$log"
say bow shock
timeout 120 python3 benchmarks/bow_shock.py --backend cuda --time 20 --restitution 0 0.9 --out "$OUT" 2>&1 | tail -4 | tee -a "$log"
say done
