"""The transport-velocity formulation (Adami, Hu & Adams 2013; `sph.transport_velocity`) in the
SPH box: the pair stage against a float64 NumPy minimum-image reference on every CPU backend
and index (the extra stress in the momentum equation, the transport velocity in the continuity
equation, the background push as the step stores it), momentum conserved over a run, a
checkpoint resumed bit for bit, bad combinations one line with exit code 2, CUDA equal to the
CPU (gpu). The Taylor-Green validation (test_sph_canonical.py) checks the physics it is for."""

from __future__ import annotations

import json

import numpy as np
import pytest

from corpuscle import Simulation

from cli_script import assert_one_line_error, corpuscle
from test_sph_box import kernel_grad
from test_sph_canonical import INDEXES, CPU, box2, check_against_reference, reference, stir


def tvf_box(backend="serial", neighbors="grid", **over):
    """box2 with the transport velocity at its default background pressure (rho0 c0^2)."""
    over.setdefault("sph__transport_pressure", 0.0)
    return box2(backend, neighbors, sph__transport_velocity=True, **over)


def set_transport(sim, seed=7, scale=0.05):
    """Random v~ - v on the fluid (a checkpoint's field), float32."""
    rng = np.random.default_rng(seed)
    n = sim.info["n_fluid"]
    dvt = np.ascontiguousarray(rng.normal(0.0, scale, (n, sim.kind.dim)), dtype=np.float32)
    sim.core.upload("transport", dvt)
    return dvt.astype(np.float64)


def tvf_reference(sim, dvt):
    """float64, minimum image: what the formulation adds to dv/dt and drho/dt of the fluid, and
    the background push a~ = -(p_b / m) sum_j (V_i^2 + V_j^2) grad W (V = m / rho), the fluid
    only (a box with no walls)."""
    p = sim.params
    dim = sim.kind.dim
    x = np.asarray(sim.core.download("position"), dtype=np.float64)
    v = np.asarray(sim.core.download("velocity"), dtype=np.float64)
    rho = np.asarray(sim.core.download("density"), dtype=np.float64)
    m, h, p_b = p["mass"], p["h"], p["transport_pressure"]
    L = np.asarray(p["box_hi"], dtype=np.float64)
    n = len(x)
    vol = m / rho
    dacc, ddrho, push = np.zeros((n, dim)), np.zeros(n), np.zeros((n, dim))
    for i in range(n):
        d = x[i] - x
        d -= L * np.round(d / L)
        r2 = (d * d).sum(1)
        j = np.flatnonzero((r2 < h * h) & (np.arange(n) != i))
        _, g = kernel_grad("wendland", dim, h, d[j], np.sqrt(r2[j]))
        s = (vol[i] ** 2 + vol[j] ** 2) / m
        ai = rho[i] * v[i][None, :] * (g @ dvt[i])[:, None]
        aj = rho[j][:, None] * v[j] * (g * dvt[j]).sum(1)[:, None]
        dacc[i] = (0.5 * s[:, None] * (ai + aj)).sum(0)
        ddrho[i] = m * ((dvt[i] - dvt[j]) * g).sum()
        push[i] = -p_b * (s[:, None] * g).sum(0)
    return dacc, ddrho, push


@pytest.mark.parametrize("backend", CPU)
@pytest.mark.parametrize("neighbors", INDEXES)
def test_tvf_pair_stage_matches_reference(backend, neighbors):
    sim = stir(tvf_box(backend, neighbors))
    assert sim.params["transport_velocity"] == 1
    assert sim.params["transport_pressure"] == pytest.approx(sim.params["rho0"] * sim.params["c0"] ** 2)
    set_transport(sim)
    sim.evaluate()
    dvt = np.asarray(sim.core.download("transport"), dtype=np.float64)  # (in the evaluated state's order)
    base_acc, base_drho, _ = reference(sim)
    dacc, ddrho, push = tvf_reference(sim, dvt)
    got = np.asarray(sim.core.download("acceleration"), dtype=np.float64)
    want = base_acc + dacc
    np.testing.assert_allclose(got, want, rtol=0, atol=3e-5 * np.abs(want).max())
    # the extra stress is not negligible here (the test would not see it otherwise)
    assert np.abs(dacc).max() > 0.01 * np.abs(want).max()
    dr = np.asarray(sim.core.download("density_rate"), dtype=np.float64)
    wr = base_drho + ddrho
    assert np.abs(ddrho).max() > 0.01 * np.abs(wr).max()
    np.testing.assert_allclose(dr, wr, rtol=0, atol=3e-5 * np.abs(wr).max())
    # one step (an Euler step): x += dt (v + dt/2 (a + a~)), and the stored v~ - v is dt/2 a~
    x0 = np.asarray(sim.core.download("position"), dtype=np.float64)
    v0 = np.asarray(sim.core.download("velocity"), dtype=np.float64)
    ids0 = np.asarray(sim.core.download("id"))
    sim.step(1)
    dt = sim.state()["dt"]
    ids = np.asarray(sim.core.download("id"))
    order = np.argsort(ids0)[ids]  # the pre-step slot of each particle now
    dvt1 = np.asarray(sim.core.download("transport"), dtype=np.float64)
    np.testing.assert_allclose(dvt1, 0.5 * dt * push[order], rtol=0, atol=3e-5 * 0.5 * dt * np.abs(push).max())
    x1 = np.asarray(sim.core.download("position"), dtype=np.float64)
    step = x1 - x0[order]
    step -= np.round(step)  # (the unit box's minimum image)
    want_step = dt * (v0[order] + 0.5 * dt * (want[order] + push[order]))
    np.testing.assert_allclose(step, want_step, rtol=0, atol=1e-6)


def test_tvf_lanes_merge_the_push():
    # lists with 4 lanes a particle (their partial sums merged): the same sums as one lane, to
    # float reordering, the push (stored as v~ - v after a step) included
    sims = [stir(tvf_box("cpu", "lists", sph__lanes=g)) for g in (1, 4)]
    for s in sims:
        set_transport(s)
        s.step(1)
    for f in ("acceleration", "transport"):
        one, four = (np.asarray(s.core.download(f), dtype=np.float64) for s in sims)
        assert np.abs(one).max() > 0
        np.testing.assert_allclose(four, one, rtol=0, atol=1e-5 * np.abs(one).max())


def test_tvf_off_is_the_plain_model():
    # the switch off: the pair stage is the reference's without any of it (the default scene
    # values of test_sph_canonical)
    sim = stir(box2("cpu", "lists"))
    assert sim.params["transport_velocity"] == 0
    assert np.asarray(sim.core.download("transport")).size == 0
    check_against_reference(sim)


@pytest.mark.parametrize("neighbors", ("grid", "lists"))
def test_tvf_conserves_momentum_and_keeps_the_particles_in_the_box(neighbors):
    sim = tvf_box("cpu", neighbors, res=16, flow__initial="taylor-green")
    m = sim.info["mass"]
    n = sim.info["n_fluid"]
    p0 = m * np.asarray(sim.core.download("velocity"), dtype=np.float64).sum(0)
    sim.run(until=0.1)
    sim.check_health()
    v = np.asarray(sim.core.download("velocity"), dtype=np.float64)
    x = np.asarray(sim.core.download("position"), dtype=np.float64)
    np.testing.assert_allclose(m * v.sum(0), p0, rtol=0, atol=1e-5 * m * n)
    assert np.all((x >= 0.0) & (x < 1.0)) and sim.state()["outside_max"] == 0
    # the push acted: the particles left the advection of v alone
    assert np.abs(np.asarray(sim.core.download("transport"))).max() > 0


def test_tvf_checkpoint_resumes_bit_for_bit():
    a = tvf_box("cpu", "lists", res=16, flow__initial="taylor-green")
    a.step(20)
    c = a.checkpoint()
    assert np.abs(c["transport"]).max() > 0
    a.step(15)
    b = tvf_box("cpu", "lists", res=16, flow__initial="taylor-green")
    b.restore(c)
    b.step(15)
    for f in ("position", "velocity", "density", "transport"):
        np.testing.assert_array_equal(b.core.download(f), a.core.download(f))


@pytest.mark.parametrize("over,words", [
    ({"sph.transport_velocity": True, "sph.shifting": 2.0}, "sph.shifting"),
    ({"sph.transport_velocity": True, "fluid.background_pressure": 1e5}, "fluid.background_pressure"),
    ({"sph.transport_pressure": -1.0}, "sph.transport_pressure"),
])
def test_tvf_bad_input_one_line_exit_2(over, words):
    args = ["run", "taylor-green", "--backend", "serial"]
    for k, v in over.items():
        args += ["--set", f"{k}={json.dumps(v)}"]
    assert_one_line_error(corpuscle(*args, timeout=60), words)


@pytest.mark.gpu
@pytest.mark.parametrize("neighbors", INDEXES)
def test_cuda_matches_cpu_transport_velocity(neighbors):
    if not Simulation.cuda_available():
        pytest.skip("no CUDA")
    cpu, gpu = (stir(tvf_box(b, neighbors, res=40)) for b in ("cpu", "cuda"))
    for s in (cpu, gpu):
        set_transport(s)
        s.evaluate()
    for f in ("acceleration", "density_rate"):
        c, g = (np.asarray(s.core.download(f)) for s in (cpu, gpu))
        np.testing.assert_allclose(g, c, rtol=0, atol=1e-4 * np.abs(c).max())
    cpu, gpu = (tvf_box(b, neighbors, res=40, flow__initial="taylor-green") for b in ("cpu", "cuda"))
    cpu.step(100)
    gpu.step(100)
    oc, og = np.argsort(cpu.core.download("id")), np.argsort(gpu.core.download("id"))
    np.testing.assert_allclose(gpu.core.download("position")[og], cpu.core.download("position")[oc], rtol=0,
                               atol=1e-3 * cpu.info["spacing"])
    np.testing.assert_allclose(gpu.core.download("transport")[og], cpu.core.download("transport")[oc], rtol=0,
                               atol=1e-2 * np.abs(cpu.core.download("transport")).max())
