"""spatial/lbvh.h's traversal stack (``lbvh.stack``): its depth changes nothing in the walk
(the same contacts, forces and densities, bit for bit, as long as it is deep enough), and a
walk that needs more than it has raises the overflow flag: the step is not taken and the run
stops with a one-line error naming the key (exit 3 from the CLI), in the gather and in the
reflexive traversal. On CUDA the stack is in shared memory (tests/scenes/wind_tunnel/test_wind_tunnel_gpu.py)."""

from __future__ import annotations

import numpy as np
import pytest

from corpuscle import Simulation
from corpuscle.kinds import wind_tunnel as wt
from corpuscle.scene import load_scene
from corpuscle.simulation import UnstableRunError
from cli_script import corpuscle


def make(n=2500, stack=None, form="gather", backend="serial"):
    ov = {"inflow.speed": 1.0, "inflow.speed_ratio": 1.0, "gas.solid_fraction": 0.3, "contact.form": form}
    if stack is not None:
        ov["lbvh.stack"] = stack
    return Simulation.from_scene(load_scene("wind-tunnel"), backend=backend, particles=n, neighbors="lbvh",
                                 overrides=ov)


FIELDS = ("force", "pressure", "contacts", "number_density")


@pytest.mark.parametrize("form", ["gather", "reflexive"])
def test_the_stack_depth_changes_nothing_when_deep_enough(form):
    a, b = make(stack=wt.LBVH_MAX_STACK, form=form), make(stack=10, form=form)
    assert a.params["lbvh_stack"] == wt.LBVH_MAX_STACK and b.params["lbvh_stack"] == 10
    a.step(30)
    b.step(30)
    assert a.state()["bad"] == 0 and b.state()["bad"] == 0
    assert np.array_equal(a.field("position"), b.field("position"))
    if form == "gather":  # the reflexive sums run through atomics: their order is the threads'
        for name in FIELDS:
            assert np.array_equal(a.field(name), b.field(name)), name
    else:
        assert np.array_equal(a.field("contacts"), b.field("contacts"))


def test_the_default_depth_is_the_schemas():
    s = make(600)
    assert s.params["lbvh_stack"] == wt.LBVH_STACK == wt.WIND_TUNNEL_KEYS["lbvh.stack"].default


@pytest.mark.parametrize("form", ["gather", "reflexive"])
def test_an_overflowing_stack_stops_the_run_without_taking_the_step(form):
    s = make(stack=1, form=form)
    p0 = s.positions.copy()
    with pytest.raises(UnstableRunError, match=r"unstable at step 0: an LBVH traversal needed more stack than "
                                               r"lbvh\.stack entries .*raise lbvh\.stack, at most 128"):
        s.run(steps=5)
    st = s.state()
    assert st["bad"] == 2 and st["step"] == 0 and st["time"] == 0.0
    assert np.array_equal(np.sort(s.positions, axis=0), np.sort(p0, axis=0))  # nothing moved


def test_a_clustered_gas_needs_a_deeper_stack():
    """Particles piled within one Morton cell share codes: the tree below them is as deep as
    the pile, and every box there overlaps the query, so the walk needs about log2(pile)
    entries. A stack too shallow for it is reported, a deep one finds every pair."""
    s = make(1200, stack=3)
    rng = np.random.default_rng(5)
    p = s.positions.astype(np.float64).copy()
    p[:256] = p[0] + rng.uniform(-1e-6, 1e-6, (256, 2))  # 256 particles in one spot
    p = p.astype(np.float32)
    s.set_particles(p, np.zeros_like(p))
    s.evaluate()
    assert s.state()["bad"] == 2
    deep = make(1200, stack=16)
    deep.set_particles(p, np.zeros_like(p))
    deep.evaluate()
    assert deep.state()["bad"] == 0
    ref = Simulation.from_scene(load_scene("wind-tunnel"), backend="serial", particles=1200, neighbors="allpairs",
                                overrides={"inflow.speed": 1.0, "inflow.speed_ratio": 1.0, "gas.solid_fraction": 0.3})
    ref.set_particles(p, np.zeros_like(p))
    ref.evaluate()
    c = deep.field("contacts")[np.argsort(deep.field("id"))]
    assert np.array_equal(c, ref.field("contacts")[np.argsort(ref.field("id"))])
    assert c[:256].min() >= 250  # (pairs of coinciding centres have no normal and no contact)


def test_cli_reports_the_overflow_in_one_line(tmp_path):
    r = corpuscle("run", "wind-tunnel", "--backend", "serial", "--particles", "2000", "--neighbors", "lbvh",
                  "--set", "lbvh.stack=1", "--steps", "5", "--out", tmp_path / "o.cps", "--no-progress")
    assert r.returncode == 3, (r.stdout, r.stderr)
    err = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(err) == 1 and "lbvh.stack" in err[0] and "Traceback" not in r.stderr, r.stderr


@pytest.mark.parametrize("value", ["0", "129", "2.5"])
def test_cli_refuses_a_bad_depth(tmp_path, value):
    r = corpuscle("run", "wind-tunnel", "--backend", "serial", "--particles", "500", "--neighbors", "lbvh",
                  "--set", f"lbvh.stack={value}", "--steps", "1", "--out", tmp_path / "o.cps", "--no-progress")
    assert r.returncode == 2
    assert "lbvh.stack" in r.stderr and value in r.stderr and len(r.stderr.strip().splitlines()) == 1
