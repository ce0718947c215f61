"""CUDA vs CPU on the device machine: one evaluation from the same state, then a short run.

Usage: python3 benchmarks/gpu_smoke.py [particles]
"""
import sys
import time

import numpy as np

from corpuscle.simulation import Simulation


def by_id(sim, name):
    ids = sim.field("id", copy=True)
    out = np.empty_like(sim.field(name, copy=True))
    out[ids] = sim.field(name, copy=True)
    return out


n = int(sys.argv[1]) if len(sys.argv) > 1 else 3500
cpu = Simulation.from_scene("magic8ball", backend="cpu", particles=n)
gpu = Simulation.from_scene("magic8ball", backend="cuda", particles=n)
sc, sg = cpu.evaluate(), gpu.evaluate()
for f in ("density", "acceleration"):
    a, b = by_id(cpu, f), by_id(gpu, f)
    err = np.abs(a - b).max() / (np.abs(a).max() + 1e-30)
    print(f"evaluate {f:13s} max|diff|/max = {err:.2e}")
print(f"chosen_dt cpu {sc['chosen_dt']:.6e} cuda {sg['chosen_dt']:.6e}; ghosts {sc['n_ghost']} {sg['n_ghost']}")
for steps in (10, 190):
    cpu.step(steps)
    gpu.step(steps)
    a, b = cpu.state(), gpu.state()
    pa, pb = by_id(cpu, "position"), by_id(gpu, "position")
    print(f"t={a['time']:.4f}/{b['time']:.4f} steps={a['step']}/{b['step']} ke={a['kinetic_energy']:.4f}/{b['kinetic_energy']:.4f} "
          f"mean_rho={a['mean_density']:.2f}/{b['mean_density']:.2f} die={np.round(a['die']['position'], 4)}/{np.round(b['die']['position'], 4)} "
          f"max|dx|={np.abs(pa - pb).max():.2e}")
t0 = time.perf_counter()
secs = [gpu.bench_steps(1000) for _ in range(5)]
print("cuda steps/s (median of 5 x 1000):", 1000 / np.median(secs), "particles", gpu.n_particles)
print("stages ms/step:", {k: round(v, 4) for k, v in gpu.stage_times(200).items()})
