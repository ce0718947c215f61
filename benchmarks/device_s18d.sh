#!/usr/bin/env bash
# Session 18, fourth call: the list walk loading ahead. P = this tree (an index two entries and
# a position one entry ahead), P2 = ./tmp_p2 (an index three and a position two ahead),
# Q = ./tmp_q (P, and the next neighbour's PairVel line prefetched into L1), built side by side;
# every gpu test of P; the box and dsph on each; P's lane widths against the automatic ones.
NAME=s18d SELF=p
source benchmarks/_device_common.sh
build_trees "p2 q"
gpu_tests all 240 tests
bench_on 131072 "p p2 q" "${BOX129[@]}"
bench_on dsph "p p2 q" "${DSPH[@]}"
bench_on 1M "p p2 q" "${BOX1M[@]}"
for l in 2 4; do bench_on "lanes=$l 131072" p "${BOX129[@]}" --set sph.lanes=$l; done
bench_on "lanes=2 1M" p "${BOX1M[@]}" --set sph.lanes=2
bench_on "lanes=2 dsph" p "${DSPH[@]}" --set sph.lanes=2
bench_on "131072 again" p "${BOX129[@]}"
say done
