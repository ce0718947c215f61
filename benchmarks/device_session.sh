#!/usr/bin/env bash
# One device call for the session's GPU work: build this tree (and, when .baseline holds an
# earlier tree, that one beside it), the gpu tests, old-vs-new benchmarks on the same GPU, the
# run-loop timings, the 2M start-up and the control-overhead benchmark. Results in $OUT.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"
mkdir -p "$OUT"
log="$OUT/session.log"
say() { echo "== $*" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version,compute_cap --format=csv,noheader | tee -a "$log"
say build new
( time python3 -m pip install --no-build-isolation --no-deps . ) > "$OUT/build.log" 2>&1 || { tail -40 "$OUT/build.log"; exit 1; }
grep real "$OUT/build.log" | tee -a "$log"
corpuscle info | tee -a "$log"
if [ -d .baseline ]; then
  say build baseline
  python3 -m pip install --no-build-isolation --no-deps --target /tmp/base .baseline > "$OUT/build_base.log" 2>&1 || tail -20 "$OUT/build_base.log"
fi
say gpu tests
python3 -m pytest -q -m gpu $(grep -l "mark.gpu" tests/*.py) 2>&1 | tee "$OUT/gpu_tests.log" | tail -15
base() { PYTHONPATH=/tmp/base python3 -m corpuscle.cli "$@"; }
say bench default scene, old then new then old
for who in base new base new; do
  if [ $who = base ]; then base bench magic8ball --backend cuda --steps 2000 --repeats 5 --no-progress | head -2 | tail -1 | sed "s/^/$who /" | tee -a "$log";
  else corpuscle bench magic8ball --backend cuda --steps 2000 --repeats 5 --no-progress | head -2 | tail -1 | sed "s/^/$who /" | tee -a "$log"; fi
done
say bench neighbors new
for nb in lists grid allpairs; do corpuscle bench magic8ball --backend cuda --neighbors $nb --steps 1000 --repeats 3 --no-progress | head -2 | tail -1 | sed "s/^/$nb /" | tee -a "$log"; done
say CLI main job, old and new
base run magic8ball --backend cuda --out /tmp/o.cps --json | tee -a "$log"
corpuscle run magic8ball --backend cuda --out /tmp/n.cps --json | tee -a "$log"
say surplus steps: --time 0.3 --every 100000 vs 10, cpu and cuda, old and new
for b in cpu cuda; do for e in 10 100000; do
  if [ $b = cuda ] || [ $e = 10 ]; then  # the old CPU run with every=100000 takes ~720 s
  timeout 60 bash -c "PYTHONPATH=/tmp/base python3 -m corpuscle.cli run magic8ball --backend $b --time 0.3 --every $e --out /tmp/s.cps --json" | sed "s/^/base $b every=$e /" | tee -a "$log"
  fi
  corpuscle run magic8ball --backend $b --time 0.3 --every $e --out /tmp/s.cps --json | sed "s/^/new $b every=$e /" | tee -a "$log"
done; done
say control overhead, old and new
for b in cuda cpu; do
  PYTHONPATH=/tmp/base python3 benchmarks/control_overhead.py --backend $b --steps 1000 | sed "s/^/base /" | tee -a "$log"
  python3 benchmarks/control_overhead.py --backend $b --steps 1000 | sed "s/^/new /" | tee -a "$log"
done
say 2M start-up, new
corpuscle run magic8ball --backend cuda --particles 2000000 --steps 20 --every 10 --out /tmp/big.cps --json | tee -a "$log"
corpuscle bench magic8ball --backend cuda --particles 2000000 --steps 20 --repeats 3 --no-progress | tee -a "$log"
say CLI against bench, new, three times
for k in 1 2 3; do
  corpuscle run magic8ball --backend cuda --out /tmp/n.cps --json | python3 -c "import json,sys; d=json.load(sys.stdin); print('cli', round(d['steps_per_second']))" | tee -a "$log"
done
say resume on cuda
corpuscle run magic8ball --backend cuda --steps 600 --every 100 --checkpoint-every 200 --velocity --out /tmp/r1.cps --json > /dev/null
cp /tmp/r1.cps /tmp/r2.cps
python3 - <<'PY' | tee -a "$log"
import corpuscle, corpuscle.io, numpy as np, subprocess, json
# cut r2 back to its checkpoint at step 200 (frame 2), resume, compare with r1
w = corpuscle.io.FrameWriter.append("/tmp/r2.cps", keep=3); w.close()
p = subprocess.run(["corpuscle", "run", "--resume", "/tmp/r2.cps", "--backend", "cuda", "--json"], capture_output=True, text=True)
print("resume rc", p.returncode, p.stderr.strip())
a, b = corpuscle.open("/tmp/r1.cps"), corpuscle.open("/tmp/r2.cps")
print("frames", len(a), len(b), "steps", list(a.steps), list(b.steps))
same = all(np.array_equal(a[i][k], b[i][k]) for i in range(len(a)) for k in ("position", "velocity", "density"))
print("cuda resume bit-identical:", same)
PY
