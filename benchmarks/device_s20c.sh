#!/usr/bin/env bash
# The third call: ./tmp_cb (branch sphcbuild: the lists built through the compact grid's chunks,
# a block of a chunk's slots reading their neighbour cells once through shared memory) against
# main (skin 0.04 now the default), its gpu tests, the smaller skins with it; then the issue's
# fluid-box sweep (benchmarks/fluid_box_sweep.py, every index and backend, 16-core host) on cb,
# stopped before the call's limit (its rows stay in $OUT/sweep). Make the tree first:
#   mkdir tmp_cb; git archive sphcbuild | tar -x -C tmp_cb   (remove it before committing)
NAME=s20c SELF=m
source benchmarks/_device_common.sh
build_trees "cb"
tree_gpu_tests cb 120
bench_on 131072 "m cb" "${BOX129[@]}"
bench_on dsph "m cb" "${DSPH[@]}"
bench_on 1M "m cb" "${BOX1M[@]}"
for s in 0.02 0.03; do
  bench_on "131072 skin=$s" "cb" "${BOX129[@]}" --set sph.skin=$s
  bench_on "dsph skin=$s" "cb" "${DSPH[@]}" --set sph.skin=$s
done
bench_on "171k dsph" "m cb" "${DSPH[@]}" --particles 171496
say round 2
bench_on 131072 "m cb" "${BOX129[@]}"
bench_on dsph "m cb" "${DSPH[@]}"
say sweep
PYTHONPATH=/tmp/t_cb timeout $((570 - SECONDS)) python3 benchmarks/fluid_box_sweep.py --out "$OUT/sweep" --max-step 0.1 2>&1 | tee "$OUT/sweep.log" | tail -n 60
say done
