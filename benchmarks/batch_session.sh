#!/usr/bin/env bash
# One device call for the batch issue (8): build this tree with CUDA, the batch gpu tests
# (CUDA vs CPU, DLPack zero-copy), the sweep over B and particles per scene with the reset
# cost, the CLI's --batch bench at the target size, and the GPU run of the learner.
# Results in $OUT (session.log, batch_sweep.json, rig_gpu.json, rig_gpu.png).
#   bash benchmarks/batch_session.sh bench   # build, gpu tests, --batch bench, sweep (~7 min)
#   bash benchmarks/batch_session.sh learn   # build, the learner at 4,096 scenes (~5 min)
# Gymnasium is not on the device image: carry its wheels in .whl (gymnasium and
# farama_notifications; `pip download --no-deps -d .whl gymnasium==1.4.0 farama-notifications`)
# and name .whl in carry; they are installed below when present.
set -uo pipefail
part="${1:-bench}"
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"
mkdir -p "$OUT"
log="$OUT/session.log"
say() { echo "== $*" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version,compute_cap --format=csv,noheader | tee -a "$log"
say build
( time python3 -m pip install --no-build-isolation --no-deps . ) > "$OUT/build.log" 2>&1 || { tail -40 "$OUT/build.log"; exit 1; }
grep real "$OUT/build.log" | tee -a "$log"
if [ -d .whl ]; then python3 -m pip install -q --no-index --no-deps --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site; fi
python3 -c "import gymnasium" 2>/dev/null || echo "gymnasium missing: carry its wheel (.whl) for tests/test_envs.py and the learner" | tee -a "$log"
if [ "$part" = bench ]; then
say gpu tests, batch
python3 -m pytest -q -m gpu tests/test_batch_api.py tests/test_batch.py 2>&1 | tee "$OUT/gpu_tests.log" | tail -8
say batch tests on the CPU of the device machine
python3 -m pytest -q -m "not gpu" tests/test_batch_api.py tests/test_envs.py 2>&1 | tail -3 | tee -a "$log"
say target: 4096 scenes of 1000 particles, and one 3500-particle scene
corpuscle bench magic8ball --backend cuda --particles 1000 --batch 4096 --steps 200 --repeats 3 --no-progress | tee -a "$log"
corpuscle bench magic8ball --backend cuda --particles 3500 --batch 1 --steps 2000 --repeats 3 --no-progress | tee -a "$log"
say sweep over B and particles, reset of 10%
timeout 240 python3 benchmarks/batch_sweep.py --backend cuda --max-seconds 6 --repeats 2 --json "$OUT/batch_sweep.json" | tee -a "$log"
fi
if [ "$part" = learn ]; then
say learner on the GPU
timeout 400 python3 examples/rig_the_8ball.py --backend cuda --particles 1000 --population 256 --scenes 16 \
  --iterations 10 --dt-max 1.5e-3 --plot "$OUT/rig_gpu.png" --json "$OUT/rig_gpu.json" | tee -a "$log"
fi
