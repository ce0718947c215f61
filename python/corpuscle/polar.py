"""A sweep over the angle of attack (`corpuscle polar SCENE --aoa START:STOP:STEP`, whose
command is corpuscle.cli.polar).

Each angle is one run of the scene (a wind-tunnel scene: every key of it, ``--set`` and
``--particles`` apply) to its end time; the steady-part means of C_L, C_D, C_M with their
standard errors (the kind's block means) go into a CSV, and a PNG shows C_L and C_D against
the angle with error bars, beside the free-molecular flat-plate theory for the scene's
airfoil restitution and free stream (corpuscle.free_molecular: the Newtonian
2 (1 + e) sin^2 alpha for the cold beam, the Maxwellian closed form at the scene's speed
ratio). The theory is the collisionless limit: with particle-particle contacts on (the
default scene) the measured points depart from it, which is what the polar shows.
"""

from __future__ import annotations

import math

import numpy as np

COLUMNS = ("angle_of_attack", "cl", "cl_se", "cd", "cd_se", "cm", "cm_se", "lift", "drag", "moment", "blocks",
           "steps", "particles", "theory_cl", "theory_cd")


def parse_aoa(text: str) -> list[float]:
    """START:STOP:STEP (STOP included when the steps reach it) or a comma-separated list."""
    t = (text or "").strip()
    try:
        if ":" in t:
            parts = [float(p) for p in t.split(":")]
            if len(parts) != 3:
                raise ValueError
            a, b, s = parts
            if not all(math.isfinite(x) for x in parts) or s == 0 or (b - a) / s < 0:
                raise ValueError
            n = int(math.floor((b - a) / s + 1e-9)) + 1
            if n > 1000:
                raise ValueError
            vals = [round(a + k * s, 10) for k in range(n)]
        else:
            vals = [float(p) for p in t.split(",") if p.strip()]
    except ValueError:
        raise ValueError(f"--aoa {text!r}: give START:STOP:STEP (e.g. -10:20:2) or a comma-separated list") from None
    if not vals or any(not (math.isfinite(v) and -90.0 <= v <= 90.0) for v in vals):
        raise ValueError(f"--aoa {text!r}: angles must be finite and within [-90, 90] degrees")
    return vals


def theory_curves(scene, angles) -> dict[str, np.ndarray]:
    """The thin flat plate's free-molecular C_L, C_D for the scene's wing restitution and stream."""
    from . import free_molecular as fm
    from .kinds import wind_tunnel as wt

    v = scene.values
    m = float(v["gas.mass"])
    k, c, e = float(v["wing.k"]), float(v["wing.c"]), float(v["wing.restitution"])
    if not e > 0:
        e = wt.restitution(k, c, m)
    ratio = wt.thermal_ratio(v)
    S = math.inf if ratio == 0 else 1.0 / ratio
    th = fm.thin_plate(np.asarray(angles, dtype=np.float64), S, e)
    return {"cl": th["cl"], "cd": th["cd"], "restitution": e, "speed_ratio": S}


def plot_polar(rows, th, scene, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = np.array([r["angle_of_attack"] for r in rows])
    fine = np.linspace(a.min(), a.max(), 200) if len(a) > 1 else a
    thf = theory_curves(scene, fine)
    S = th["speed_ratio"]
    label = (f"free-molecular flat plate (e = {th['restitution']:.2f}, "
             + ("cold beam" if not math.isfinite(S) else f"S = {S:g}") + ")")
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for ax, k, name in ((axes[0], "cl", "C_L"), (axes[1], "cd", "C_D")):
        y = np.array([r[k] for r in rows], dtype=np.float64)
        e = np.array([r[k + "_se"] for r in rows], dtype=np.float64)
        ax.errorbar(a, y, yerr=np.where(np.isfinite(e), e, 0.0), fmt="o", ms=4, capsize=2, label="measured")
        ax.plot(fine, thf[k], "-", lw=1.2, label=label)
        ax.set_xlabel("angle of attack (deg)")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"{scene.name}: {scene.values['airfoil.shape']}, {rows[0]['particles']:,} particles")
    fig.savefig(path, dpi=120)
    plt.close(fig)
