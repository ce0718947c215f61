#!/usr/bin/env bash
# Everything the GPU machine is for, in one call: build, GPU tests, CPU-vs-CUDA checks and
# the benchmark table. Results land in $OUT (the device tool brings them back).
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"
mkdir -p "$OUT"
python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 || { tail -30 "$OUT/build.log"; exit 1; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee "$OUT/device.txt"
corpuscle info | tee -a "$OUT/device.txt"
# gpu-marked tests (CUDA against the CPU backend)
python3 -m pytest -q -m gpu tests/test_backends.py tests/test_neighbor_reuse.py 2>&1 | tee "$OUT/gpu_tests.log" | tail -3
# the default scene on every backend, then larger counts
corpuscle bench magic8ball --backend serial cpu cuda --steps 200 --repeats 5 --json "$OUT/bench_default.json" --no-progress 2>&1 | tee "$OUT/bench.log"
for n in 20000 200000; do
  corpuscle bench magic8ball --backend cpu cuda --particles $n --steps 50 --repeats 3 --json "$OUT/bench_$n.json" --no-progress 2>&1 | tee -a "$OUT/bench.log"
done
corpuscle bench magic8ball --backend cuda --particles 2000000 --steps 20 --repeats 3 --json "$OUT/bench_2000000.json" --no-progress 2>&1 | tee -a "$OUT/bench.log"
# the largest count through the CLI, recorded
corpuscle run magic8ball --backend cuda --particles 2000000 --steps 40 --every 20 --out /tmp/big.cps --json 2>&1 | tail -1
