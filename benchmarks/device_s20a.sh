#!/usr/bin/env bash
# This session's first call: main's gpu tests (its last CUDA changes, 37f1e0c, were compiled but
# not run on a GPU), the pair pass's blocks per multiprocessor (./tmp_b10, ./tmp_b12: main with
# kPairBlocksPerSM = 10 / 12: the pass waits on memory at 50% occupancy with 55 registers) and
# the lists' skin on main (sph.skin = 0.05 / 0.2 against the default 0.1). Make the trees first:
#   for b in 10 12; do mkdir tmp_b$b; git archive HEAD | tar -x -C tmp_b$b
#     sed -i "s/kPairBlocksPerSM = 8;/kPairBlocksPerSM = $b;/" tmp_b$b/cpp/include/corpuscle/scenes/sph/pipeline.h; done
# (Remove the tmp_* trees before committing.)
NAME=s20a SELF=m
source benchmarks/_device_common.sh
build_trees "b10 b12"
gpu_tests main 240 tests
say round 1
bench_on 131072 "m b10 b12" "${BOX129[@]}"
bench_on dsph "m b10 b12" "${DSPH[@]}"
bench_on 1M "m b10 b12" "${BOX1M[@]}"
say skin
for s in 0.05 0.2; do
  bench_on "131072 skin=$s" m "${BOX129[@]}" --set sph.skin=$s
  bench_on "dsph skin=$s" m "${DSPH[@]}" --set sph.skin=$s
done
say round 2
bench_on 131072 "m b10 b12" "${BOX129[@]}"
bench_on 1M "m b10 b12" "${BOX1M[@]}"
say 4M
bench_on 4M m fluid-box --particles 4194304 --steps 20 --repeats 3 --warmup 5
say done
