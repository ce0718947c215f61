#!/usr/bin/env bash
# The second call: the lists' skin (sph.skin) swept on main (kPairBlocksPerSM for lists = 10) and
# on ./tmp_rec (branch sphrec: a neighbour's position and PairVel in one 32-byte record), with
# the lane width at the smaller skin; rec's gpu tests. s20a: skin 0.05 beat 0.1 by 9% (box
# 129,600) and 18% (dam-break-dsph); 0.2 lost. Make the tree first:
#   mkdir tmp_rec; git archive sphrec | tar -x -C tmp_rec   (remove it before committing)
NAME=s20b SELF=m
source benchmarks/_device_common.sh
build_trees "rec"
tree_gpu_tests rec 150
for s in 0.1 0.05 0.03 0.07; do
  bench_on "131072 skin=$s" "m rec" "${BOX129[@]}" --set sph.skin=$s
  bench_on "dsph skin=$s" "m rec" "${DSPH[@]}" --set sph.skin=$s
  bench_on "1M skin=$s" "m rec" "${BOX1M[@]}" --set sph.skin=$s
done
for s in 0.02 0.04; do
  bench_on "131072 skin=$s" m "${BOX129[@]}" --set sph.skin=$s
  bench_on "dsph skin=$s" m "${DSPH[@]}" --set sph.skin=$s
done
for g in 2 8; do bench_on "131072 skin=0.05 lanes=$g" m "${BOX129[@]}" --set sph.skin=0.05 --set sph.lanes=$g; done
bench_on "dsph skin=0.05 lanes=2" m "${DSPH[@]}" --set sph.skin=0.05 --set sph.lanes=2
bench_on "171k dsph skin=0.05" "m rec" "${DSPH[@]}" --particles 171496 --set sph.skin=0.05
bench_on "171k dsph skin=0.1" "m rec" "${DSPH[@]}" --particles 171496
say round 2
bench_on "131072 skin=0.05" "m rec" "${BOX129[@]}" --set sph.skin=0.05
bench_on "dsph skin=0.05" "m rec" "${DSPH[@]}" --set sph.skin=0.05
say done
