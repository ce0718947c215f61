#!/usr/bin/env bash
# s21b: main (the default model's terms fixed in every index's pair pass, CUDA included; the
# cell walks leaving out the cells beyond reach) against ./tmp_h (ce24ac0: the fixed terms
# alone) and ./tmp_b (a05c2ff: the dispatch on CUDA); every gpu test of main; the dam break in
# motion (bench --start-time 0.15, where the lists relist every few steps) across skins; whole
# runs of dam-break-dsph as DualSPHysics times its own (to its end time); Nsight Compute on the
# pair pass and the build. Trees:
#   mkdir tmp_b; git archive a05c2ff | tar -x -C tmp_b
#   mkdir tmp_h; git archive ce24ac0 | tar -x -C tmp_h
NAME=s21b SELF=m
source benchmarks/_device_common.sh
build_trees "b h"
gpu_tests main 240 tests
bench_on 131072 "b h m" "${BOX129[@]}"
bench_on dsph "b h m" "${DSPH[@]}"
bench_on 1M "h m" "${BOX1M[@]}"
bench_on "131072 grid" "b h m" "${BOX129[@]}" --neighbors grid
bench_on "dsph grid" "h m" "${DSPH[@]}" --neighbors grid
for t in h m; do echo "## $t wind" >> "$OUT/bench_full.log"; run $t bench wind-tunnel --backend cuda --steps 200 --repeats 3 --no-progress | tee -a "$OUT/bench_full.log" | grep -E "^(grid|cuda)" | sed "s/^/$t wind /" | tee -a "$log"; done
say the flow at t = 0.15 s
bench_on "dsph t0.15" "h m" "${DSPH[@]}" --start-time 0.15
for s in 0.06 0.08 0.12; do bench_on "dsph t0.15 skin $s" m "${DSPH[@]}" --start-time 0.15 --set sph.skin=$s; done
bench_on "131072 t0.15" m "${BOX129[@]}" --start-time 0.15
say whole runs
for p in 1040000 171496; do
  run m run dam-break-dsph --backend cuda --particles $p --out /tmp/w.cps --no-progress 2>&1 | grep -E "particles|steps|wall time|relistings" | sed "s/^/run $p /" | tee -a "$log"
done
say ncu
timeout 150 python3 benchmarks/ncu_top.py fluid-box --top 2 --out "$OUT" 2>&1 | tail -14 | tee -a "$log"
say done
