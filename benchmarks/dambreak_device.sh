#!/usr/bin/env bash
# Issue 9 on the device: build, the gpu tests of the SPH box, the fluid-box sweep (JSON +
# tables + PNG), the DualSPHysics-matched dam break at 1.04 M and 171,496 fluid particles (its
# 239 and 880 steps/s on an H200), stage profiles, and the full dam-break validation. Results in $OUT.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"
mkdir -p "$OUT"
log="$OUT/dambreak.log"
say() { echo "== $*" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version,compute_cap --format=csv,noheader | tee -a "$log"
say build
python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 || { tail -40 "$OUT/build.log"; exit 1; }
say gpu tests
python3 -m pytest -q -m gpu tests/test_sph_box.py 2>&1 | tee "$OUT/gpu_tests.log" | tail -15
say dam-break-dsph, 1.04 M and 171,496 fluid particles, three indexes
for n in 1040000 171496; do for nb in grid compact; do
  corpuscle bench dam-break-dsph --backend cuda --neighbors $nb --particles $n --steps 500 --repeats 3 --no-progress \
    --json "$OUT/dsph_${nb}_${n}.json" | tee -a "$log"
done; done
say fluid-box sweep
python3 benchmarks/fluid_box_sweep.py --out "$OUT/sweep" 2>&1 | tee -a "$log"
say validation, full
corpuscle validate dam-break --full --backend cuda --plot "$OUT/dam_break_front.png" | tee -a "$log"
corpuscle validate dam-break --dim 3 --particles 64000 --backend cuda --plot "$OUT/dam_break_front_3d.png" | tee -a "$log"
corpuscle validate hydrostatic --full --backend cuda | tee -a "$log"
corpuscle validate hydrostatic --dim 3 --full --backend cuda | tee -a "$log"
