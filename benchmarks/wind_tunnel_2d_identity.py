"""The 2-D wind tunnel bitwise before and after a change of its code: record the state of six
short runs (grid, lbvh, allpairs, reflexive, a thermal stream with symplectic Euler, the
collisionless validation set-up; one with the pitch control) on one build, compare on another. Every field and scalar must be equal to the bit.

    python benchmarks/wind_tunnel_2d_identity.py record /tmp/wt2d.npz    # on main's build
    python benchmarks/wind_tunnel_2d_identity.py compare /tmp/wt2d.npz   # on the branch's build
    (BACKEND=cuda for the CUDA backend; the same compiler and flags both times)
"""
import os
import sys

import numpy as np
from corpuscle import Simulation
from corpuscle.scene import load_scene
CASES = {
 "grid": dict(index="grid", ov={}),
 "lbvh": dict(index="lbvh", ov={}),
 "allpairs": dict(index="allpairs", ov={}),
 "reflexive": dict(index="grid", ov={"contact.form": "reflexive"}),
 "thermal_symp": dict(index="grid", ov={"inflow.speed_ratio": 2.0, "timestep.integrator": "symplectic-euler", "airfoil.shape": "naca2412"}),
 "collisionless": dict(index="grid", ov={"contact.enabled": False, "wall.recycle_scattered": True, "inflow.speed_ratio": 2.0, "airfoil.shape": "flat-plate", "airfoil.angle_of_attack": 30.0}),
}
def run(name, c, backend):
    ov = {"inflow.speed": 2.0, "measure.start": 0.0, "run.end_time": 0.4, "measure.block_time": 0.002}
    ov.update(c["ov"])
    sim = Simulation.from_scene(load_scene("wind-tunnel"), backend=backend, particles=2000, neighbors=c["index"], overrides=ov)
    sim.step(150)
    if name == "grid":
        sim.set_control(pitch=5.0); sim.step(50)
    out = {f"{name}_{k}": np.asarray(sim.field(k, copy=True)) for k in ("position", "velocity", "id", "pressure", "number_density", "force")}
    for k, v in sim.scalars().items():
        out[f"{name}_s_{k}"] = np.asarray(v)
    return out
mode, path = sys.argv[1], sys.argv[2]
data = {}
for name, c in CASES.items():
    data.update(run(name, c, os.environ.get("BACKEND", "serial")))
if mode == "record":
    np.savez(path, **data); print("recorded", len(data))
else:
    ref = np.load(path); bad = [k for k in ref.files if k not in data or not np.array_equal(ref[k], data[k], equal_nan=True)]
    missing = [k for k in data if k not in ref.files]
    print("compared", len(ref.files), "mismatches", bad[:20], "new keys", missing[:5]); sys.exit(1 if bad else 0)
