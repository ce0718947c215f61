"""Weakly compressible SPH in a closed box: what the kinds ``fluid-box`` (seed 002's block of
fluid in a box), ``dam-break`` (3-D) and ``dam-break-2d`` (Martin & Moyce's column of width a
and height 2a against a wall) share. The core is cpp/include/corpuscle/scenes/sph/.
(It is longer than 600 lines: the kind's keys, build and readings for every SPH box feature meet
here; the probes' and the bodies' own logic is in _sph_probes.py and _sph_bodies.py.)

The model is DualSPHysics's: continuity density, Tait's equation of state, Monaghan's
artificial or the laminar viscosity, optional delta-SPH (Molteni & Colagrossi 2009 or
Fourtakas et al. 2019), the CFL time step, the Verlet scheme (or symplectic Euler). Walls are dynamic boundary
particles (DBC; Crespo, Gomez-Gesteira & Dalrymple 2007): lattice layers outside every face
of the box, as deep as the kernel support, whose density follows the continuity equation.

Particles start on a square lattice of spacing dp (from ``fluid.particles`` or
``fluid.spacing``), the fluid's density hydrostatic, rho = rho0 (1 + rho0 g d / B)^(1/gamma)
at depth d; the walls' density is hydrostatic where fluid lies above them. The box's
extents are rounded to whole multiples of dp.

Probes (``[[probes]]`` with ``name`` and ``position``) sample pressure and velocity by
kernel interpolation (Shepard-normalised, as DualSPHysics's MeasureTool) in every step;
they are recorded with every frame as the diagnostics ``probe_<name>_p``, ``_vx``, ... .
"""

from __future__ import annotations

import math
import weakref
from typing import Any, Callable

import numpy as np

from ..schema import INT64_MAX, CrossCheck, KeySpec, SceneError, SceneKind, _fmt_value, check_le
from . import Build, Kind, Target, check_memory, core, key_values
from ._sph_bodies import (MAX_BODIES, body_keys, build_bodies, check_bodies, contact_params, header_obstacles,
                          moving_arrays)
from ._sph_probes import (PROBE_SERIES, ProbeSeries, _check_probe_faces, _check_probes, _probes_inside,  # noqa: F401
                          is_gauge, pressure_impulse, probe_face_params, probe_face_reach, probe_keys, probe_sample_points,
                          probe_samples_of)

KERNELS = {"wendland": 4, "cubic-spline": 3, "poly6-spiky": 0}
VISCOSITIES = {"artificial": 0, "laminar": 1}
DIFFUSIONS = {"none": 0, "molteni": 1, "fourtakas": 2}
INTEGRATORS = {"verlet": 0, "symplectic-euler": 1}
UNSTABLE_REASONS = {1: "a density, velocity or position became non-finite (NaN/inf)",
                    2: "the neighbour lists overflowed and could not grow (not enough memory)"}

_K = KeySpec


def common_keys(dim: int, *, end_time: float, record_every: int, smoothing: float, alpha: float) -> dict[str, KeySpec]:
    """The keys every SPH box kind has (with this kind's defaults)."""
    return {
        "run.end_time": _K("float", end_time, "s", 0.0, 1e7, "simulated time at which the run ends", lo_open=True),
        "run.seed": _K("int", 0, "", 0, INT64_MAX, "random seed (the start is a lattice: unused)"),
        "run.record_every": _K("int", record_every, "steps", 1, 10**9, "record a frame every this many steps"),
        "run.rebalance": _K("float", 0.0, "", 0.0, 1e3,
                            "split over MPI ranks: move the slab cuts to even out the measured work at a relisting "
                            "when the ranks' core time (max / mean since the last balance) passes this; 0: never "
                            "(docs/distributed.md)"),
        "fluid.particles": _K("int", 0, "", 0, 2**31 - 1,
                              "fluid particles (approximately: a lattice fills the block); 0: the kind's default "
                              "for the backend, unless fluid.spacing is set"),
        "fluid.spacing": _K("float", 0.0, "m", 0.0, 1e3, "lattice spacing dp; 0: from fluid.particles"),
        "fluid.density": _K("float", 1000.0, "kg/m^3", 0.0, 1e6, "rest density rho0", lo_open=True),
        "fluid.sound_speed": _K("float", 0.0, "m/s", 0.0, 1e6,
                                "numerical sound speed c0; 0: fluid.sound_factor times sqrt(2 g H), H the fluid height"),
        "fluid.sound_factor": _K("float", 10.0, "", 1.0, 1e3,
                                 "c0 over the largest free-fall speed sqrt(2 g H) when fluid.sound_speed = 0 "
                                 "(10: density changes near 1%)"),
        "fluid.gamma": _K("float", 7.0, "", 1.0, 20.0, "Tait exponent"),
        "fluid.gravity": _K("float", 9.81, "m/s^2", 0.0, 1e4, "gravity (along -z in 3-D, -y in 2-D)"),
        "sph.kernel": _K("enum", "wendland", "", doc="wendland (Wendland C2), cubic-spline, or poly6-spiky "
                         "(the seed's: Poly6 interpolation, Spiky gradient)", choices=tuple(KERNELS)),
        "sph.smoothing": _K("float", smoothing, "dp", 0.5, 4.0,
                            "smoothing length hs over dp; the kernel support is 2 hs (DualSPHysics: hs = 1.732 dp "
                            "in 3-D, about 170 neighbours)"),
        "sph.viscosity": _K("enum", "artificial", "", doc="artificial (Monaghan 1992) or laminar (Lo & Shao 2002)",
                            choices=tuple(VISCOSITIES)),
        "sph.alpha": _K("float", alpha, "", 0.0, 10.0, "artificial viscosity alpha"),
        "sph.beta": _K("float", 0.0, "", 0.0, 10.0, "artificial viscosity beta (DualSPHysics: 0)"),
        "sph.nu": _K("float", 1e-6, "m^2/s", 0.0, 1e3, "kinematic viscosity of the laminar model"),
        "sph.diffusion": _K("enum", "fourtakas", "", doc="density diffusion: none, molteni (Molteni & Colagrossi "
                            "2009) or fourtakas (Fourtakas et al. 2019, DualSPHysics's DDT2)", choices=tuple(DIFFUSIONS)),
        "sph.delta": _K("float", 0.1, "", 0.0, 1.0, "density diffusion coefficient delta"),
        "sph.skin": _K("float", 0.08, "h", 0.0, 1.0,
                       "--neighbors lists: the lists reach h (1 + skin), h the kernel support, and are reused "
                       "until a particle has moved skin h / 2; 0 relists every step (0.08: the fastest of "
                       "0.04 to 0.2 over whole dam-break runs on the H200; a still column's first steps "
                       "favour 0.04, docs/benchmarks.md)"),
        "sph.list_storage": _K("enum", "slots", "", doc="--neighbors lists: how the lists are stored: slots (four "
                               "bytes an entry) or delta (each entry one byte, its difference to the one before, "
                               "an escape and four bytes where that is not 1 to 254: about a quarter of the "
                               "memory; the same entries in the same order, so the same results)",
                               choices=("slots", "delta")),
        "sph.lanes": _K("int", 0, "", 0, 8,
                        "--neighbors lists: threads sharing a particle's list in the CUDA pair pass, 1, 2, 4 or 8 "
                        "(their partial sums merged in a fixed order); 0: chosen by the state's size (on CUDA the "
                        "fewest, up to 8, that give 400,000 threads; the CPU backends 1)"),
        "sph.order_by_id": _K("bool", False, "", doc="break the sort's ties within a cell by particle id, so "
                              "every particle's neighbours are summed in an order independent of its slot (a run "
                              "split over MPI ranks forces it on, and is then bitwise this one-process run; off: "
                              "one sort pass fewer)"),
        "timestep.cfl": _K("float", 0.2, "", 0.0, 1.0, "CFL number of the time step (DualSPHysics: 0.2)", lo_open=True),
        "timestep.dt_min": _K("float", 1e-9, "s", 0.0, 1.0, "smallest time step", lo_open=True),
        "timestep.dt_max": _K("float", 1e-3, "s", 0.0, 1.0, "largest time step", lo_open=True),
        "timestep.integrator": _K("enum", "verlet", "", doc="verlet (DualSPHysics's default, an Euler step every "
                                  "timestep.verlet_steps) or symplectic-euler (needs a CFL near 0.05)",
                                  choices=tuple(INTEGRATORS)),
        "timestep.verlet_steps": _K("int", 40, "steps", 1, 10**6, "Verlet: an Euler step every this many steps"),
    } | boundary_keys(dim)


def boundary_keys(dim: int) -> dict[str, KeySpec]:
    """Periodic axes, moving walls, a body force and the initial flow (the canonical flows:
    Taylor-Green, Poiseuille, the lid-driven cavity)."""
    vec = f"vec{dim}"
    return {
        "boundary.periodic": _K("list[str]", [], "", doc="periodic axes (" + ", ".join("xyz"[:dim]) + "): no walls "
                                "across them, the fluid leaving one face enters the other and neighbours are found "
                                "across it (the minimum image)"),
        "walls.moving": _K("list[str]", [], "", doc="walls that move (a lid): faces " + ", ".join(
                           f"{a}-, {a}+" for a in "xyz"[:dim]) + " (top = " + "xyz"[dim - 1] + "+, bottom = "
                           + "xyz"[dim - 1] + "-); their particles carry walls.velocity in the pair terms and stay "
                           "in place (a wall sliding in its own plane)"),
        "walls.velocity": _K(vec, [0.0] * dim, "m/s", -1e4, 1e4, "the moving walls' velocity (tangential to them)"),
        "walls.layers": _K("int", 0, "dp", 0, 64, "lattice layers of wall (DBC) particles outside each face of the "
                           "box and inside each body's surface; 0: as deep as the kernel support, ceil(2 hs / dp) "
                           "(4 at hs = 1.732 dp); 1: DualSPHysics's drawing of a wall as one layer (about a quarter "
                           "of the wall particles; the fluid then sees a truncated kernel at the wall: "
                           "docs/sph_box.md)"),
        "fluid.body_force": _K(vec, [0.0] * dim, "m/s^2", -1e6, 1e6, "a body acceleration added to gravity (drives "
                               "a periodic channel: Poiseuille flow)"),
        "fluid.background_pressure": _K("float", 0.0, "Pa", 0.0, 1e9, "a constant added to the pressure in the "
                                        "pressure gradient only (keeps it positive in a vortex's core: no tensile "
                                        "instability; the pressure fields report p without it)"),
        "sph.shifting": _K("float", 0.0, "", 0.0, 100.0, "particle shifting A (Skillen et al. 2013: each step a "
                           "particle moves by -A hs |v| dt grad C, keeping the particles evenly spread in a "
                           "stretching flow; 2 is DualSPHysics's); 0: off. For flows with no free surface"),
        "sph.transport_velocity": _K("bool", False, "", doc="the transport-velocity formulation (Adami, Hu & "
                                     "Adams 2013): the particles move with the momentum velocity plus the push of a "
                                     "background pressure (sph.transport_pressure) over the step, which keeps them "
                                     "evenly spread where the flow stretches them, and the momentum equation gains "
                                     "the extra stress rho v (v~ - v). For flows with no free surface"),
        "sph.transport_pressure": _K("float", 0.0, "Pa", 0.0, 1e12, "the transport velocity's background pressure "
                                     "p_b; 0: rho0 c0^2 (the paper's reference pressure)"),
        "flow.initial": _K("enum", "rest", "", doc="the fluid's initial velocity: rest, or taylor-green (2-D, "
                           "periodic in x and y: u = U sin(2 pi x / Lx) cos(2 pi y / Ly), v = -U cos sin, with its "
                           "pressure)", choices=("rest", "taylor-green")),
        "flow.speed": _K("float", 1.0, "m/s", 0.0, 1e4, "U of flow.initial = taylor-green", lo_open=True),
    }


def _face(name: str, dim: int) -> tuple[int, int] | None:
    """(axis, side) of a face name (x-, x+, ..., top, bottom; side -1 or +1), None if unknown."""
    if name == "top":
        return dim - 1, 1
    if name == "bottom":
        return dim - 1, -1
    if len(name) == 2 and name[0] in "xyz"[:dim] and name[1] in "+-":
        return "xyz".index(name[0]), 1 if name[1] == "+" else -1
    return None


def _check_boundaries(dim: int) -> CrossCheck:
    """Periodic axes are axes of the kind, once each, with no moving wall on them; moving walls
    are faces of the box sliding in their own plane; the Taylor-Green start needs 2-D and both
    axes periodic."""
    axes = "xyz"[:dim]

    def check(values, arrays) -> None:
        per = list(values["boundary.periodic"])
        for a in per:
            if a not in axes:
                raise SceneError(f"boundary.periodic = {_fmt_value(per)}: {a!r} is not an axis of this kind "
                                 f"({', '.join(axes)})")
        if len(set(per)) != len(per):
            raise SceneError(f"boundary.periodic = {_fmt_value(per)} names an axis twice")
        moving = list(values["walls.moving"])
        vel = np.asarray(values["walls.velocity"], dtype=np.float64)
        for f in moving:
            fa = _face(f, dim)
            if fa is None:
                raise SceneError(f"walls.moving = {_fmt_value(moving)}: {f!r} is not a face (" + ", ".join(
                    f"{a}-, {a}+" for a in axes) + ", top, bottom)")
            if axes[fa[0]] in per:
                raise SceneError(f"walls.moving = {_fmt_value(moving)}: the face {f!r} lies across the periodic axis "
                                 f"{axes[fa[0]]!r} (boundary.periodic), which has no walls")
            if vel[fa[0]] != 0.0:
                raise SceneError(f"walls.velocity = {_fmt_value(values['walls.velocity'])} moves the wall {f!r} "
                                 f"along its normal: only walls sliding in their own plane are supported")
        if len(set(_face(f, dim) for f in moving)) != len(moving):
            raise SceneError(f"walls.moving = {_fmt_value(moving)} names a face twice")
        if values["sph.transport_velocity"]:
            for key, off in (("sph.shifting", 0.0), ("fluid.background_pressure", 0.0)):
                if values[key] != off:
                    raise SceneError(f"{key} = {_fmt_value(values[key])} with sph.transport_velocity = true: the "
                                     f"transport velocity keeps the particles spread itself (use one or the other)")
        if values["flow.initial"] == "taylor-green" and (dim != 2 or set(per) != {"x", "y"}):
            raise SceneError(f"flow.initial = 'taylor-green' needs a 2-D kind periodic in x and y "
                             f"(boundary.periodic = [\"x\", \"y\"]), got boundary.periodic = {_fmt_value(per)}")
    return check


def _check_rebalance(values, arrays) -> None:
    """run.rebalance is a ratio of the slowest rank's time to the mean: above 1 (or 0: never)."""
    r = values["run.rebalance"]
    if r != 0 and not r > 1.0:
        raise SceneError(f"run.rebalance must be above 1 (the slowest rank's time over the mean) or 0 (never), "
                         f"got {_fmt_value(r)}")


def _check_lanes(values, arrays) -> None:
    """sph.lanes is a width the lists pair pass has (or 0: automatic)."""
    if values["sph.lanes"] not in (0, 1, 2, 4, 8):
        raise SceneError(f"sph.lanes must be 0 (automatic), 1, 2, 4 or 8, got {_fmt_value(values['sph.lanes'])}")



def lattice(lo_cells, hi_cells, dp: float) -> np.ndarray:
    """Lattice points (i + 1/2) dp for integer cells lo <= i < hi per axis (float64, (n, D))."""
    axes = [(np.arange(a, b) + 0.5) * dp for a, b in zip(lo_cells, hi_cells)]
    grids = np.meshgrid(*axes, indexing="ij")
    return np.column_stack([g.ravel() for g in grids])


def hydrostatic_density(depth, rho0: float, B: float, gamma: float, g: float) -> np.ndarray:
    """rho = rho0 (1 + rho0 g d / B)^(1/gamma): Tait's density (the core's inverse of its
    equation of state, physics/tait.h, in double) at the pressure rho0 g d of depth d (d <= 0:
    rho0)."""
    d = np.maximum(np.asarray(depth, dtype=np.float64), 0.0)
    p = np.ascontiguousarray(rho0 * g * d, dtype=np.float64)
    return core().tait_density(p.ravel(), rho0, B, gamma).reshape(p.shape)


class SphBox(Kind):
    """A box of SPH fluid; subclasses give the geometry (:meth:`geometry`) and defaults."""
    fluid = True

    particle_key = "fluid.particles"
    unstable_reasons = UNSTABLE_REASONS
    frame_fields = ()  # the core's table marks what frames record (position, density, pressure)
    default_particles: dict[str, int] = {}

    def __init__(self) -> None:
        self._series: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()

    @property
    def units(self) -> dict[str, str]:  # type: ignore[override]
        return {"position": "m", "velocity": "m/s", "density": "kg/m^3", "pressure": "Pa", "kinetic_energy": "J",
                "vmax": "m/s", "p_max": "Pa", "mean_neighbors": "count", "outside": "count"}

    # geometry ----------------------------------------------------------------------------
    def geometry(self, v: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(box size, fluid block lower corner, fluid block upper corner), float64, in m."""
        raise NotImplementedError

    def _spacing(self, v, target: Target) -> tuple[float, int]:
        size, flo, fhi = self.geometry(v)
        vol = float(np.prod(fhi - flo))
        dp = float(v["fluid.spacing"])
        n = int(v["fluid.particles"])
        if dp <= 0.0:
            n = n or self.default_particles.get(target.backend, self.default_particles.get("cpu", 8192))
            dp = (vol / n) ** (1.0 / self.dim)
        return dp, n

    def build(self, scene, target: Target, checkpoint: dict | None = None) -> Build:
        v = scene.values
        D = self.dim
        size, flo, fhi = self.geometry(v)
        dp, _ = self._spacing(v, target)
        # whole cells of dp: the box [0, nb dp], the fluid block [f0 dp, f1 dp]
        nb = np.maximum(np.rint(size / dp).astype(np.int64), 1)
        f0 = np.clip(np.rint(flo / dp).astype(np.int64), 0, nb)
        f1 = np.clip(np.rint(fhi / dp).astype(np.int64), 0, nb)
        if np.any(f1 <= f0):
            raise SceneError(f"{key_values(scene, ('fluid.particles', 'fluid.spacing'))}: spacing {dp:.3g} m "
                             f"leaves no fluid in the block")
        smoothing = float(v["sph.smoothing"])
        hs = smoothing * dp
        h = 2.0 * hs
        support_layers = int(math.ceil(h / dp - 1e-6))
        # walls.layers: the DBC walls' thickness in lattice layers (0: the kernel support's)
        layers = int(v["walls.layers"]) or support_layers
        # periodic axes: no wall layers across them (the walls of the other axes span the period)
        periodic = np.array(["xyz"[k] in v["boundary.periodic"] for k in range(D)])
        wall_layers = np.where(periodic, 0, layers)
        # [[bodies]]: their boundary particles join the walls; no fluid inside them (_sph_bodies.py)
        fluid_pts = lattice(f0, f1, dp)
        bodies, body_pts, owner, clear, motions = build_bodies(scene.arrays, D, dp, layers, fluid_pts)
        fluid_pts = fluid_pts[clear]
        nf_est = len(fluid_pts)
        if nf_est == 0:
            raise SceneError("bodies: the bodies fill the whole fluid block (no fluid is left)")
        box_cells = int(np.prod(nb + 2 * wall_layers) - np.prod(nb)) + len(body_pts)
        if nf_est + box_cells > 2**31 - 1:
            raise SceneError(f"{key_values(scene, ('fluid.particles', 'fluid.spacing'))}: "
                             f"{nf_est + box_cells} particles, more than 2^31 - 1")
        rho0 = float(v["fluid.density"])
        gamma = float(v["fluid.gamma"])
        g = float(v["fluid.gravity"])
        height = float((f1[-1] - f0[-1]) * dp)
        if g <= 0.0 and float(v["fluid.sound_speed"]) <= 0.0:
            raise SceneError("fluid.gravity = 0 needs fluid.sound_speed > 0 (c0 is otherwise taken from the "
                             "free-fall speed sqrt(2 g H))")
        c0 = float(v["fluid.sound_speed"]) or float(v["fluid.sound_factor"]) * math.sqrt(2.0 * g * height)
        B = core().tait_stiffness(c0, rho0, gamma)  # c0^2 rho0 / gamma (physics/tait.h, in double)
        box_hi = nb * dp
        probes = [p["position"] for p in scene.arrays.get("probes", [])]
        gravity = (np.array([0.0] * (D - 1) + [-g]) + np.asarray(v["fluid.body_force"], dtype=np.float64)).tolist()
        skin_ = float(v["sph.skin"]) if target.index == "lists" else 0.0
        self._check_periods(scene, periodic, box_hi, h * (1.0 + skin_))
        domain_lo = np.where(periodic, 0.0, -(layers + 1) * dp)
        domain_hi = np.where(periodic, box_hi, box_hi + (layers + 1) * dp)
        params = {
            "n_fluid": nf_est, "n_wall": int(box_cells), "kernel": KERNELS[v["sph.kernel"]], "h": h, "hs": hs,
            "mass": rho0 * dp ** D, "rho0": rho0, "c0": c0, "gamma": gamma,
            "viscosity": VISCOSITIES[v["sph.viscosity"]], "alpha": float(v["sph.alpha"]), "beta": float(v["sph.beta"]),
            "nu": float(v["sph.nu"]), "diffusion": DIFFUSIONS[v["sph.diffusion"]], "delta": float(v["sph.delta"]),
            "cfl": float(v["timestep.cfl"]), "dt_min": float(v["timestep.dt_min"]),
            "dt_max": float(v["timestep.dt_max"]), "gravity": gravity,
            "integrator": INTEGRATORS[v["timestep.integrator"]], "verlet_steps": int(v["timestep.verlet_steps"]),
            "box_lo": [0.0] * D, "box_hi": box_hi.tolist(),
            "domain_lo": domain_lo.tolist(), "domain_hi": domain_hi.tolist(),
            "probes": [float(x) for p in probes for x in p],
            **probe_face_params(scene.arrays, D, dp),
            "periodic": int(sum(1 << k for k in range(D) if periodic[k])),
            "background_pressure": float(v["fluid.background_pressure"]), "shifting": float(v["sph.shifting"]),
            "transport_velocity": int(bool(v["sph.transport_velocity"])),
            "transport_pressure": float(v["sph.transport_pressure"]) or rho0 * c0 * c0,
        }
        # --neighbors lists: slot lists within h (1 + skin), rebuilt once a particle has moved
        # skin h / 2; capacity 1.3 times the count within that reach at the lattice spacing
        # (the fluid compresses ~1%), plus 32 (a list that still overflows grows)
        skin = float(v["sph.skin"]) if target.index == "lists" else 0.0
        reach = h * (1.0 + skin) / dp
        mean = 4.0 / 3.0 * math.pi * reach ** 3 if D == 3 else math.pi * reach ** 2
        params["list_radius"] = h * (1.0 + skin)
        params["rebuild_distance"] = 0.5 * skin * h * (1.0 - 1e-5)  # (a margin for the float distances)
        params["max_neighbors"] = int(math.ceil((1.3 * mean + 32) / 32.0)) * 32 if target.index == "lists" else 1
        delta = target.index == "lists" and v["sph.list_storage"] == "delta"
        params["list_delta"] = int(delta)
        if delta:
            # bytes: an entry's byte, and four more for each escape (one a cell range with
            # neighbours, 3^(D-1) of them: spatial/delta_list.h)
            params["max_neighbors"] = int(math.ceil((1.3 * mean + 32 + 4 * 3 ** (D - 1)) / 32.0)) * 32
        params["lanes"] = int(v["sph.lanes"])
        params["order_by_id"] = int(bool(v["sph.order_by_id"]))
        params["rebalance"] = float(v["run.rebalance"])
        check_memory(self.name, target, params, key_values(scene, ("fluid.particles", "fluid.spacing")),
                     f"{nf_est + box_cells} particles")
        # the walls: every lattice point of the box widened by `layers` that is not inside it
        pts = lattice(-wall_layers, nb + wall_layers, dp)
        inside = np.all((pts > 0.0) & (pts < box_hi), axis=1)
        wall = np.concatenate([pts[~inside], body_pts]) if len(body_pts) else pts[~inside]
        wall_vel = self._wall_velocity(v, wall, box_hi)
        # moving bodies: the core sets their particles from their poses (scenes/sph/bodies.h)
        moving_params, moving, moving_index = moving_arrays(motions, owner, body_pts, len(wall), D)
        params.update(moving_params)
        if "body_free" in moving_params:  # free bodies: the tank's contact (_sph_bodies.contact_params)
            params["body_contact"] = contact_params(dp, h, c0)
        top = float(f1[-1] * dp)
        near = np.all((wall[:, :-1] > (f0[:-1] - layers) * dp) & (wall[:, :-1] < (f1[:-1] + layers) * dp), axis=1)
        wall_rho = np.where(near, hydrostatic_density(top - wall[:, -1], rho0, B, gamma, g), rho0)
        if checkpoint is None:
            pos = fluid_pts
            vel = np.zeros_like(pos)
            rho = hydrostatic_density(top - pos[:, -1], rho0, B, gamma, g)
            if v["flow.initial"] == "taylor-green":
                vel, rho = taylor_green(pos, box_hi, float(v["flow.speed"]), rho0, B, gamma)
        else:
            pos = np.asarray(checkpoint["position"], dtype=np.float64)
            vel = np.asarray(checkpoint["velocity"], dtype=np.float64)
            rho = np.asarray(checkpoint["density"], dtype=np.float64)
            if pos.shape != (nf_est, D):
                raise ValueError(f"checkpoint: {pos.shape[0] if pos.ndim else 0} fluid particles, the scene has {nf_est}")
            if "wall_density" in checkpoint:
                wall_rho = np.asarray(checkpoint["wall_density"], dtype=np.float64)
            if "wall_position" in checkpoint:
                wall = np.asarray(checkpoint["wall_position"], dtype=np.float64)
        arrays = {"position": np.ascontiguousarray(pos, dtype=np.float32),
                  "velocity": np.ascontiguousarray(vel, dtype=np.float32),
                  "density": np.ascontiguousarray(rho, dtype=np.float32),
                  "wall_position": np.ascontiguousarray(wall, dtype=np.float32).reshape(-1, D),
                  "wall_density": np.ascontiguousarray(wall_rho, dtype=np.float32)}
        if wall_vel is not None:
            arrays["wall_velocity"] = np.ascontiguousarray(wall_vel, dtype=np.float32).reshape(-1, D)
        arrays.update(moving)
        info = {"spacing": dp, "h": h, "hs": hs, "mass": rho0 * dp ** D, "rho0": rho0, "c0": c0, "B": B,
                "gamma": gamma, "gravity": g, "layers": layers, "support_layers": support_layers, "box": box_hi.copy(), "fluid_height": height,
                "fluid_lo": f0 * dp, "fluid_hi": f1 * dp, "n_fluid": nf_est, "n_wall": int(box_cells),
                "probe_names": [str(p["name"]) for p in scene.arrays.get("probes", [])],
                "probe_gauges": [is_gauge(p) for p in scene.arrays.get("probes", [])],
                "probe_positions": np.asarray(probes, dtype=np.float64).reshape(-1, D),
                "periodic": [a for a in "xyz"[:D] if a in v["boundary.periodic"]],
                "moving_walls": list(v["walls.moving"]), "wall_speed": list(map(float, v["walls.velocity"])),
                "body_force": list(map(float, v["fluid.body_force"])),
                "n_body_particles": int(len(body_pts)), "obstacles": header_obstacles(bodies, motions),
                "moving_bodies": [bodies[k].name for k in moving_index], "moving_obstacles": moving_index,
                "free_bodies": [bodies[k].name for k in moving_index if scene.arrays["bodies"][k]["motion"] == "free"]}
        info.update(self.extra_info(v, info))
        return Build(params, arrays, info)

    def extra_info(self, v, info) -> dict[str, Any]:
        return {}

    # periodic axes and moving walls ------------------------------------------------------------
    def _check_periods(self, scene, periodic, box_hi, radius: float) -> None:
        """A periodic axis holds three cells of the neighbour search's radius (so the cells
        around one are three distinct ones): one line naming the keys otherwise."""
        for k in np.flatnonzero(periodic):
            if box_hi[k] < 3.0 * radius * (1.0 + 4e-6):
                raise SceneError(f"boundary.periodic = {_fmt_value(list(scene.values['boundary.periodic']))}: the "
                                 f"box is {box_hi[k]:.4g} m along {'xyz'[k]}, less than three neighbour radii "
                                 f"(3 x {radius:.4g} m, the kernel support 2 sph.smoothing dp with the lists' skin): "
                                 f"use a longer box or a smaller spacing")

    def _wall_velocity(self, v, wall: np.ndarray, box_hi: np.ndarray) -> np.ndarray | None:
        """The wall particles' prescribed velocity: walls.velocity on the particles beyond a
        face of walls.moving (the corners' too), zero elsewhere; None when no wall moves."""
        if not v["walls.moving"]:
            return None
        moving = np.zeros(len(wall), dtype=bool)
        for f in v["walls.moving"]:
            axis, side = _face(f, self.dim)
            moving |= wall[:, axis] > box_hi[axis] if side > 0 else wall[:, axis] < 0.0
        out = np.zeros_like(wall)
        out[moving] = np.asarray(v["walls.velocity"], dtype=np.float64)
        return out

    # reading -----------------------------------------------------------------------------
    def probes(self, sim, s: dict[str, Any] | None = None) -> dict[str, dict[str, Any]]:
        """name -> {position, pressure, velocity, weight} of the probes (the state at probe_time);
        a gauge's: {position (its lower end), level (m above it), elevation (its height coordinate),
        weight (the filling at its lower end)}."""
        s = sim.core.scalars() if s is None else s
        out = {}
        p, vel, w = s["probe_pressure"], s["probe_velocity"], s["probe_weight"]
        nan = float("nan")
        gauges = sim.info["probe_gauges"]
        for k, name in enumerate(sim.info["probe_names"]):
            if gauges[k]:
                x0 = sim.info["probe_positions"][k]
                out[name] = {"position": x0.tolist(), "level": float(p[k]),
                             "elevation": float(x0[-1]) + float(p[k]), "weight": float(w[k])}
                continue
            # no particle within the kernel's support: nothing measured (NaN; null in JSON), not 0
            seen = float(w[k]) > 0.0
            out[name] = {"position": sim.info["probe_positions"][k].tolist(),
                         "pressure": float(p[k]) if seen else nan,
                         "velocity": [float(x) if seen else nan for x in vel[3 * k:3 * k + self.dim]],
                         "weight": float(w[k])}
        return out

    # the probes' series (probe.h's rings, drained every PROBE_SERIES steps) ---------------
    def steps_between_drains(self, sim) -> int | None:
        return PROBE_SERIES if sim.info["probe_names"] else None

    def _probe_series(self, sim) -> ProbeSeries:
        store = self.__dict__.setdefault("_probe_store", weakref.WeakKeyDictionary())
        if sim not in store:
            store[sim] = ProbeSeries(sim.info["probe_names"])
        return store[sim]

    def drain(self, sim) -> None:
        if sim.info["probe_names"]:
            self._probe_series(sim).drain(sim.core.scalars())

    def probe_series(self, sim, name: str) -> tuple[np.ndarray, np.ndarray]:
        return self._probe_series(sim).series(name)

    def frame(self, sim, ghosts: bool = False, velocity: bool = False) -> dict[str, Any]:
        """The frame, with each probe's samples since the last frame (group probe.<name>:
        fields probe.<name>.time (s), probe.<name>.pressure (Pa; a gauge's: probe.<name>.level,
        m) and probe.<name>.position, the probe's centre for each sample)."""
        rec = super().frame(sim, ghosts=ghosts, velocity=velocity)
        if sim.info["probe_names"]:
            ser = self._probe_series(sim)
            gauges = sim.info["probe_gauges"]
            for k, name in enumerate(ser.names):
                value = "level" if gauges[k] else "pressure"
                t, p = ser.t[k][ser.recorded[k]:], ser.p[k][ser.recorded[k]:]
                ser.recorded[k] = len(ser.t[k])
                centre = np.asarray(sim.info["probe_positions"][k], dtype=np.float32)
                # (each sample at the probe's centre: a group of points any reader or exporter places)
                rec["fields"][f"probe.{name}.position"] = np.tile(centre, (len(t), 1))
                rec["fields"][f"probe.{name}.time"] = np.asarray(t, dtype=np.float64)
                rec["fields"][f"probe.{name}.{value}"] = np.asarray(p, dtype=np.float32)
                for f in ("position", "time", value):
                    rec["groups"][f"probe.{name}.{f}"] = f"probe.{name}"
        return rec

    def state(self, sim, s: dict[str, Any]) -> dict[str, Any]:
        return {"time": s["time"], "end_time": s["end_time"], "step": s["step"], "dt": s["dt"],
                "done": bool(s["done"]), "bad": s["bad"], "bad_step": s["bad_step"],
                "kinetic_energy": float(s["sums_ke"]), "vmax": float(s["vmax"]), "amax": float(s["amax"]),
                "rho_min": float(s["sums_rho_min"]), "rho_max": float(s["sums_rho_max"]),
                "p_max": float(s["sums_p_max"]), "mean_neighbors": float(s["mean_neighbors"]),
                "outside": int(s["outside"]), "outside_max": max(int(s["outside"]), int(s["outside_max"])),
                "chosen_dt": float(s["chosen_dt"]), "probe_time": float(s["probe_time"]),
                "rebuilds": int(s["rebuilds"]),
                "probes": self.probes(sim, s)}

    def diagnostics(self, sim, s: dict[str, Any]) -> dict[str, float]:
        st = self.state(sim, s)
        out = {k: float(st[k]) for k in ("kinetic_energy", "vmax", "rho_min", "rho_max", "p_max", "mean_neighbors",
                                         "outside")}
        out.update(self.body_diagnostics(sim, s))
        out["probe_time"] = st["probe_time"]
        axes = "xyz"[:self.dim]
        for name, p in st["probes"].items():
            if "level" in p:  # a gauge
                out[f"probe_{name}_level"] = p["level"]
                continue
            out[f"probe_{name}_p"] = p["pressure"]
            for a, x in zip(axes, p["velocity"]):
                out[f"probe_{name}_v{a}"] = x
        out.update(self.extra_diagnostics(sim))
        # the series the summary reports
        series = self._series.setdefault(sim, {})
        for k, x in out.items():
            series.setdefault(k, []).append(x)
        return out

    def extra_diagnostics(self, sim) -> dict[str, float]:
        return {}

    def body_poses(self, sim, s: dict[str, Any] | None = None) -> dict[str, dict[str, np.ndarray]]:
        """name -> {position, rotation (3 x 3), velocity, angular_velocity (rad/s), force, torque}
        of each moving body at the state's time (the core's record, scenes/sph/bodies.h; force and
        torque: a free body's, of the fluid and the tank's contact in the last step's state)."""
        s = sim.core.scalars() if s is None else s
        pose = np.asarray(s.get("body_pose", []), dtype=np.float64).reshape(-1, 18)
        force = np.asarray(s.get("body_force", np.zeros(6 * len(pose))), dtype=np.float64).reshape(-1, 6)
        out = {}
        for j, name in enumerate(sim.info.get("moving_bodies", [])):
            p = pose[j]
            out[name] = {"position": p[0:3], "rotation": p[3:12].reshape(3, 3), "velocity": p[12:15],
                         "angular_velocity": p[15:18], "force": force[j, 0:3], "torque": force[j, 3:6]}
        return out

    def body_diagnostics(self, sim, s: dict[str, Any]) -> dict[str, float]:
        """Each moving body's reference point and velocity (body_<name>_x, ..., _vx, ...) and, 3-D,
        its rotation matrix's rows (_r00 .. _r22), 2-D its angle (_angle, degrees)."""
        out = {}
        axes = "xyz"[:self.dim]
        for name, p in self.body_poses(sim, s).items():
            for k, a in enumerate(axes):
                out[f"body_{name}_{a}"] = float(p["position"][k])
                out[f"body_{name}_v{a}"] = float(p["velocity"][k])
            R = p["rotation"]
            if name in sim.info.get("free_bodies", ()):  # the fluid's and the contact's force on it
                for k, a in enumerate(axes):
                    out[f"body_{name}_f{a}"] = float(p["force"][k])
                if self.dim == 2:
                    out[f"body_{name}_torque"] = float(p["torque"][2])
            if self.dim == 2:
                out[f"body_{name}_angle"] = math.degrees(math.atan2(R[1, 0], R[0, 0]))
            else:
                for r in range(3):
                    for c in range(3):
                        out[f"body_{name}_r{r}{c}"] = float(R[r, c])
        return out

    def result(self, sim, s: dict[str, Any]) -> dict[str, Any]:
        st = self.state(sim, s)
        out: dict[str, Any] = {"fluid_particles": sim.info["n_fluid"], "wall_particles": sim.info["n_wall"],
                               "spacing": sim.info["spacing"], "mean_neighbors": st["mean_neighbors"],
                               "outside_max": st["outside_max"]}
        series = self._series.get(sim, {})
        for name in sim.info["probe_names"]:
            if "level" in st["probes"][name]:  # a gauge: its highest recorded level and the last
                lv = np.asarray(series.get(f"probe_{name}_level", []), dtype=np.float64)
                if lv.size:
                    out[f"probe_{name}_level_max"] = float(np.max(lv))
                out[f"probe_{name}_level"] = st["probes"][name]["level"]
                continue
            ps = np.asarray(series.get(f"probe_{name}_p", []), dtype=np.float64)
            ps = ps[np.isfinite(ps)]  # the records that measured something
            if ps.size:
                out[f"probe_{name}_p_max"] = float(np.max(ps))
                out[f"probe_{name}_p_mean"] = float(np.mean(ps))
            elif f"probe_{name}_p" in series:  # recorded, never near fluid
                out[f"probe_{name}_p_max"] = out[f"probe_{name}_p_mean"] = float("nan")
            out[f"probe_{name}_p"] = st["probes"][name]["pressure"]
        return out

    def summary(self, result: dict[str, Any]) -> tuple[list[str], dict[str, Any]]:
        """A probe that measured nothing (no fluid within the kernel's support of it) is
        named with the reason, not printed as a number."""
        lines, rest = [], dict(result)
        names = sorted({k[len("probe_"):-len("_p")] for k in result if k.startswith("probe_") and k.endswith("_p")})
        for name in names:
            keys = [f"probe_{name}_p", f"probe_{name}_p_max", f"probe_{name}_p_mean"]
            missing = [k for k in keys if k in result and not _finite(result[k])]
            if missing:
                lines.append(f"{', '.join(missing)}: not measured (no fluid within the kernel support of the probe)")
                for k in missing:
                    rest.pop(k)
        return lines, rest

    def header(self, sim) -> dict[str, Any]:
        p = sim.params
        return {"container": {"type": "box", "min": list(p["box_lo"]), "max": list(p["box_hi"])},
                "obstacles": list(sim.info.get("obstacles", [])), "bodies": [], "particles": sim.info["n_fluid"], "wall_particles": sim.info["n_wall"],
                "spacing": sim.info["spacing"], "h": sim.info["h"], "particle_radius": 0.5 * sim.info["spacing"],
                "probes": {n: sim.info["probe_positions"][k].tolist() for k, n in enumerate(sim.info["probe_names"])},
                "units": dict(self.units)}

    def control(self, sim, acceleration=(0.0, 0.0, 0.0)) -> dict[str, list[float]]:
        """A body acceleration (m/s^2) added to gravity from the next step on (shaking, tilting),
        each component within CONTROL_BOUNDS's."""
        from . import bounded_control
        a = list(acceleration)
        if len(a) == self.dim:
            a = a + [0.0] * (3 - self.dim)
        return {"acceleration": bounded_control("acceleration", a, 3)}

    def set_particles(self, sim, positions, velocities=None) -> None:
        from . import particle_array
        n = int(sim.info["n_fluid"])
        pos = particle_array("positions", positions, n, self.dim)
        vel = np.zeros_like(pos) if velocities is None else particle_array("velocities", velocities, n, self.dim)
        self.check_positions(sim, pos)
        sim.core.upload("position", pos)
        sim.core.upload("velocity", vel)

    def check_positions(self, sim, positions: np.ndarray) -> None:
        hi = np.asarray(sim.params["box_hi"])
        out = np.flatnonzero(~np.all((positions >= 0.0) & (positions <= hi), axis=1))
        if out.size:
            raise ValueError(f"positions[{int(out[0])}] = {positions[int(out[0])].tolist()} is outside the box")

    # helpers for the dam break -------------------------------------------------------------
    @staticmethod
    def fluid_positions(sim) -> np.ndarray:
        return np.asarray(sim.core.download("position"), dtype=np.float64)


def taylor_green(pos: np.ndarray, size: np.ndarray, U: float, rho0: float, B: float, gamma: float):
    """The 2-D Taylor-Green vortex at t = 0 in a periodic box of size (Lx, Ly): velocity
    u = U sin(kx x) cos(ky y), v = -U (kx / ky) cos(kx x) sin(ky y) (divergence-free), and the
    density of its pressure p = rho0 U^2 / 4 (cos(2 kx x) + (kx / ky)^2 cos(2 ky y)) by Tait's
    equation of state inverted (the core's, physics/tait.h)."""
    kx, ky = 2.0 * math.pi / size[0], 2.0 * math.pi / size[1]
    x, y = pos[:, 0], pos[:, 1]
    vel = np.column_stack([U * np.sin(kx * x) * np.cos(ky * y), -U * (kx / ky) * np.cos(kx * x) * np.sin(ky * y)])
    p = 0.25 * rho0 * U * U * (np.cos(2.0 * kx * x) + (kx / ky) ** 2 * np.cos(2.0 * ky * y))
    rho = core().tait_density(np.ascontiguousarray(p, dtype=np.float64), rho0, B, gamma)
    return vel, np.asarray(rho, dtype=np.float64)


def dam_front(pos: np.ndarray, dp: float) -> float:
    """The surge front: the largest x of the fluid plus half a spacing (a particle's extent)."""
    return float(pos[:, 0].max() + 0.5 * dp)


def column_height(pos: np.ndarray, dp: float) -> float:
    """The water height at the back wall (x = 0): the highest fluid within two spacings of it."""
    near = pos[:, 0] < 2.0 * dp
    return float(pos[near, -1].max() + 0.5 * dp) if near.any() else 0.0


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


def make_schema(name: str, description: str, keys: dict[str, KeySpec], dim: int, checks=(), *,
                box: Callable[[dict[str, Any]], Any]) -> SceneKind:
    """The kind's schema; ``box(values)`` is the tank's inner size (what probes must lie in)."""
    return SceneKind(name=name, description=description, keys=keys,
                     arrays={"probes": probe_keys(dim), "bodies": body_keys(dim)},
                     required_in_arrays={"probes": ("name", "position"), "bodies": ("shape",)},
                     max_in_arrays={"probes": 64,  # kMaxProbes of scenes/sph/model.h
                                    "bodies": MAX_BODIES},
                     checks=[check_le("timestep.dt_min", "timestep.dt_max"), _check_probes, _check_probe_faces,
                             _check_lanes, _check_rebalance, *checks, _probes_inside(box), _check_boundaries(dim),
                             check_bodies(box, dim)])

