#!/usr/bin/env bash
# s23b: this branch (the SPH cell grid sorted in rows: a walk reads each row of its 3^D block,
# three cells, as one range) against ./tmp_m (main, Morton-sorted cells read one by one); every
# gpu test of the branch; the box and the dsph dam break at their start and in the flow; whole
# runs at 1.03 M and 171k. Tree:
#   mkdir tmp_m; git archive main | tar -x -C tmp_m
NAME=s23b SELF=r
source benchmarks/_device_common.sh
t0=$SECONDS
build_trees "m"
gpu_tests branch 150 tests
bench_on "131072" "m r" "${BOX129[@]}"
bench_on "131072 t0.15" "m r" "${BOX129[@]}" --start-time 0.15
bench_on "dsph t0.15" "m r" "${DSPH[@]}" --start-time 0.15
bench_on "dsph" "m r" "${DSPH[@]}"
say whole runs
for p in 171496 0; do
  for t in m r; do
    [ $((SECONDS - t0)) -lt 500 ] || break
    extra=(); [ $p -gt 0 ] && extra=(--particles $p)
    run $t run dam-break-dsph --backend cuda "${extra[@]}" --out /tmp/w.cps --no-progress 2>&1 | grep -E "steps/s|wall time|relistings" | sed "s/^/run $t $p /" | tee -a "$log"
  done
done
say done
