#!/usr/bin/env bash
# Session 18, second call: the SPH pair pass's special functions. A = ./tmp_a (HEAD: the lanes
# build), S = this tree (the Fourtakas odd part by its series, no powers), E = ./tmp_e (S with
# Wendland's q = r / h by a stored 1 / h and one reciprocal of r^2 + eta^2 for mu and the
# diffusion), built side by side; the SPH gpu tests of S; the box and dsph on each; ncu of S's
# two longest launches in the box.
NAME=s18b SELF=s
source benchmarks/_device_common.sh
build_trees "a e"
gpu_tests sph 200 tests/test_sph*.py
for r in 1 2; do
  bench_on 131072 "a s e" "${BOX129[@]}"
  bench_on dsph "a s e" "${DSPH[@]}"
done
bench_on 1M "a s e" "${BOX1M[@]}"
say ncu S
timeout 240 python3 benchmarks/ncu_top.py fluid-box --top 2 --out "$OUT" 2>&1 | tail -14 | tee -a "$log"
say done
