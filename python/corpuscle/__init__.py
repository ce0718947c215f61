"""corpuscle: GPU particle simulator (SPH fluids, DEM, rigid bodies)."""

__version__ = "0.1.0"
