"""The wind tunnel on CUDA against the CPU (gpu-marked: skipped without a device). The
device's log/exp/erf/cos are the CUDA intrinsics, a few ulps from the host's, so positions
are compared by id to a tolerance far below a radius, over a few steps (before differences
of rounding can grow), and the contact counts where positions agree."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corpuscle import Simulation
from corpuscle.scene import load_scene
from corpuscle.validation import wind_tunnel as vwt

CUDA = Simulation.cuda_available()
pytestmark = [pytest.mark.gpu, pytest.mark.skipif(not CUDA, reason="no usable CUDA backend (build or device)")]


def _by_id(sim, name):  # host copies (a CUDA field view is device memory)
    return sim.field(name, copy=True)[np.argsort(sim.field("id", copy=True))]


@pytest.mark.parametrize("index", ["grid", "lbvh", "allpairs"])
def test_interacting_gas_cuda_matches_cpu(index):
    n = 20_000 if index == "grid" else 4000
    ov = {"inflow.speed": 1.0, "inflow.speed_ratio": 2.0}
    sims = {b: Simulation.from_scene(load_scene("wind-tunnel"), backend=b, particles=n, neighbors=index, overrides=ov)
            for b in ("cpu", "cuda")}
    for s in sims.values():
        s.step(20)
    pa, pb = _by_id(sims["cpu"], "position"), _by_id(sims["cuda"], "position")
    r = sims["cpu"].radius
    assert np.abs(pa - pb).max() < 1e-3 * r
    assert np.array_equal(_by_id(sims["cpu"], "contacts"), _by_id(sims["cuda"], "contacts"))
    for k in ("recycled", "pushouts", "step"):
        assert sims["cpu"].state()[k] == sims["cuda"].state()[k], k


def test_collisionless_validation_case_cuda_matches_cpu():
    ov, num = vwt.scene_overrides("flat-plate", 20.0, 2.0, 1.0, 20_000, 0.2, stiffness=10.0)
    sims = {b: Simulation.from_scene(load_scene("wind-tunnel"), backend=b, overrides=ov) for b in ("cpu", "cuda")}
    for s in sims.values():
        s.step(200)
    pa, pb = _by_id(sims["cpu"], "position"), _by_id(sims["cuda"], "position")
    close = np.all(np.abs(pa - pb) < 1e-4, axis=1)
    assert close.mean() > 0.99  # the re-entered particles' velocities agree to rounding
    sa, sb = sims["cpu"].scalars(), sims["cuda"].scalars()
    assert sa["recycled"] == pytest.approx(sb["recycled"], rel=0.01)
    fa, fb = np.asarray(sa["airfoil_force"]), np.asarray(sb["airfoil_force"])
    assert np.abs(fa - fb).max() <= 0.05 * np.abs(fa).max() + 1e-6


def test_validation_on_cuda_passes_at_ci_size():
    m = vwt.measure("flat-plate", 30.0, 2.0, 1.0, 100_000, "cuda", 0.3, seed=9)
    th = vwt.theory(m["polygon"], m["radius"], 30.0, 2.0, 1.0)
    assert abs(m["cn"] - th["cn"]) <= vwt.Z * m["cn_se"]
    assert abs(m["ca"] - th["ca"]) <= vwt.Z * m["ca_se"]


@pytest.mark.parametrize("index,form", [("grid", "reflexive"), ("lbvh", "reflexive"), ("lbvh", "reflexive-warp"),
                                        ("grid", "reflexive-warp")])
def test_reflexive_form_cuda_matches_cpu_gather(index, form):
    ov = {"inflow.speed": 1.0, "contact.form": form}
    a = Simulation.from_scene(load_scene("wind-tunnel"), backend="cpu", particles=20_000, neighbors="grid",
                              overrides={"inflow.speed": 1.0})
    b = Simulation.from_scene(load_scene("wind-tunnel"), backend="cuda", particles=20_000, neighbors=index, overrides=ov)
    ia = np.argsort(a.field("id"))
    b.set_particles(a.positions[ia], a.velocities[ia])
    a.evaluate()
    b.evaluate()
    assert np.array_equal(_by_id(a, "contacts"), _by_id(b, "contacts"))
    fa, fb = _by_id(a, "force").astype(np.float64), _by_id(b, "force").astype(np.float64)
    assert np.abs(fa - fb).max() <= 1e-5 * np.abs(fa).max()


def test_cold_beam_conveyor_on_cuda():
    # the inflow conveyor's claims (atomic min over ids) and slots on the device: no particle
    # enters on another, the entering stream is exactly the free stream, and as many re-enter
    # as on the CPU (the trajectories differ by rounding, the flux does not)
    ov = {"inflow.speed": 1.0}
    sims = {b: Simulation.from_scene(load_scene("wind-tunnel"), backend=b, particles=4000, overrides=ov)
            for b in ("cpu", "cuda")}
    assert sims["cuda"].params["conv_rows"] > 0
    for sim in sims.values():
        sim.step(2000)
    sim = sims["cuda"]
    lo = np.asarray(sim.params["channel_lo"])
    r = float(sim.params["radius"])
    x, v = sim.field("position", copy=True), sim.field("velocity", copy=True)
    near = x[:, 0] < lo[0] + 0.5
    p = x[near]
    d2 = ((p[:, None, :] - p[None, :, :]) ** 2).sum(-1)
    np.fill_diagonal(d2, np.inf)
    assert near.sum() > 100 and d2.min() >= (2 * r) ** 2
    assert np.all(v[near] == np.float32([1.0, 0.0]))
    rc, rg = sims["cpu"].scalars()["recycled"], sims["cuda"].scalars()["recycled"]
    assert rg > 1000 and abs(rg - rc) < 0.05 * rc
    assert len(np.unique(sim.field("id", copy=True))) == 4000


@pytest.mark.parametrize("stack", [10, 128])
@pytest.mark.parametrize("form", ["gather", "reflexive"])
def test_lbvh_shared_memory_stack_matches_cpu(stack, form):
    """The tree's walks keep their stacks in shared memory (128 entries: 64 KiB a block, above
    the 48 KiB a launch gets unasked): the same contacts and forces as the CPU's gather."""
    ov = {"inflow.speed": 1.0, "contact.form": form, "lbvh.stack": stack}
    a = Simulation.from_scene(load_scene("wind-tunnel"), backend="cpu", particles=20_000, neighbors="lbvh",
                              overrides={"inflow.speed": 1.0})
    b = Simulation.from_scene(load_scene("wind-tunnel"), backend="cuda", particles=20_000, neighbors="lbvh",
                              overrides=ov)
    a.step(30)
    ia = np.argsort(a.field("id"))
    b.set_particles(a.positions[ia], a.velocities[ia])
    a.evaluate()
    b.evaluate()
    assert b.state()["bad"] == 0
    assert np.array_equal(_by_id(a, "contacts"), _by_id(b, "contacts"))
    assert np.array_equal(_by_id(a, "number_density"), _by_id(b, "number_density"))
    fa, fb = _by_id(a, "force").astype(np.float64), _by_id(b, "force").astype(np.float64)
    assert np.abs(fa - fb).max() <= 1e-5 * np.abs(fa).max()


@pytest.mark.parametrize("form", ["gather", "reflexive"])
def test_lbvh_shared_stack_overflow_is_reported_on_cuda(form):
    from corpuscle.simulation import UnstableRunError

    s = Simulation.from_scene(load_scene("wind-tunnel"), backend="cuda", particles=20_000, neighbors="lbvh",
                              overrides={"inflow.speed": 1.0, "contact.form": form, "lbvh.stack": 1})
    with pytest.raises(UnstableRunError, match="lbvh.stack"):
        s.run(steps=5)
    assert s.state()["bad"] == 2 and s.state()["step"] == 0
