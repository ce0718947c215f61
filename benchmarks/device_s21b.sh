#!/usr/bin/env bash
# s21b: main with the default model's terms fixed at compile time in every index's pair pass,
# CUDA included (the lists pass's +10% of s21a), against ./tmp_b (a05c2ff: the dispatch on CUDA)
# and ./tmp_b12 (main with the lists pass at 12 blocks a multiprocessor); every gpu test of main;
# then the dam break in motion (bench --start-time 0.15, where the lists relist every few steps)
# across skins; whole runs of dam-break-dsph as DualSPHysics times its own (to its end time);
# Nsight Compute on the fixed pair pass and the build. Trees:
#   mkdir tmp_b; git archive a05c2ff | tar -x -C tmp_b
#   mkdir tmp_b12; (main's files); sed -i "s/kListPairBlocksPerSM = 10;/kListPairBlocksPerSM = 12;/" tmp_b12/cpp/include/corpuscle/scenes/sph/pipeline.h
NAME=s21b SELF=m
source benchmarks/_device_common.sh
build_trees "b b12"
gpu_tests main 240 tests
bench_on 131072 "b m b12" "${BOX129[@]}"
bench_on dsph "b m b12" "${DSPH[@]}"
bench_on 1M "m b12" "${BOX1M[@]}"
bench_on "131072 grid" "b m" "${BOX129[@]}" --neighbors grid
bench_on "dsph grid" "b m" "${DSPH[@]}" --neighbors grid
say the flow at t = 0.15 s
for s in 0.04 0.06 0.08 0.12; do bench_on "dsph t0.15 skin $s" m "${DSPH[@]}" --start-time 0.15 --set sph.skin=$s; done
bench_on "131072 t0.15" m "${BOX129[@]}" --start-time 0.15
say whole runs
for p in 1040000 171496; do
  run m run dam-break-dsph --backend cuda --particles $p --out /tmp/w.cps --no-progress 2>&1 | grep -E "particles|steps|wall time|relistings" | sed "s/^/run $p /" | tee -a "$log"
done
say ncu
timeout 150 python3 benchmarks/ncu_top.py fluid-box --top 2 --out "$OUT" 2>&1 | tail -14 | tee -a "$log"
say done
