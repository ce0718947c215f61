#!/usr/bin/env bash
# Session 18, first call: the SPH lists' build with lanes. A = ./tmp_a (main: a thread a slot),
# C = this tree (8 lanes a slot), w4 / w16 / w32 = ./tmp_wN (the same with N lanes), built side
# by side; the gpu tests of C; fluid-box 131,072 and 1,048,576 and dam-break-dsph on each.
NAME=s18a SELF=c
source benchmarks/_device_common.sh
build_trees "a w4 w16 w32"
gpu_tests sph 200 tests/test_sph*.py
bench_on 131072 "a c w4 w16 w32" "${BOX129[@]}"
bench_on dsph "a c w4 w16 w32" "${DSPH[@]}"
bench_on 1M "a c w4 w16 w32" "${BOX1M[@]}"
say round 2
bench_on 131072 "a c" "${BOX129[@]}"
bench_on dsph "a c" "${DSPH[@]}"
gpu_tests all 240 tests
say done
