#!/usr/bin/env bash
# Mid-session device call: build, every gpu-marked test, the learner on the GPU, the batch's
# neighbour-list skin sweep, and the default wind-tunnel run rendered with flow colourings.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/mid.log"
say() { echo "== $*" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
[ -d .whl ] && python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site
say gpu tests
timeout 300 python3 -m pytest -q -m gpu $(grep -l "mark.gpu" tests/*.py) -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests.log" | grep -v "^\.\+ *\[" | tail -15 | tee -a "$log"
say batch skin sweep
for s in 0.2 0.3 0.4 0.6; do timeout 60 corpuscle bench magic8ball --backend cuda --particles 1000 --batch 4096 --steps 100 --repeats 3 --set sph.skin=$s --no-progress 2>&1 | head -2 | tail -1 | sed "s/^/skin=$s /" | tee -a "$log"; done
say wind tunnel renders
timeout 60 corpuscle run wind-tunnel --backend cuda --out /tmp/wt.cps --velocity --no-progress --json > /dev/null
for c in number_density speed; do timeout 100 corpuscle render /tmp/wt.cps -o "$OUT/wt_$c.mp4" --color $c --linear --frames 0:101:2 -q 2>&1 | tail -2 | tee -a "$log"; done
say learner
( time timeout 330 python3 examples/rig_the_8ball.py --backend cuda --particles 1000 --population 256 --scenes 16 \
    --iterations 10 --dt-max 1.5e-3 --plot "$OUT/rig_gpu.png" --json "$OUT/rig_gpu.json" ) 2>&1 | tail -25 | tee -a "$log"
