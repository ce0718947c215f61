"""corpuscle: GPU particle simulator (SPH fluids, DEM gases and granular media, rigid bodies).

`corpuscle.Simulation` runs a scene on the serial, OpenMP (cpu) or CUDA backend;
`corpuscle.Batch` runs many independent Magic 8-Balls together (`corpuscle.envs` has a
Gymnasium vector environment over it);
`corpuscle.open(path)` reads a recorded run. The compiled core is imported lazily so that
scenes and the CLI's input checks work even where it is missing.
"""

__version__ = "0.1.0"

from . import _omp

# the OpenMP runtime's thread count and wait policy, set before the compiled core loads it
_omp.configure()

__all__ = ["Simulation", "Batch", "open", "load_scene", "__version__"]


def __getattr__(name):
    # lazy exports: the compiled core is only loaded when a simulation is asked for
    if name == "Simulation":
        from .simulation import Simulation
        return Simulation
    if name == "Batch":
        from .batch import Batch
        return Batch
    if name == "open":
        from .io import open as open_run
        return open_run
    if name == "load_scene":
        from .scene import load_scene
        return load_scene
    raise AttributeError(f"module 'corpuscle' has no attribute {name!r}")
