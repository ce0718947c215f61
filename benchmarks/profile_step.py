"""A few steps of the default scene on CUDA, for `ncu` (kernel durations and stall reasons).

Usage: ncu [options] python3 benchmarks/profile_step.py [particles] [steps]
"""
import sys

from corpuscle.simulation import Simulation

n = int(sys.argv[1]) if len(sys.argv) > 1 else 3500
steps = int(sys.argv[2]) if len(sys.argv) > 2 else 4
sim = Simulation.from_scene("magic8ball", backend="cuda", particles=n)
sim.step(steps)
print(sim.state()["step"])
