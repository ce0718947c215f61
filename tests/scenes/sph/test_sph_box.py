"""The SPH box kinds (fluid-box, dam-break, dam-break-2d; seed 002): the three neighbour
searches give the same pair sums (grid and compact bit for bit), the CPU matches a float64
NumPy reference of the whole pair stage (every kernel, both viscosities, both density
diffusions, the DBC walls), serial and OpenMP are bitwise equal, a checkpoint resumes
bitwise, the probes are the Shepard interpolation of the fields, the DBC walls hold a
hydrostatic column, and the validations pass at CI size."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from corpuscle import Simulation
from corpuscle import _core
from corpuscle.scene import load_scene

from cli_script import assert_one_line_error, corpuscle

KINDS = {"fluid-box": 3, "dam-break": 3, "dam-break-2d": 2}
INDEXES = ("grid", "compact", "allpairs")


def small(kind="dam-break-2d", backend="serial", neighbors="grid", particles=None, **over):
    ov = {k.replace("__", "."): v for k, v in over.items()}
    if particles is not None:
        ov["fluid.particles"] = particles
    elif kind == "dam-break-2d":
        ov["fluid.particles"] = 200
    elif kind == "dam-break":
        ov.setdefault("fluid.particles", 300)
    else:
        ov.setdefault("fluid.particles", 400)
    ov.setdefault("run.end_time", 10.0)
    return Simulation(load_scene(kind).with_overrides(ov), backend, neighbors=neighbors)


def stirred(sim, seed=1, speed=0.5, jitter=0.15):
    """Jittered positions and random velocities: every pair term is exercised."""
    rng = np.random.default_rng(seed)
    pos = np.asarray(sim.core.download("position"), dtype=np.float64)
    dp = sim.info["spacing"]
    pos = pos + rng.uniform(-jitter, jitter, pos.shape) * dp
    hi = np.asarray(sim.params["box_hi"])
    pos = np.clip(pos, 1e-4, hi - 1e-4)
    vel = rng.normal(0.0, speed, pos.shape)
    sim.set_particles(pos, vel)
    rho = np.asarray(sim.core.download("density"), dtype=np.float32)
    rho *= (1.0 + rng.uniform(-0.01, 0.01, rho.shape)).astype(np.float32)
    sim.core.upload("density", rho)
    return sim


def fields(sim):
    f = {name: np.asarray(sim.core.download(name)) for name in
         ("position", "velocity", "density", "acceleration", "density_rate", "pressure", "id",
          "wall_position", "wall_density")}
    return f


def test_registered_with_four_indexes():
    k = dict(_core.kinds())
    for name in KINDS:
        assert k[name] == ["lists"] + list(INDEXES)  # the first is the default


@pytest.mark.parametrize("kind", list(KINDS))
def test_indexes_agree(kind):
    out = {}
    for idx in INDEXES:
        sim = stirred(small(kind, neighbors=idx))
        sim.evaluate()
        out[idx] = fields(sim)
    g, c, a = out["grid"], out["compact"], out["allpairs"]
    # the same particles in the same (sorted) order
    assert np.array_equal(g["id"], c["id"]) and np.array_equal(g["id"], a["id"])
    # compact walks the grid's cells in the grid's order: bit for bit
    for name in ("acceleration", "density_rate"):
        assert np.array_equal(g[name], c[name]), name
    # all pairs sums the same terms in another order
    scale = np.abs(g["acceleration"]).max()
    assert scale > 1.0
    np.testing.assert_allclose(a["acceleration"], g["acceleration"], rtol=0, atol=2e-5 * scale)
    np.testing.assert_allclose(a["density_rate"], g["density_rate"], rtol=0,
                               atol=2e-5 * np.abs(g["density_rate"]).max())
    # and after a few steps grid and compact are still identical
    sims = [stirred(small(kind, neighbors=idx)) for idx in ("grid", "compact")]
    for s in sims:
        s.step(15)
    assert np.array_equal(sims[0].core.download("position"), sims[1].core.download("position"))


# ---- the float64 NumPy reference of the pair stage ----------------------------------------


def kernel_grad(name, dim, h, d, r):
    """(W for interpolation at r, grad_i W at d) of the model's kernel set, float64."""
    q = r / h
    if name == "wendland":
        c = (7.0 / math.pi if dim == 2 else 21.0 / (2 * math.pi)) / h ** dim
        w = np.where(q < 1, c * (1 - q) ** 4 * (1 + 4 * q), 0.0)
        g = np.where(q < 1, -20 * c / h ** 2 * (1 - q) ** 3, 0.0)[:, None] * d
    elif name == "cubic-spline":
        c = (40.0 / (7 * math.pi) if dim == 2 else 8.0 / math.pi) / h ** dim
        w = np.where(q < 0.5, c * (1 - 6 * q ** 2 + 6 * q ** 3), np.where(q < 1, 2 * c * (1 - q) ** 3, 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(q < 0.5, 18 * q - 12, np.where(q < 1, -6 * (1 - q) ** 2 / q, 0.0))
        g = (c / h ** 2 * f)[:, None] * d
    else:  # poly6 interpolation, spiky gradient
        c = 4.0 / (math.pi * h ** 8) if dim == 2 else 315.0 / (64 * math.pi * h ** 9)
        w = np.where(r < h, c * (h * h - r * r) ** 3, 0.0)
        gc = 30.0 / (math.pi * h ** 5) if dim == 2 else 45.0 / (math.pi * h ** 6)
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where((r < h) & (r > 0), -gc * (h - r) ** 2 / r, 0.0)
        g = f[:, None] * d
    return w, g


def reference_rates(sim, f):
    """dv/dt (fluid) and drho/dt (fluid, walls) in float64 from the fields."""
    v = sim.scene.values
    info, p = sim.info, sim.params
    dim = sim.kind.dim
    nf = len(f["position"])
    x = np.concatenate([f["position"], f["wall_position"]]).astype(np.float64)
    vel = np.concatenate([f["velocity"], np.zeros_like(f["wall_position"])]).astype(np.float64)
    rho = np.concatenate([f["density"], f["wall_density"]]).astype(np.float64)
    rho0, c0, gamma, m = p["rho0"], p["c0"], p["gamma"], p["mass"]
    B = c0 * c0 * rho0 / gamma
    prs = B * ((rho / rho0) ** gamma - 1)
    h, hs = p["h"], p["hs"]
    eta2 = 0.01 * hs * hs
    n = len(x)
    acc = np.zeros((nf, dim))
    drho = np.zeros(n)
    for i in range(n):
        d = x[i] - x
        r2 = (d * d).sum(1)
        sel = (r2 < h * h) & (np.arange(n) != i)
        if i >= nf:
            sel &= np.arange(n) < nf
        j = np.flatnonzero(sel)
        dj, r = d[j], np.sqrt(r2[j])
        _, gw = kernel_grad(v["sph.kernel"], dim, h, dj, r)
        dv = vel[i] - vel[j]
        drho[i] = m * (dv * gw).sum(1).sum()
        if i >= nf:
            continue
        fj = j < nf
        rd = -(dj * gw).sum(1)
        if p["diffusion"]:
            drh = rho[j] - rho[i]
            if p["diffusion"] == 2:
                kz = gamma * p["gravity"][-1] * -1 / c0 ** 2
                z = dj[:, -1]
                drh = drh - 0.5 * rho0 * ((1 + kz * z) ** (1 / gamma) - (1 - kz * z) ** (1 / gamma))
            drho[i] += (2 * p["delta"] * hs * c0 * drh * rd / (r ** 2 + eta2) * (m / rho[j]))[fj].sum()
        a = -(gw * (m * (prs[i] / rho[i] ** 2 + prs[j] / rho[j] ** 2))[:, None]).sum(0)
        vr = (dv * dj).sum(1)
        if p["viscosity"] == 0:
            mu = hs * vr / (r ** 2 + eta2)
            pi = np.where(vr < 0, (-p["alpha"] * c0 * mu + p["beta"] * mu * mu) / (0.5 * (rho[i] + rho[j])), 0.0)
            a += (-m * pi[:, None] * gw).sum(0)
        else:
            s = m * 4 * p["nu"] * (dj * gw).sum(1) / ((rho[i] + rho[j]) * (r ** 2 + eta2))
            a += (s[:, None] * dv).sum(0)
        acc[i] = a + np.asarray(p["gravity"])
    return acc, drho


@pytest.mark.parametrize("kind,kernel,viscosity,diffusion", [
    ("dam-break-2d", "wendland", "artificial", "fourtakas"),
    ("dam-break-2d", "cubic-spline", "laminar", "molteni"),
    ("dam-break-2d", "poly6-spiky", "artificial", "none"),
    ("dam-break", "wendland", "laminar", "fourtakas"),
])
def test_pair_stage_matches_float64_reference(kind, kernel, viscosity, diffusion):
    over = {"sph__kernel": kernel, "sph__viscosity": viscosity, "sph__diffusion": diffusion,
            "sph__nu": 1e-3, "sph__alpha": 0.2, "sph__beta": 0.1}
    sim = stirred(small(kind, particles=120 if kind == "dam-break" else 150, **over))
    sim.evaluate()
    f = fields(sim)
    acc, drho = reference_rates(sim, f)
    nf = len(f["position"])
    scale = np.abs(acc).max()
    np.testing.assert_allclose(f["acceleration"], acc, rtol=0, atol=3e-5 * scale)
    dr = np.concatenate([f["density_rate"], np.asarray(sim.core.download("wall_density"))[:0]])
    np.testing.assert_allclose(dr, drho[:nf], rtol=0, atol=3e-5 * np.abs(drho).max())
    assert np.abs(drho[nf:]).max() > 0  # the walls feel the fluid (DBC)


def test_serial_and_openmp_bitwise():
    for idx in INDEXES:
        a, b = (stirred(small("dam-break-2d", backend=be, neighbors=idx)) for be in ("serial", "cpu"))
        a.step(25)
        b.step(25)
        for name in ("position", "velocity", "density", "wall_density"):
            assert np.array_equal(a.core.download(name), b.core.download(name)), (idx, name)
        assert a.time == b.time


def test_checkpoint_resumes_bitwise():
    a = stirred(small("dam-break-2d"))
    a.step(10)
    ck = a.checkpoint()
    a.step(20)
    b = small("dam-break-2d")
    b.restore(ck)
    b.step(20)
    for name in ("position", "velocity", "density", "wall_density"):
        assert np.array_equal(a.core.download(name), b.core.download(name)), name
    assert a.time == b.time


def test_probes_are_the_shepard_interpolation():
    probes = [{"name": "mid", "position": [0.07, 0.1]}, {"name": "low", "position": [0.05, 0.012]},
              {"name": "air", "position": [0.6, 0.3]}]
    sim = stirred(small("dam-break-2d", particles=400, probes=probes))
    sim.step(3)
    sim.evaluate()
    f = fields(sim)
    p = sim.params
    st = sim.state()["probes"]
    for pr in probes:
        x = np.asarray(pr["position"])
        d = x - f["position"].astype(np.float64)
        r = np.sqrt((d * d).sum(1))
        w, _ = kernel_grad("wendland", 2, p["h"], d, r)
        wv = w * p["mass"] / f["density"]
        got = st[pr["name"]]
        if wv.sum() == 0:
            # nothing within the support: not measured (NaN, null in JSON), not a pressure of 0
            assert got["weight"] == 0 and np.isnan(got["pressure"]) and np.isnan(got["velocity"]).all()
            continue
        ref_p = (wv * f["pressure"]).sum() / wv.sum()
        ref_v = (wv[:, None] * f["velocity"]).sum(0) / wv.sum()
        assert got["weight"] == pytest.approx(wv.sum(), rel=1e-5)
        assert got["pressure"] == pytest.approx(ref_p, rel=1e-4, abs=1e-3 * float(np.abs(f["pressure"]).max()))
        np.testing.assert_allclose(got["velocity"], ref_v, rtol=1e-4, atol=1e-5)
    assert st["air"]["weight"] == 0
    # the probes are diagnostics (series in the frames) of every recorded step
    d = sim.diagnostics()
    assert {"probe_mid_p", "probe_mid_vx", "probe_mid_vy", "probe_low_p"} <= set(d)


def test_probe_names_checked():
    with pytest.raises(Exception, match="probes"):
        load_scene("dam-break-2d").with_overrides({"probes": [{"name": "a b", "position": [0.1, 0.1]}]})


def test_hydrostatic_column_holds():
    from corpuscle.validation import hydrostatic
    import argparse

    p = argparse.ArgumentParser()
    hydrostatic.add_arguments(p)
    checks = hydrostatic.run(p.parse_args(["--backend", "serial", "--particles", "450", "--time", "0.4"]))
    bad = [c for c in checks if not c.passed]
    assert not bad, bad


def test_validate_dam_break_ci_size(tmp_path):
    proc = corpuscle("validate", "dam-break", "--backend", "serial", "--plot", tmp_path / "front.png", timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "PASS"
    assert (tmp_path / "front.png").stat().st_size > 1000
    assert "front 2-D a/dp=20 T=2.96" in proc.stdout


def test_validate_json_is_the_checks_alone():
    # --json: stdout is the JSON of the checks and nothing else (the front table goes to stderr)
    proc = corpuscle("validate", "dam-break", "--backend", "cpu", "--plot", "none", "--json", timeout=300)
    assert proc.returncode == 0, proc.stderr
    checks = json.loads(proc.stdout)
    assert len(checks) == 14 and all(c["passed"] for c in checks)
    assert "surge front" in proc.stderr


def test_validate_runs_the_scenes_index_by_default_and_any_other_alike():
    # the default is the scenes' own index (lists); grid gives the same fronts to float rounding
    fronts = {}
    for idx in (None, "grid"):
        args = ["validate", "dam-break", "--backend", "cpu", "--plot", "none", "--json"]
        proc = corpuscle(*(args + (["--neighbors", idx] if idx else [])), timeout=300)
        assert proc.returncode == 0, proc.stderr
        fronts[idx] = [c["measured"] for c in json.loads(proc.stdout) if c["name"].startswith("front")]
    assert len(fronts[None]) == 13
    np.testing.assert_allclose(fronts[None], fronts["grid"], rtol=0, atol=0.02)
    helptext = corpuscle("validate", "hydrostatic", "--help").stdout
    assert "default: lists" in helptext


def test_validate_bad_input():
    assert_one_line_error(corpuscle("validate", "nonsense"), "nonsense")
    assert_one_line_error(corpuscle("validate", "hydrostatic", "--particles", "-5"), "--particles")
    assert_one_line_error(corpuscle("validate", "dam-break", "--bogus"), "--bogus")
    # a plot that cannot be written is refused before the runs, not after them
    assert_one_line_error(corpuscle("validate", "dam-break", "--plot", "/nonexistent-folder/front.png", timeout=30),
                          "/nonexistent-folder")


def test_run_cli_dam_break_2d(tmp_path):
    out = tmp_path / "run.cps"
    proc = corpuscle("run", "dam-break-2d", "--backend", "serial", "--particles", "200", "--time", "0.02",
                     "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert "surge front" in proc.stdout


@pytest.mark.slow
def test_validate_dam_break_study(tmp_path):
    proc = corpuscle("validate", "dam-break", "--study", "--json", "--plot", tmp_path / "f.png", timeout=3600)
    checks = {c["name"]: c for c in json.loads(proc.stdout)}
    # the 2-D study: three runs, monotone convergence, an order, the residual against each series after
    # the one delay, nothing outside the tank; the exit code says whether every check passed
    assert sum(n.startswith("fluid outside the tank 2-D") for n in checks) == 3
    assert {"convergence ratio 2-D (rms change finest / coarser)", "observed order 2-D"} <= set(checks)
    resid = [c for n, c in checks.items() if n.startswith("residual after the delay fit 2-D")]
    assert len(resid) == 3 and all(c["tolerance"] > 0 for c in resid)
    assert all(c["passed"] == (c["measured"] <= c["tolerance"]) for c in resid)
    assert proc.returncode == (0 if all(c["passed"] for c in checks.values()) else 1), proc.stderr
    assert (tmp_path / "f.png").stat().st_size > 10_000


@pytest.mark.slow
def test_validate_dam_break_3d_default():
    proc = corpuscle("validate", "dam-break", "--dim", "3", "--plot", "none", timeout=3600)
    assert proc.returncode == 0, proc.stdout


# ---- CUDA against the CPU (the device machine) ------------------------------------------


@pytest.mark.gpu
@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("idx", INDEXES)
def test_cuda_matches_cpu(kind, idx):
    if not Simulation.cuda_available():
        pytest.skip("no CUDA")
    cpu = stirred(small(kind, backend="cpu", neighbors=idx, particles=2000))
    gpu = stirred(small(kind, backend="cuda", neighbors=idx, particles=2000))
    cpu.evaluate()
    gpu.evaluate()
    fc, fg = fields(cpu), fields(gpu)
    assert np.array_equal(fc["id"], fg["id"])
    scale = np.abs(fc["acceleration"]).max()
    np.testing.assert_allclose(fg["acceleration"], fc["acceleration"], rtol=0, atol=1e-4 * scale)
    # 50 steps from the (smooth) lattice start: the same particles in the same places
    cpu, gpu = (small(kind, backend=b, neighbors=idx, particles=2000) for b in ("cpu", "cuda"))
    cpu.step(50)
    gpu.step(50)
    assert gpu.time == pytest.approx(cpu.time, rel=1e-4)
    order_c, order_g = np.argsort(cpu.core.download("id")), np.argsort(gpu.core.download("id"))
    np.testing.assert_allclose(gpu.core.download("position")[order_g], cpu.core.download("position")[order_c],
                               rtol=0, atol=1e-3 * cpu.info["spacing"])
    np.testing.assert_allclose(gpu.core.download("density")[order_g], cpu.core.download("density")[order_c],
                               rtol=1e-4)
