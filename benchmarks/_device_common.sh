# The device scripts' shared part (source it; the device tool runs a script in the repository
# root). Set NAME (the log's name) and SELF (this tree's label) first. Gives:
#   say MSG                 a timestamped line in the log
#   build_trees "T ..."     ./tmp_T installed into /tmp/t_T, in parallel with this tree (pip .)
#   run T ARGS              `corpuscle ARGS` on tree T (SELF: the installed one), 90 s at most
#   bench_on LABEL "T ..." ARGS   `corpuscle bench ARGS --backend cuda` on each tree, its rows
#                           in the log and the whole output (stage times) in bench_full.log
#   gpu_tests LABEL LIMIT PATHS   this tree's gpu tests
#   tree_gpu_tests T LIMIT  every gpu test of ./tmp_T, run from it on its install in /tmp/t_T
#   BOX129 BOX1M DSPH       the SPH box at 129,600 and 1,056,321 and dam-break-dsph, as bench ARGS
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/$NAME.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
build_trees() {
  local v
  for v in $1; do
    ( python3 -m pip install --no-build-isolation --no-deps --target /tmp/t_$v ./tmp_$v > "$OUT/build_$v.log" 2>&1; echo "built $v rc=$?" | tee -a "$log" ) &
  done
  ( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"
  wait
  say built
}
run() { local t=$1; shift; if [ "$t" = "$SELF" ]; then timeout 90 corpuscle "$@"; else PYTHONPATH=/tmp/t_$t timeout 90 python3 -m corpuscle.cli "$@"; fi; }
full() { tee -a "$OUT/bench_full.log" | grep -E "^(lists|grid)|relisting" | sed "s/^/$1 /" | tee -a "$log"; }
bench_on() {
  local label=$1 trees=$2 t; shift 2
  for t in $trees; do echo "## $t" >> "$OUT/bench_full.log"; run $t bench "$@" --backend cuda --no-progress | full "$t $label"; done
}
gpu_tests() {
  local label=$1 limit=$2; shift 2
  say gpu tests $label
  timeout $limit python3 -m pytest -q -m gpu "$@" -p no:cacheprovider 2>&1 | tee "$OUT/gpu_tests_$label.log" | grep -v "^\.\+ *\[" | tail -5 | tee -a "$log"
}
tree_gpu_tests() {
  local t=$1 limit=$2
  say gpu tests $t
  (cd tmp_$t && PYTHONPATH=/tmp/t_$t timeout $limit python3 -m pytest -q -m gpu tests -p no:cacheprovider 2>&1) |
    tee "$OUT/gpu_tests_$t.log" | grep -v "^\.\+ *\[" | tail -3 | tee -a "$log"
}
BOX129=(fluid-box --particles 131072 --steps 200 --repeats 3)
BOX1M=(fluid-box --particles 1048576 --steps 50 --repeats 3 --warmup 10)
DSPH=(dam-break-dsph --steps 50 --repeats 3 --warmup 10)
