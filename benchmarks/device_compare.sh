#!/usr/bin/env bash
# Speed of this working tree against a base taken from git, both built and timed in one call on
# the same GPU: the figures the issues ask to stay within 2% ("before and after in one device
# call"). Two steps, because the device machine receives a copy of the working tree without .git:
#
#   1. here, in a clone:      bash benchmarks/device_compare.sh prepare [REF]
#        extracts `git archive REF` (REF: $1, else $BASE, else origin/main, else main) into
#        ./base_tree/: untracked and not ignored, so it travels with the working tree. It adds
#        nothing to git; do not commit it (delete it when done).
#   2. on the GPU machine:    bash benchmarks/device_compare.sh run
#        from the repository root. Builds ./base_tree into /tmp/t_base and this tree into the
#        environment (pip install ., in parallel; about 4 min on 16 cores, less when build/ from
#        an earlier call is still there), runs this tree's gpu tests, then times every case with
#        the base and this tree taking turns, and prints a table.
#
# The cases (all `--backend cuda`):
#   m8      corpuscle bench magic8ball --steps 2000 --repeats 5                (3,500 particles)
#   batch   corpuscle bench magic8ball --particles 1000 --batch 4096 --steps 100 --repeats 3
#   box129  corpuscle bench fluid-box --particles 131072 --steps 200 --repeats 3       (129,600 fluid)
#   box1m   corpuscle bench fluid-box --particles 1048576 --steps 50 --repeats 3 --warmup 10 (1,056,321)
#   wt      corpuscle bench wind-tunnel --steps 200 --repeats 3 --warmup 50   (2,097,152 particles)
#   dsph    corpuscle run dam-break-dsph --json --out /tmp/...   (the whole run, 1,030,400 fluid, about 45 s)
#   chip    the batch on the 8-ball's chip path (--path chip; this tree only: the base's is `batch`,
#           which runs --path general on a tree that has the choice)
#
# Environment: OUT (logs; default ./out), BACKEND (default cuda), ROUNDS (turns of each bench case, default 2; the
# whole dam-break run takes one), CASES (a subset, e.g. "m8 batch"), STEPS (default
# "build tests bench": a call may do "build tests" and a later call on the same warm machine
# "build bench"; a build whose build/ folder is still there is quick), TEST_LIMIT (seconds for
# the gpu tests, default 200), BUDGET (seconds from the start after which no new timing begins,
# default 540, to end inside the device tool's 10 minutes).
# Writes under $OUT: compare.log (everything in order, and the table), build_base.log,
# build_new.log, gpu_tests.log, results.tsv (one row a timing), bench.jsonl (bench's and run's
# JSON, one object a line).
set -uo pipefail

prepare() {
  local ref="${1:-${BASE:-}}"
  if [ -z "$ref" ]; then
    if git rev-parse -q --verify origin/main >/dev/null; then ref=origin/main; else ref=main; fi
  fi
  local sha
  sha=$(git rev-parse --verify "$ref^{commit}") || { echo "device_compare: no such ref: $ref" >&2; exit 2; }
  rm -rf base_tree && mkdir base_tree
  git archive "$sha" | tar -x -C base_tree
  echo "$ref $sha" > base_tree/BASE_REF
  echo "base_tree/: $ref ($sha); run 'bash benchmarks/device_compare.sh run' on the device"
}

run_all() {
  [ -d base_tree ] || { echo "device_compare: no ./base_tree: run 'bash benchmarks/device_compare.sh prepare REF' first" >&2; exit 2; }
  export PYTHONUNBUFFERED=1
  OUT="${OUT:-out}"; mkdir -p "$OUT"
  local log="$OUT/compare.log" tsv="$OUT/results.tsv" jsonl="$OUT/bench.jsonl"
  local rounds="${ROUNDS:-2}" steps="${STEPS:-build tests bench}" budget="${BUDGET:-540}"
  local cases="${CASES:-m8 batch box129 box1m wt dsph}"
  local t0=$SECONDS
  say() { echo "== $* ($(date -u +%H:%M:%S), ${SECONDS}s)" | tee -a "$log"; }
  { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; date -u +%Y-%m-%dT%H:%MZ
    echo "base: $(cat base_tree/BASE_REF 2>/dev/null)"; } 2>&1 | tee -a "$log"

  if [[ " $steps " == *" build "* ]]; then
    say build base and new
    ( python3 -m pip install --no-build-isolation --no-deps --upgrade --target /tmp/t_base ./base_tree \
        > "$OUT/build_base.log" 2>&1; echo "base build rc=$?" | tee -a "$log" ) &
    python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build_new.log" 2>&1
    echo "new build rc=$?" | tee -a "$log"
    wait
    say built
  fi
  python3 -c "import corpuscle._core" 2>/dev/null || { say "this tree is not installed"; tail -30 "$OUT/build_new.log"; exit 1; }
  PYTHONPATH=/tmp/t_base python3 -c "import corpuscle._core as c; assert c.__file__.startswith('/tmp/t_base/')" 2>/dev/null || { say "the base is not built"; tail -30 "$OUT/build_base.log"; exit 1; }

  if [[ " $steps " == *" tests "* ]]; then
    say gpu tests of this tree
    timeout "${TEST_LIMIT:-200}" python3 -m pytest -q -m gpu tests -p no:cacheprovider > "$OUT/gpu_tests.log" 2>&1
    echo "gpu tests rc=$? ($( tail -1 "$OUT/gpu_tests.log"))" | tee -a "$log"
  fi

  [[ " $steps " == *" bench "* ]] || { say done; return 0; }
  local B="--backend ${BACKEND:-cuda} --no-progress"
  declare -A args=(
    [m8]="bench magic8ball $B --steps 2000 --repeats 5"
    [batch]="bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3"
    [box129]="bench fluid-box $B --particles 131072 --steps 200 --repeats 3"
    [box1m]="bench fluid-box $B --particles 1048576 --steps 50 --repeats 3 --warmup 10"
    [wt]="bench wind-tunnel $B --steps 200 --repeats 3 --warmup 50"
    [dsph]="run dam-break-dsph $B --json --out /tmp/dc_whole.cps"
    [chip]="bench magic8ball $B --particles 1000 --batch 4096 --steps 100 --repeats 3 --path chip"
  )
  # the batch case times the general path on a tree that also has the chip path (bench --path);
  # `chip` (this tree only) times the chip path
  knows_path() {
    local pp=${PYTHONPATH:-}
    [ "$1" = base ] && pp=/tmp/t_base${PYTHONPATH:+:$PYTHONPATH}
    PYTHONPATH=$pp python3 -m corpuscle bench --help 2>/dev/null | grep -q -- "--path"
  }
  # one timing: corpuscle ARGS on tree T (base: /tmp/t_base first on the path), its JSON kept
  one() {
    local case=$1 tree=$2 round=$3 js=/tmp/dc_$$.json pp=${PYTHONPATH:-} limit=90 a
    a=${args[$case]}
    [ "$case" = batch ] && knows_path "$tree" && a="$a --path general"
    [ "$tree" = base ] && pp=/tmp/t_base${PYTHONPATH:+:$PYTHONPATH}
    if [ "$case" = dsph ]; then
      limit=150
      PYTHONPATH=$pp timeout $limit python3 -m corpuscle $a > $js 2>> "$log"
    else
      PYTHONPATH=$pp timeout $limit python3 -m corpuscle $a --json $js >> "$log" 2>&1
    fi
    local rc=$?
    rm -f /tmp/dc_whole.cps
    if [ $rc -ne 0 ]; then echo "$case $tree round $round: rc=$rc" | tee -a "$log"; rm -f $js; return; fi
    python3 - "$js" "$case" "$tree" "$round" "$tsv" "$jsonl" <<'PY' | tee -a "$log"
import json, sys
js, case, tree, rnd, tsv, jsonl = sys.argv[1:]
d = json.load(open(js))
rows = d if isinstance(d, list) else [d]
r = rows[0]
with open(jsonl, "a") as f:
    f.write(json.dumps({"case": case, "tree": tree, "round": int(rnd), "rows": rows}) + "\n")
with open(tsv, "a") as f:
    f.write(f"{case}\t{tree}\t{rnd}\t{r['particles']}\t{r['steps_per_second']:.6g}\t{r['particle_steps_per_second']:.6g}\n")
print(f"{case:7s} {tree:4s} round {rnd}: {r['particles']:>9,} particles {r['steps_per_second']:>10,.1f} steps/s")
PY
    rm -f $js
  }
  local r c order
  for r in $(seq 1 "$rounds"); do
    order="base new"; [ $((r % 2)) -eq 0 ] && order="new base"
    for c in $cases; do
      [ -n "${args[$c]:-}" ] || { say "unknown case $c"; continue; }
      [ "$c" = dsph ] && [ "$r" -gt 1 ] && continue
      if [ $((SECONDS - t0)) -ge "$budget" ]; then say "time budget spent: $c round $r skipped"; continue; fi
      for tree in $order; do
        [ "$c" = chip ] && [ "$tree" = base ] && continue
        one "$c" "$tree" "$r"
      done
    done
  done
  say table
  python3 - "$tsv" <<'PY' | tee -a "$log"
import statistics, sys
rows = [l.rstrip("\n").split("\t") for l in open(sys.argv[1]) if l.strip()]
cases = list(dict.fromkeys(r[0] for r in rows))
print(f"{'case':7s} {'particles':>10s} {'base steps/s':>22s} {'new steps/s':>22s} {'new/base':>9s}")
for c in cases:
    got = {t: [float(r[4]) for r in rows if r[0] == c and r[1] == t] for t in ("base", "new")}
    n = next(r[3] for r in rows if r[0] == c)
    fmt = lambda v: " / ".join(f"{x:,.1f}" for x in v) or "-"
    ratio = (f"{statistics.median(got['new']) / statistics.median(got['base']) - 1:+.1%}"
             if got["base"] and got["new"] else "-")
    print(f"{c:7s} {int(n):>10,} {fmt(got['base']):>22s} {fmt(got['new']):>22s} {ratio:>9s}")
PY
  say done
}

case "${1:-}" in
  prepare) shift; prepare "$@" ;;
  run) run_all ;;
  *) sed -n '2,32p' "$0"; exit 2 ;;
esac
