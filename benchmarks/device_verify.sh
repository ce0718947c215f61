#!/usr/bin/env bash
# One device call: build this tree, every gpu-marked test, the wind tunnel at 2M (grid, lbvh),
# Nsight Compute full reports of the longest kernels (fluid box, batch of 8-balls, 8-ball),
# and the default wind-tunnel run recorded and rendered to an MP4 (needs imageio-ffmpeg in .whl).
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/verify.log"
say() { echo "== $*" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version,compute_cap --format=csv,noheader | tee -a "$log"
date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
[ -d .whl ] && python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site
corpuscle info | tee -a "$log"
say gpu tests
timeout 330 python3 -m pytest -q -x -m gpu $(grep -l "mark.gpu" tests/*.py) -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests.log" | grep -v "^\.\+ *\[" | tail -30 | tee -a "$log"
say wind tunnel
timeout 60 corpuscle bench wind-tunnel --backend cuda --steps 200 --repeats 3 --warmup 50 --no-progress | tee -a "$log"
say ncu
for c in fluid-box batch; do timeout 120 python3 benchmarks/ncu_top.py $c --out "$OUT" 2>&1 | tee -a "$log"; done
say wind tunnel default run, recorded and rendered
( time timeout 90 corpuscle run wind-tunnel --backend cuda --out /tmp/wt.cps --no-progress ) 2>&1 | tail -25 | tee -a "$log"
ls -la /tmp/wt.cps | tee -a "$log"
( time timeout 150 corpuscle render /tmp/wt.cps -o "$OUT/wind_tunnel.mp4" --size 1280x720 -q ) 2>&1 | tail -5 | tee -a "$log"
ls -la "$OUT" | tee -a "$log"
