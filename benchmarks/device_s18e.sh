#!/usr/bin/env bash
# Session 18, fifth call: M = this tree (the walk loading ahead, the automatic lane width from
# 400,000 threads), Q4 = ./tmp_q4 (M, and the next neighbour's PairVel line prefetched into L1);
# the SPH gpu tests of M; the box at 129,600, 262,144 and 1M and dsph on each.
NAME=s18e SELF=m
source benchmarks/_device_common.sh
build_trees q4
gpu_tests sph 120 tests/test_sph*.py
bench_on 131072 "m q4" "${BOX129[@]}"
bench_on dsph "m q4" "${DSPH[@]}"
bench_on 1M "m q4" "${BOX1M[@]}"
for l in 0 4; do bench_on "lanes=$l 262144" m fluid-box --particles 262144 --steps 100 --repeats 3 --set sph.lanes=$l; done
say done
