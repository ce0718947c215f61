#!/usr/bin/env bash
# The fourth call: the fluid-box sweep (benchmarks/fluid_box_sweep.py: 128, then powers of
# 4 from 256 to 4,194,304; every index and backend on the 16-core host) on main, stopped before
# the call's limit; the tables, JSON, plot and log come back in $OUT (the rows stay in /tmp).
NAME=s20d SELF=m
source benchmarks/_device_common.sh
build_trees ""
say sweep
timeout $((560 - SECONDS)) python3 benchmarks/fluid_box_sweep.py --out /tmp/sweep --max-step 0.5 2>&1 | tee "$OUT/sweep.log" | grep -v "^- " | tail -n 40
cp /tmp/sweep/fluid_box_sweep.* "$OUT/" 2>/dev/null
say done
