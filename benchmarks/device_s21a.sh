#!/usr/bin/env bash
# Next session's first call: the `lists` pair pass with the default model's terms fixed at
# compile time on CUDA too (./tmp_fx: main with kFixedTermsOnDevice = true; the CPU takes it
# since bb1faad, serial +14 to +20%), its gpu tests (the fixed run must be the dispatched one bit
# for bit on CUDA as well), against main; then the SASS of the two list kernels (what the build
# and the pair pass spend a candidate on). Make the tree first:
#   mkdir tmp_fx; git archive HEAD | tar -x -C tmp_fx
#   sed -i "s/constexpr bool kFixedTermsOnDevice = false;/constexpr bool kFixedTermsOnDevice = true;/" tmp_fx/cpp/include/corpuscle/scenes/sph/pipeline.h
#   sed -i 's/\["serial", "cpu"\])$/["serial", "cpu", pytest.param("cuda", marks=pytest.mark.gpu)])/' tmp_fx/tests/test_sph_lists.py
# (Remove the tmp_* trees before committing.)
NAME=s21a SELF=m
source benchmarks/_device_common.sh
build_trees "fx"
tree_gpu_tests fx 150
bench_on 131072 "m fx" "${BOX129[@]}"
bench_on dsph "m fx" "${DSPH[@]}"
bench_on 1M "m fx" "${BOX1M[@]}"
bench_on "171k dsph" "m fx" "${DSPH[@]}" --particles 171496
say round 2
bench_on 131072 "m fx" "${BOX129[@]}"
bench_on dsph "m fx" "${DSPH[@]}"
say sass
so=$(python3 -c "import corpuscle._core as c; print(c.__file__)" 2>/dev/null)
if command -v cuobjdump >/dev/null && [ -n "$so" ]; then
  cuobjdump -sass "$so" > /tmp/all.sass 2>/dev/null
  awk '/Function : .*ListGatherLanesFnILi4E.*SlotListViewILi3E/{p=1} p&&/Function : /&&!/ListGatherLanesFnILi4E/{p=0} p' /tmp/all.sass > "$OUT/pair4.sass"
  awk '/Function : .*SlotListFillFn.*CellGridViewILi3E/{p=1} p&&/Function : /&&!/SlotListFillFn/{p=0} p' /tmp/all.sass > "$OUT/fill.sass"
  wc -l "$OUT"/*.sass | tee -a "$log"
fi
say done
