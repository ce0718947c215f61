#!/usr/bin/env bash
# The session's closing device call: build this tree (and BASE_TREE beside it when given), every
# gpu-marked test, the 8-ball against the base, the CLI main job, the batch at its target size,
# the SPH box and dam break at the sizes, the wind tunnel at 2M, and the learner on the
# GPU. Results in $OUT/final.log. Needs the gymnasium wheels in .whl (carried).
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/final.log"
say() { echo "== $*" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version,compute_cap --format=csv,noheader | tee -a "$log"
date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
if [ -n "${BASE_TREE:-}" ]; then
  ( python3 -m pip install --no-build-isolation --no-deps --target /tmp/tB "$BASE_TREE" > "$OUT/build_base.log" 2>&1; echo "built base rc=$?" ) &
fi
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
wait
[ -d .whl ] && python3 -m pip install -q --no-index --no-deps --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site
corpuscle info | tee -a "$log"
say gpu tests
timeout 300 python3 -m pytest -q -m gpu $(grep -l "mark.gpu" tests/*.py) -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests.log" | grep -v "^\.\+ *\[" | tail -30 | tee -a "$log"
say magic8ball single scene, base then new
for r in 1 2; do
  [ -d /tmp/tB ] && PYTHONPATH=/tmp/tB:${PYTHONPATH:-} python3 -m corpuscle.cli bench magic8ball --backend cuda --steps 2000 --repeats 5 --no-progress | head -2 | tail -1 | sed "s/^/base /" | tee -a "$log"
  corpuscle bench magic8ball --backend cuda --steps 2000 --repeats 5 --no-progress | head -2 | tail -1 | sed "s/^/new /" | tee -a "$log"
done
for r in 1 2; do corpuscle run magic8ball --backend cuda --out /tmp/n.cps --json | python3 -c "import json,sys; d=json.load(sys.stdin); print('cli main job', round(d['steps_per_second']), 'steps/s', d['frames'], 'frames')" | tee -a "$log"; done
say batch of 8-balls
timeout 120 corpuscle bench magic8ball --backend cuda --particles 1000 --batch 1 1024 4096 16384 --steps 100 --repeats 3 --no-progress | tee -a "$log"
timeout 150 python3 benchmarks/batch_sweep.py --backend cuda --batches 4096 --particles 1000 --settle 0.5 --steps 100 \
  --repeats 3 --json "$OUT/batch_settled.json" 2>&1 | tail -3 | tee -a "$log"
say wind tunnel
timeout 60 corpuscle bench wind-tunnel --backend cuda --steps 200 --repeats 3 --warmup 50 --no-progress | tee -a "$log"
for c in 0.001 0.0014 0.00184 0.0026; do
  timeout 60 corpuscle bench wind-tunnel --backend cuda --set grid.cell=$c --steps 200 --repeats 3 --warmup 50 --no-progress | head -2 | tail -1 | sed "s/^/grid.cell=$c /" | tee -a "$log"
done
timeout 60 corpuscle bench wind-tunnel --backend cuda --neighbors lbvh --steps 200 --repeats 3 --warmup 50 --no-progress 2>&1 | tee -a "$log"
