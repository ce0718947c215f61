#!/usr/bin/env bash
# Next session's first call: two branches' SPH pair-loop changes against main, one call.
# M = this tree (main); R = ./tmp_rec (branch sphrecord: the neighbour's padded position and
# PairVel in one 32-byte record); R10 / R12 = ./tmp_r10, ./tmp_r12 (R with 10 / 12 pair blocks a
# multiprocessor: the pair pass waits on memory at 50% occupancy, 55 registers); P2 = ./tmp_p2
# (branch sphpair2 = R and the walk finding two entries, then visiting both). Make them first:
#   mkdir tmp_rec tmp_p2; git archive sphrecord | tar -x -C tmp_rec; git archive sphpair2 | tar -x -C tmp_p2
#   for b in 10 12; do mkdir tmp_r$b; git archive sphrecord | tar -x -C tmp_r$b
#     sed -i "s/kPairBlocksPerSM = 8;/kPairBlocksPerSM = $b;/" tmp_r$b/cpp/include/corpuscle/scenes/sph/pipeline.h; done
# Built side by side; every gpu test of M (main's last changes were compiled, not run on a GPU),
# R and P2; the box at 129,600 and 1M and dam-break-dsph on each, a second round on M, R, P2. (Remove the tmp_* trees before committing.)
NAME=s19a SELF=m
source benchmarks/_device_common.sh
build_trees "rec r10 r12 p2"
gpu_tests main 240 tests
for t in rec p2; do
  say gpu tests $t
  (cd tmp_$t && PYTHONPATH=/tmp/t_$t timeout 150 python3 -m pytest -q -m gpu tests -p no:cacheprovider 2>&1) | tee "$OUT/gpu_tests_$t.log" | grep -v "^\.\+ *\[" | tail -3 | tee -a "$log"
done
say round 1
bench_on 131072 "m rec r10 r12 p2" "${BOX129[@]}"
bench_on dsph "m rec r10 r12 p2" "${DSPH[@]}"
bench_on 1M "m rec r10 r12 p2" "${BOX1M[@]}"
say round 2  # (the two branches against main again; the block counts once: the call's 10 minutes)
bench_on 131072 "m rec p2" "${BOX129[@]}"
bench_on dsph "m rec p2" "${DSPH[@]}"
bench_on 1M "m rec p2" "${BOX1M[@]}"
say done
