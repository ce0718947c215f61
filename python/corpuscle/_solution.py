"""Time to solution and memory per particle, as `run --json`, `run`'s summary and `bench`
report them beside steps/s and particle-steps/s.

- wall seconds per simulated second: the stepping's wall time over the simulated time it
  advanced (what a user waits for one second of the flow; steps/s hides how large the steps
  are, which the CFL condition sets from the spacing and the sound speed);
- fluid and wall particles (a kind with walls of boundary particles: the SPH box);
- bytes per particle (fluid and wall together: every slot is stored alike) from the core's
  own estimate, ``_core.bytes_needed`` (what the memory check refuses a scene by), and the
  largest scene of this kind, index and per-particle cost the device holds: its memory free
  now plus what this scene took, over the bytes per particle.
"""

from __future__ import annotations

import math
from typing import Any


def wall_per_sim_second(wall_seconds: float, sim_seconds: float) -> float | None:
    """Wall seconds per simulated second, None when no simulated time passed."""
    if not (sim_seconds > 0.0) or not math.isfinite(sim_seconds):
        return None
    return float(wall_seconds) / float(sim_seconds)


def particle_counts(sim) -> dict[str, int]:
    """{"fluid_particles", "wall_particles"} of a kind with walls of particles; {} otherwise."""
    info = getattr(sim, "info", None) or {}
    if "n_wall" not in info or "n_fluid" not in info:
        return {}
    return {"fluid_particles": int(info["n_fluid"]), "wall_particles": int(info["n_wall"])}


def memory_per_particle(sim) -> dict[str, Any]:
    """{"bytes_needed", "bytes_per_particle", "largest_particles"} of a single simulation
    whose kind stores fluid and wall slots (the SPH box); {} for others or where the core
    cannot say. The lists' capacity is the one the run has now (it grows when a list
    overflows)."""
    from .kinds import Target, core, memory_available

    counts = particle_counts(sim)
    params = getattr(sim, "params", None)
    if not counts or not isinstance(params, dict):
        return {}
    n = counts["fluid_particles"] + counts["wall_particles"]
    p = dict(params)
    try:
        cap = sim.core.scalars().get("list_capacity")
        if cap is not None and "max_neighbors" in p:
            p["max_neighbors"] = int(cap)
        need = float(core().bytes_needed(sim.kind.name, sim.neighbors, p))
    except Exception:  # noqa: BLE001 (a kind the core does not estimate this way)
        return {}
    per = need / n if n > 0 else float("nan")
    have, _ = memory_available(Target(sim.backend, sim.neighbors, getattr(sim, "device", 0)))
    out: dict[str, Any] = {"bytes_needed": need, "bytes_per_particle": per, "largest_particles": None}
    if have is not None and per > 0:
        # (this scene's buffers are allocated already: what it took is free to a larger one)
        out["largest_particles"] = int((have + need) / per)
    return out


def memory_table(scene, backend: str, device: int = 0, particles: int = 20000) -> list[dict[str, Any]]:
    """Bytes per particle of a scene of a kind with fluid and wall slots, for each of its
    indexes (and, for `lists`, each list storage), and the largest count of particles the
    backend's memory holds so (``corpuscle info --memory``). The estimate is the core's
    (``_core.bytes_needed``) for the scene at about ``particles`` fluid particles (the bytes
    a particle hardly depend on the size: the cells' table is a few bytes a particle)."""
    from . import _core
    from .kinds import Target, core, find, memory_available

    kind = find(scene.kind)
    indexes = dict(_core.kinds(hidden=True)).get(scene.kind, ())
    small = scene.with_overrides({"fluid.particles": int(particles), "fluid.spacing": 0.0})
    have, where = memory_available(Target(backend, "grid", device))
    rows = []
    for idx in indexes:
        storages = ("slots", "delta") if idx == "lists" and "sph.list_storage" in scene.values else (None,)
        for st in storages:
            sc = small if st is None else small.with_overrides({"sph.list_storage": st})
            params = kind.build(sc, Target(backend, idx, device)).params
            n = int(params.get("n_fluid", 0)) + int(params.get("n_wall", 0))
            if n <= 0:
                continue
            per = float(core().bytes_needed(scene.kind, idx, params)) / n
            rows.append({"index": idx, "list_storage": st, "bytes_per_particle": per,
                         "largest_particles": int(have / per) if have else None, "memory": have, "where": where})
    return rows
