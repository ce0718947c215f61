"""Where the wind tunnel's shock layer stands: the gas's number density ahead of the airfoil.

Runs `wind-tunnel` for each case given and writes, per run, the
number density on a grid of cells around the leading edge (NumPy .npz: the map, its edges,
the free stream's density) and a profile along the line through the leading edge parallel to
the free stream: where the density first exceeds twice the free stream's upstream of the
nose is the shock's stand-off.

Usage: python3 benchmarks/bow_shock.py --backend cuda --time 20 --case default \
           --case seed:contact.restitution=0,timestep.integrator=forward-euler --out DIR
"""
import argparse
import json
import os
import time

import numpy as np

import corpuscle

ap = argparse.ArgumentParser()
ap.add_argument("--backend", default="cuda")
ap.add_argument("--time", type=float, default=20.0)
ap.add_argument("--particles", type=int, default=0)
ap.add_argument("--case", action="append", default=[], help="NAME[:key=value,...] (scene overrides)")
ap.add_argument("--out", default=".")
ap.add_argument("--cell", type=float, default=0.004, help="map cell edge, m")
args = ap.parse_args()
os.makedirs(args.out, exist_ok=True)

def parse(case):
    name, _, rest = case.partition(":")
    over = {}
    for kv in filter(None, rest.split(",")):
        k, _, v = kv.partition("=")
        try:
            over[k] = float(v)
        except ValueError:
            over[k] = v
    return name, over


for tag, over in map(parse, args.case or ["default"]):
    kw = {"particles": args.particles} if args.particles else {}
    sim = corpuscle.Simulation.from_scene("wind-tunnel", backend=args.backend, overrides=over, **kw)
    t0 = time.perf_counter()
    sim.run(until=args.time)
    wall = time.perf_counter() - t0
    x = np.asarray(sim.field("position", copy=True), dtype=np.float64)
    sc = sim.scene
    lo = np.array([-0.5 * 3.56, -1.0])
    le = np.array([-1.2, 0.0])
    try:
        le = np.array(sc["airfoil.leading_edge"], dtype=np.float64)
    except Exception:  # noqa: BLE001 - the default's position
        pass
    n_free = len(x) / (3.56 * 2.0)  # particles per m^2 (the airfoil's area is small)
    ex = np.arange(le[0] - 0.30, le[0] + 0.30 + 1e-9, args.cell)
    ey = np.arange(le[1] - 0.25, le[1] + 0.20 + 1e-9, args.cell)
    H, _, _ = np.histogram2d(x[:, 0], x[:, 1], bins=[ex, ey])
    dens = H / (args.cell * args.cell) / n_free
    # the profile: a band 2 cells high through the leading edge, upstream of it
    band = np.abs(x[:, 1] - le[1]) < args.cell
    px = np.arange(le[0] - 0.30, le[0] + 0.02, args.cell / 2)
    hp, _ = np.histogram(x[band, 0], bins=px)
    prof = hp / (2 * args.cell * args.cell / 2) / n_free
    centres = 0.5 * (px[1:] + px[:-1])
    above = np.nonzero(prof > 2.0)[0]
    standoff = float(le[0] - centres[above[0]]) if len(above) else float("nan")
    np.savez_compressed(os.path.join(args.out, f"bow_{tag}.npz"), density=dens, ex=ex, ey=ey, profile_x=centres,
                        profile=prof, leading_edge=le)
    res = sim.result()
    print(json.dumps({"case": tag, "overrides": over, "time": sim.time, "wall_s": round(wall, 2),
                      "cl": res.get("cl"), "cd": res.get("cd"),
                      "first_x_above_2x_free_upstream_of_le": standoff,
                      "profile_max": float(prof.max()) if len(prof) else None}))
