#!/usr/bin/env bash
# s22d: main with the lists' skin default 0.08 (chosen on whole runs, s22c): the start-of-run
# benchmarks at the new default, for the README's table.
NAME=s22d SELF=m
source benchmarks/_device_common.sh
build_trees ""
bench_on "131072" m "${BOX129[@]}"
bench_on "dsph" m "${DSPH[@]}"
bench_on "1M" m "${BOX1M[@]}"
say done
