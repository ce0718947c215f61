"""``corpuscle validate hydrostatic``: a tank of water at rest behind the DBC walls.

A column of width W = 0.2 m and height H = 0.4 m fills the floor of a closed tank (2-D by
default, ``--dim 3``: W x W x H), released from the hydrostatic start and run to t = 1 s
(about five gravity-wave crossings sqrt(H / g) and 70 acoustic ones H / c0). Checks:

- pressure against depth: the mean pressure of each particle layer below the top two is
  within 5 % of rho0 g d, d the layer's depth below the free surface (the issue's figure; a
  weakly compressible model with c0 = 10 sqrt(2 g H) holds it to about 1 % once settled, a
  leaking or sticking wall puts it off by the weight it lost or carries);
- mass: the fluid mass inside the box equals the initial mass exactly (no particle leaves);
- volume sum_i m_i / rho_i within 1 % of M / rho0 (the compression of a 0.4 m column at this
  c0 is about 0.3 %);
- the free surface within one spacing of its start (no collapse, no explosion);
- the largest speed below 1 % of sqrt(2 g H) (the column is at rest).
"""

from __future__ import annotations

import math

import numpy as np

from . import Check, within
from ._common import add_engine, positive_int

WIDTH, HEIGHT = 0.2, 0.4
SETTLE = 1.0
#: the pressure profile needs layers of at least 3 particles below the top two: fewer
#: particles give none to compare (checked before the run)
MIN_PARTICLES = 32


def add_arguments(parser) -> None:
    add_engine(parser)
    parser.add_argument("--particles", metavar="N", help="fluid particles (default: 800 in 2-D, 2,000 in 3-D)")
    parser.add_argument("--dim", choices=("2", "3"), default="2", help="2-D or 3-D (default: 2)")
    parser.add_argument("--time", metavar="T", default=str(SETTLE), help=f"settling time in s (default: {SETTLE})")
    parser.add_argument("--full", action="store_true", help="four times the particles")
    parser.add_argument("--wall-layers", metavar="L", default="0",
                        help="wall (DBC) particle layers outside each face (walls.layers; 0, the default: as deep "
                             "as the kernel support; 1: DualSPHysics's one layer)")


def run(args) -> list[Check]:
    from ..scene import SceneError, load_scene
    from ..simulation import Simulation

    dim = int(args.dim)
    n = positive_int("--particles", args.particles) or (800 if dim == 2 else 2000)
    if n < MIN_PARTICLES:
        raise ValueError(f"--particles must be at least {MIN_PARTICLES} (the pressure profile needs layers of "
                         f"3 particles or more), got {n}")
    if args.full:
        n *= 4
    try:
        t_end = float(args.time)
    except ValueError:
        raise ValueError(f"--time must be a number, got {args.time!r}") from None
    if not (math.isfinite(t_end) and t_end > 0):
        raise ValueError(f"--time must be a positive number of seconds, got {args.time!r}")
    layers = getattr(args, "wall_layers", "0")
    try:
        layers = int(layers)
    except (TypeError, ValueError):
        raise ValueError(f"--wall-layers must be a whole number of layers, got {layers!r}") from None
    if not 0 <= layers <= 64:
        raise ValueError(f"--wall-layers must be 0 (the kernel support's) to 64, got {layers}")
    over = {"walls.layers": layers, "fluid.particles": n, "dam.a": WIDTH, "dam.height": HEIGHT / WIDTH, "dam.tank_length": 1.0,
            "dam.tank_height": 1.25 * HEIGHT / WIDTH, "probes": [], "run.end_time": t_end}
    if dim == 3:
        over["dam.depth"] = 1.0
    try:  # --time is run.end_time, bounded as `run --time` is
        scene = load_scene("dam-break-2d" if dim == 2 else "dam-break").with_overrides(over)
    except SceneError as exc:
        if str(exc).startswith("run.end_time "):
            raise SceneError(f"--time {args.time}: {exc}") from None
        raise
    sim = Simulation(scene, args.backend, neighbors=args.neighbors, device=args.device)
    info = sim.info
    dp, rho0, g, m = info["spacing"], info["rho0"], info["gravity"], info["mass"]
    n_fluid = int(info["n_fluid"])
    box = np.asarray(info["box"])
    rho_start = np.asarray(sim.core.download("density"), dtype=np.float64)
    surface0 = float(info["fluid_hi"][-1])
    sim.run(until=t_end)
    sim.check_health()
    sim.evaluate()  # pressures of the final state
    pos = np.asarray(sim.core.download("position"), dtype=np.float64)
    rho = np.asarray(sim.core.download("density"), dtype=np.float64)
    prs = np.asarray(sim.core.download("pressure"), dtype=np.float64)
    st = sim.state()
    inside = np.all((pos >= 0.0) & (pos <= box), axis=1)
    surface = float(pos[:, -1].max() + 0.5 * dp)
    # layers of one spacing from the free surface down; the top two are left out
    depth = surface - pos[:, -1]
    layer = np.floor(depth / dp).astype(int)
    rows = []
    for k in range(2, layer.max() + 1):
        sel = layer == k
        if sel.sum() < 3:
            continue
        d = float(depth[sel].mean())
        rows.append((d, float(prs[sel].mean()), rho0 * g * d))
    if not rows:
        raise ValueError(f"--particles {n}: no layer of 3 particles or more below the top two to measure; "
                         f"give more particles")
    rows_a = np.array(rows)
    rel = np.abs(rows_a[:, 1] - rows_a[:, 2]) / rows_a[:, 2]
    worst = int(np.argmax(rel))
    print(f"\nhydrostatic {dim}-D tank, {n_fluid} fluid particles (dp = {dp:.4g} m), {info['layers']} wall "
          f"layer(s), t = {t_end:g} s")
    print(f"  {'depth (m)':>10} {'p (Pa)':>10} {'rho g d':>10} {'rel':>8}")
    for (d, p, pr), r in zip(rows, rel):
        print(f"  {d:10.4f} {p:10.1f} {pr:10.1f} {r:8.4f}")
    checks = [
        within("pressure vs rho0 g d (worst layer below the top two)", float(rel[worst]), 0.0, 0.05, "",
               f"depth {rows_a[worst, 0]:.4g} m"),
        within("pressure at the bottom layer / rho0 g d", rows_a[-1, 1] / rows_a[-1, 2], 1.0, 0.05),
        Check("fluid mass inside the box", float(m * inside.sum()), float(m * n_fluid), 0.0,
              bool(inside.sum() == n_fluid), "kg"),
        within("volume sum m/rho over M/rho0", float((m / rho).sum() / (m * n_fluid / rho0)), 1.0, 0.01),
        within("free surface height", surface, surface0, dp, "m"),
        within("largest speed / sqrt(2 g H)", float(st["vmax"]) / math.sqrt(2 * g * surface0), 0.0, 0.01),
        Check("fluid outside the box (any step)", float(st["outside_max"]), 0.0, 0.0, st["outside_max"] == 0,
              "particles"),
    ]
    del rho_start
    return checks
