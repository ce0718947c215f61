#!/usr/bin/env bash
# Session 16, second device call: the wind tunnel's new defaults (a nearly elastic gas,
# restitution 0.9, symplectic Euler): the bench, the default run recorded and rendered, the
# shock's stand-off against the seed's contact law (benchmarks/bow_shock.py), the 3-D kind.
set -uo pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-out}"; mkdir -p "$OUT"; log="$OUT/s16b.log"
say() { echo "== $* ($(date -u +%H:%M:%S))" | tee -a "$log"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"; date -u +%Y-%m-%dT%H:%MZ | tee -a "$log"
python3 -c "import corpuscle" 2>/dev/null || { ( time python3 -m pip install --no-build-isolation --no-deps . > "$OUT/build.log" 2>&1 ) 2>&1 | grep real | tee -a "$log"; }
[ -d .whl ] && python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site
B="--backend cuda --no-progress"
say wind tunnel defaults
for r in 1 2; do timeout 40 corpuscle bench wind-tunnel $B --steps 200 --repeats 3 --warmup 50 | head -2 | tail -1 | sed "s/^/default /" | tee -a "$log"; done
timeout 40 corpuscle bench wind-tunnel $B --set contact.restitution=0 timestep.integrator=forward-euler --steps 200 --repeats 3 --warmup 50 | head -2 | tail -1 | sed "s/^/seed-law /" | tee -a "$log"
timeout 40 corpuscle bench wind-tunnel-3d $B --steps 200 --repeats 3 --warmup 50 | head -2 | tail -1 | sed "s/^/3-D /" | tee -a "$log"
timeout 60 corpuscle bench wind-tunnel $B --particles 16384,262144,1048576,4194304 --steps 200 --repeats 3 --warmup 50 | tee -a "$log"
timeout 40 corpuscle bench wind-tunnel $B --neighbors lbvh --steps 200 --repeats 3 --warmup 50 | head -2 | tail -1 | sed "s/^/lbvh /" | tee -a "$log"
for form in reflexive reflexive-warp; do
  timeout 40 corpuscle bench wind-tunnel $B --set contact.form=$form --steps 200 --repeats 3 --warmup 50 | head -2 | tail -1 | sed "s/^/$form /" | tee -a "$log"
done
say default run, rendered
timeout 80 corpuscle run wind-tunnel --backend cuda --out /tmp/wt.cps --no-progress 2>&1 | tail -14 | tee -a "$log"
timeout 120 corpuscle render /tmp/wt.cps -o "$OUT/wind_tunnel.mp4" --size 960x540 --frames 0:101:2 -q 2>&1 | tail -2 | tee -a "$log"
timeout 30 corpuscle render /tmp/wt.cps -o "$OUT/wind_tunnel_last.png" 2>&1 | tail -1 | tee -a "$log"
timeout 30 corpuscle render /tmp/wt.cps -o "$OUT/wind_tunnel_pressure.png" --color pressure 2>&1 | tail -1 | tee -a "$log"
rm -f /tmp/wt.cps
say stand-off: default against the seed law
timeout 100 python3 benchmarks/bow_shock.py --backend cuda --time 20 --case default --case seed:contact.restitution=0,timestep.integrator=forward-euler --case seed-symplectic:contact.restitution=0 --out "$OUT" 2>&1 | tail -4 | tee -a "$log"
timeout 100 python3 benchmarks/bow_shock.py --backend cuda --time 40 --case default-t40 --out "$OUT" 2>&1 | tail -2 | tee -a "$log"
say 3-D default run
timeout 60 corpuscle run wind-tunnel-3d --backend cuda --out /tmp/wt3.cps --no-progress --time 5 2>&1 | tail -8 | tee -a "$log"
rm -f /tmp/wt3.cps
say validation CI size on CUDA
timeout 100 corpuscle validate wind-tunnel --backend cuda 2>&1 | tail -22 | tee -a "$log"
say done
