#!/usr/bin/env bash
# s23e: main's every gpu test, and the dam-break front against Martin & Moyce on CUDA at the
# default and finer resolutions: 2-D a/dp = 40, 80, 160 and 3-D a/dp = 20, 40 (`corpuscle
# validate dam-break --backend cuda --dim D --particles N`, each run's table in the log)
NAME=s23e SELF=main
source benchmarks/_device_common.sh
t0=$SECONDS
build_trees ""
gpu_tests all 220 tests
for dn in "2 3200" "2 12800" "3 8000" "3 64000" "2 51200"; do
  set -- $dn
  [ $((SECONDS - t0)) -lt 520 ] || break
  say validate dam-break dim $1 particles $2
  ( time timeout 120 corpuscle validate dam-break --backend cuda --dim $1 --particles $2 --plot "$OUT/front_$1_$2.png" ) 2>&1 |
    grep -E "^\s+[0-9.]+ +[-0-9.]+ +[-0-9.]+ +[-+0-9.]+$|rms|fluid particles|real|^(PASS|FAIL)" | tee -a "$log"
done
say done
