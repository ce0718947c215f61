#!/usr/bin/env bash
# The second call: the lists' skin (sph.skin) swept on this tree (kPairBlocksPerSM = 10), with
# the lane width at the smaller skins. s20a: skin 0.05 beat 0.1 by 9% (box 129,600) and 18%
# (dam-break-dsph); 0.2 lost.
NAME=s20b SELF=m
source benchmarks/_device_common.sh
build_trees ""
for s in 0.1 0.02 0.03 0.04 0.05 0.07; do
  bench_on "131072 skin=$s" m "${BOX129[@]}" --set sph.skin=$s
  bench_on "dsph skin=$s" m "${DSPH[@]}" --set sph.skin=$s
  bench_on "1M skin=$s" m "${BOX1M[@]}" --set sph.skin=$s
done
for g in 2 8; do bench_on "131072 skin=0.05 lanes=$g" m "${BOX129[@]}" --set sph.skin=0.05 --set sph.lanes=$g; done
bench_on "dsph skin=0.05 lanes=2" m "${DSPH[@]}" --set sph.skin=0.05 --set sph.lanes=2
bench_on "171k dsph skin=0.05" m "${DSPH[@]}" --particles 171496 --set sph.skin=0.05
bench_on "171k dsph skin=0.1" m "${DSPH[@]}" --particles 171496
say done
