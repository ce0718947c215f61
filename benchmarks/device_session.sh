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
say wind-tunnel and a batch of two on CUDA against the CPU
python3 - <<'PY' | tee -a "$log"
import numpy as np, corpuscle
from corpuscle import _core
from corpuscle.kinds import Target, registry
from corpuscle.scene import load_scene
# wind tunnel: the first steps on CUDA against the CPU (positions by id)
def by_id(sim, name):
    ids = sim.field("id", copy=True); v = sim.field(name, copy=True); out = np.empty_like(v); out[ids] = v; return out
w = {b: corpuscle.Simulation.from_scene("wind-tunnel", backend=b, particles=20000) for b in ("cpu", "cuda")}
for s in w.values(): s.set_end_time(1e9); s.step(20)
print("wind-tunnel cuda-cpu max position difference after 20 steps:",
      float(np.abs(by_id(w["cuda"], "position") - by_id(w["cpu"], "position")).max()))
# magic8ball batch of two on CUDA against two single CUDA runs
kind = registry()["magic8ball"]
def build(seed):
    return kind.build(load_scene("magic8ball", {"fluid.particles": 1000, "run.seed": seed}), Target("cuda", "lists"), None)
b1, b2 = build(1), build(2)
params = dict(b1.params, n_scenes=2, die_initial_scenes=[b1.params["die_initial"], b2.params["die_initial"]])
arrays = {k: np.ascontiguousarray(np.concatenate([b1.arrays[k], b2.arrays[k]])) for k in ("position", "velocity")}
batch = _core.Simulation("magic8ball", "cuda", "lists", params, arrays); batch.evaluate()
singles = [_core.Simulation("magic8ball", "cuda", "lists", b.params, b.arrays) for b in (b1, b2)]
for s in (batch, *singles): s.evaluate(); s.set_end_time(1e9); s.step(100)
for k, s in enumerate(singles):
    d = np.abs(np.array(batch.scalars(k)["die_position"]) - np.array(s.scalars(0)["die_position"])).max()
    print(f"batch scene {k} die position vs its single CUDA run after 100 steps: {d:.3e}")
PY
