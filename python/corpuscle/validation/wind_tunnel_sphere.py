"""`corpuscle validate wind-tunnel-sphere`: a mesh body's drag against free-molecular theory.

The sphere of the wind-tunnel-sphere scene (the shipped sphere.stl: 320 triangles held in the
engine's LBVH, contact by signed distance) in a collisionless gas (contact.enabled = false), a
Maxwellian free stream at speed ratio S, the body frictionless with restitution e (default 1:
specular reflection). In free-molecular flow a convex body neither shadows nor re-hits itself,
so its drag is the surface integral of the incident and reflected momentum fluxes, in closed
form for a sphere (corpuscle.free_molecular.sphere; Schaaf & Chambre 1958, Bird 1994 ch. 7):

    C_D = (1 + e) / 2 [ (2 S^2 + 1) / (sqrt(pi) S^3) exp(-S^2) + (4 S^4 + 4 S^2 - 1) / (2 S^4) erf(S) ]

per q pi R^2. The particle centres touch the mesh offset by the particle radius r, so the
reference is that offset polyhedron's drag (free_molecular.convex_polyhedron: the faces, the
edges' cylinders, the vertices' patches; it tends to the sphere of radius R + r as the facets
shrink, and the check also reports the smooth sphere's value for R + r).

The set-up is the 2-D validation's (corpuscle.validation.wind_tunnel): the gas starts as a
uniform random gas of the free stream, re-enters with the flux-weighted velocities of the
drifting Maxwellian, the channel walls are specular, a particle that touched the body leaves
at a wall (wall.recycle_scattered), the contact is resolved (the fastest particles penetrate
1/40 of a radius; omega dt = 0.5 elastic, 0.2 damped, the theory given the discrete contact's
restitution), the free-stream density n_inf is counted in a strip ahead of the body (a transit
earlier), and the drag is the block means of the kind's record over the window. The
tolerance is Z = 4 standard errors (the force blocks' batch means and the density's,
combined): the sample noise of the particles hitting the body, about 1.5 % of C_D at the
default size (40,000 particles, a 0.3 s window; 3 % at the CI test's 20,000 and 0.15 s);
--full (2,097,152 particles on the GPU, a 1 s window, stiffer contacts) makes it about 10
times smaller. The soft contact's own bias is below that noise at the default stiffness (a
particle penetrating 1/40 of a radius; at 1/10 the drag is about 4 % low, the effective
surface lying inside the offset one).

The span is periodic: a particle scattered by the sphere that crosses the span's end before it
reaches a wall or the outflow may meet the sphere's image; the span is 6 sphere radii, so few do,
and those meet it from the side (a span twice as wide gave the same drag within its noise).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .. import free_molecular as fm
from . import Check
from .wind_tunnel import Z, _backend, _particles, _positive_float, _restitution, discrete_restitution

SCENE = "wind-tunnel-sphere"
DEFAULT_PARTICLES = 40_000
FULL_PARTICLES = 2_097_152
RADIUS = 0.02        # m: the gas particles' (the sphere's is 0.05 m times SCALE)
SCALE = 2.0          # the shipped sphere (R = 0.05 m) at twice its size
LENGTH, HEIGHT, SPAN = 0.5, 0.4, 0.6  # (a small channel: more of the gas hits the sphere)
SPEED = 1.0
STIFFNESS, FULL_STIFFNESS = 40.0, 100.0
WDT_ELASTIC, WDT_DAMPED = 0.5, 0.2
T_START = 0.02
CENTRE_X = 0.05      # m: the sphere's centre (the channel is centred on the origin)

#: the report's runs (label, options, full only)
REPORT_RUNS = [("", [], False)]


def add_arguments(parser) -> None:
    parser.add_argument("--particles", type=_particles, default=None,
                        help=f"particles in the channel (default {DEFAULT_PARTICLES:,}; --full: {FULL_PARTICLES:,})")
    parser.add_argument("--backend", choices=("auto", "serial", "cpu", "cuda"), default="auto",
                        help="backend (default: cuda when usable, else cpu)")
    parser.add_argument("--full", action="store_true", help="the GPU size: 2,097,152 particles, a 1 s window")
    parser.add_argument("--time", type=_positive_float("--time"), default=None,
                        help="measurement window in simulated seconds (default 0.3; --full: 1)")
    parser.add_argument("--restitution", type=_restitution, default=1.0,
                        help="the sphere's restitution e (default 1: specular reflection)")
    parser.add_argument("--speed-ratio", type=_positive_float("--speed-ratio"), default=2.0,
                        help="speed ratio S = U / sqrt(2kT/m) of the Maxwellian stream (default 2; >= 1.5)")
    parser.add_argument("--seed", type=int, default=1, help="random seed")


def overrides(speed_ratio: float, restitution: float, particles: int, window: float, seed: int = 1,
              stiffness: float | None = None) -> tuple[dict[str, Any], dict[str, float]]:
    """The scene keys of the free-molecular run and its time-stepping numbers."""
    S = speed_ratio
    umax = SPEED * (1.0 + 2.5 / S)
    omega = (stiffness or STIFFNESS) * umax / RADIUS
    wdt = WDT_ELASTIC if restitution == 1.0 else WDT_DAMPED
    dt = wdt / omega
    end = T_START + window
    ov: dict[str, Any] = {
        "gas.particles": int(particles), "gas.radius": RADIUS, "gas.mass": 1.0, "contact.enabled": False,
        "wall.k": omega ** 2, "wall.restitution": 1.0, "wall.recycle_scattered": True,
        "wing.k": omega ** 2, "wing.restitution": float(restitution),
        "channel.length": LENGTH, "channel.height": HEIGHT, "channel.span": SPAN,
        "inflow.speed": SPEED, "inflow.thermal": 0.0, "inflow.speed_ratio": S,
        "timestep.integrator": "symplectic-euler", "timestep.dt_max": dt, "timestep.fraction": 10.0,
        "run.end_time": end, "run.seed": int(seed), "measure.start": T_START / end,
        "measure.block_time": window / 64.0,
    }
    return ov, {"dt": dt, "end": end, "wdt": wdt}


def measure(speed_ratio: float, restitution: float, particles: int, backend: str, window: float, seed: int = 1,
            stiffness: float | None = None) -> dict[str, Any]:
    """One collisionless run: the drag over q (m^2) with its standard error, and the body."""
    from ..scene import load_scene
    from ..simulation import Simulation

    ov, num = overrides(speed_ratio, restitution, particles, window, seed, stiffness)
    scene = load_scene(SCENE)
    entry = {k: v for k, v in scene.arrays["bodies"][0].items() if v != ""}  # (the scene's, its paths absolute)
    ov["bodies"] = [dict(entry, scale=SCALE, position=[CENTRE_X, 0.0, 0.0])]
    sim = Simulation.from_scene(scene, backend=backend, overrides=ov)
    sim.set_end_time(num["end"])
    ob = sim.info["body"]
    v = np.asarray(ob["vertices"], dtype=np.float64)
    lo, hi = np.asarray(sim.params["channel_lo"]), np.asarray(sim.params["channel_hi"])
    r = float(sim.params["radius"])
    strip_lo, strip_hi = float(lo[0]), float(v[:, 0].min()) - r - 0.02
    vol = (strip_hi - strip_lo) * (hi[1] - lo[1] - 2.0 * r) * (hi[2] - lo[2])
    chunk = max(1, int(round(min(0.005, window / 64.0) / num["dt"])))

    def strip_density():
        x = sim.field("position", copy=True)[:, 0]
        fresh = sim.field("scattered", copy=True) == 0
        return np.count_nonzero(fresh & (x > strip_lo) & (x < strip_hi)) / vol

    times, dens = [0.0], [strip_density()]
    while True:
        sim.step(chunk)
        s = sim.state()
        if s["bad"]:
            raise ValueError(f"the validation run went unstable at step {s['bad_step']} (reason {s['bad']})")
        times.append(float(s["time"]))
        dens.append(strip_density())
        if s["done"]:
            break
    sc = sim.scalars()
    nb = int(sc["nblocks"])
    if nb < 8:
        raise ValueError(f"--time {window:g}: only {nb} force blocks were closed; give a longer window")
    drag = np.asarray(sc["blocks_drag"], dtype=np.float64)[:nb]
    times, dens = np.asarray(times), np.asarray(dens, dtype=np.float64)
    t0, t1 = T_START, T_START + nb * float(sc["block_len"])
    tau = (CENTRE_X - 0.5 * (strip_lo + strip_hi)) / SPEED
    samples = np.interp(times[(times >= t0) & (times <= t1)] - tau, times, dens)
    n_inf = float(samples.mean())
    nbatch = min(16, len(samples) // 2)
    n_se = 0.0
    if nbatch >= 2:
        usable = len(samples) // nbatch * nbatch
        n_se = float(samples[:usable].reshape(nbatch, -1).mean(axis=1).std(ddof=1) / math.sqrt(nbatch))
    count = n_inf * vol
    renewals = 1.0 + max(0.0, min(t1 - tau, t1 - t0)) * SPEED / (strip_hi - strip_lo)
    n_se = max(n_se, n_inf / math.sqrt(max(count * renewals, 1.0)))
    q = 0.5 * n_inf * float(sim.params["mass"]) * SPEED ** 2
    da = drag / q  # drag area per block (m^2)
    mean = float(da.mean())
    se = math.hypot(float(da.std(ddof=1) / math.sqrt(nb)), mean * n_se / n_inf)
    return {"drag_area": mean, "drag_area_se": se, "vertices": v, "faces": np.asarray(ob["faces"]), "radius": r,
            "blocks": nb, "pushouts": int(sc["pushouts"]), "steps": int(sc["step"]), "n_inf_rel_se": n_se / n_inf,
            "restitution": discrete_restitution(restitution, num["wdt"])}


def run(args) -> list[Check]:
    full = bool(getattr(args, "full", False))
    particles = getattr(args, "particles", None) or (FULL_PARTICLES if full else DEFAULT_PARTICLES)
    window = getattr(args, "time", None) or (1.0 if full else 0.3)
    stiffness = FULL_STIFFNESS if full else STIFFNESS
    e = float(getattr(args, "restitution", 1.0))
    S = float(getattr(args, "speed_ratio", 2.0))
    if S < 1.5:
        raise ValueError(f"--speed-ratio = {S:g}: at least 1.5 (the channel's stream lacks the particles moving "
                         f"upstream, a fraction erfc(S)/2 that is no longer negligible below that)")
    m = measure(S, e, particles, _backend(args), window, int(getattr(args, "seed", 1)), stiffness)
    r = m["radius"]
    R = float(np.linalg.norm(m["vertices"] - m["vertices"].mean(axis=0), axis=1).max())
    ref_area = math.pi * (R + r) ** 2  # the contact sphere's frontal area: C_D's reference
    poly = float(fm.convex_polyhedron(m["vertices"], m["faces"], r, S, m["restitution"])[0])
    smooth = fm.sphere(S, m["restitution"])
    detail = (f"sphere.stl x{SCALE:g} (R = {R:g} m, {len(m['faces'])} triangles) + particle radius {r:g} m; "
              f"S = {S:g}, e of the discrete contact {m['restitution']:.4f}; smooth sphere of R + r: C_D "
              f"{smooth:.4f}; n_inf se {100 * m['n_inf_rel_se']:.2f} %; {m['blocks']} blocks; pushouts {m['pushouts']}")
    cd, cd_se = m["drag_area"] / ref_area, m["drag_area_se"] / ref_area
    tol = Z * cd_se
    return [Check(name=f"sphere C_D (S={S:g}, e={e:g})", measured=cd, reference=poly / ref_area, tolerance=tol,
                  passed=bool(abs(cd - poly / ref_area) <= tol), unit="", detail=detail)]
