#!/usr/bin/env bash
# Session 18, third call: A = ./tmp_a (HEAD: the lanes build), E = ./tmp_e (the Fourtakas odd
# part by its series, Wendland's q by a stored 1 / h, one reciprocal of r^2 + eta^2 for mu and
# the diffusion), EF = this tree (E, and the lanes build reading the padded positions),
# P = ./tmp_p (EF with the list walk loading an index two entries and a position one entry
# ahead), built side by side; every gpu test of EF; the box and dsph on each.
NAME=s18c SELF=ef
source benchmarks/_device_common.sh
build_trees "a e p"
gpu_tests all 240 tests
for r in 1 2; do
  bench_on 131072 "a e ef p" "${BOX129[@]}"
  bench_on dsph "a e ef p" "${DSPH[@]}"
done
bench_on 1M "a e ef p" "${BOX1M[@]}"
say done
