#!/usr/bin/env bash
# s22c: main 6df9b52; the lists' skin chosen on whole runs: corpuscle run dam-break-dsph (to its
# end time) at 171,496 and 1.03 M particles across skins, and the fluid box's start-of-run bench
# at the old and new default.
NAME=s22c SELF=m
source benchmarks/_device_common.sh
t0=$SECONDS
build_trees ""
whole() { run m run dam-break-dsph --backend cuda "$@" --out /tmp/w.cps --no-progress 2>&1 | grep -E "steps/s|wall time|relistings" | sed "s/^/run $* /" | tee -a "$log"; }
say whole runs 171k
for s in 0.04 0.08 0.12 0.16 0.2; do whole --particles 171496 --set sph.skin=$s; done
for s in 0.04 0.12; do bench_on "131072 skin $s" m "${BOX129[@]}" --set sph.skin=$s; done
say whole runs 1.03M
for s in 0.04 0.12 0.08 0.16; do
  [ $((SECONDS - t0)) -lt 420 ] || break
  whole --set sph.skin=$s
done
say done
