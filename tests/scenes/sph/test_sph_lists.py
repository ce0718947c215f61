"""The SPH box's `lists` index (Verlet slot lists, spatial/neighbor_list.h): with skin 0 it
relists every step and is bit-identical to grid; with a skin it gives grid's pair sums to float
reordering; its lists are reused until a particle has moved skin h / 2 since the build, and the
relisting happens exactly then; a run reusing its lists matches a run relisting every step; an
overflowing list grows and the step is repeated; serial and OpenMP are bitwise equal; a
checkpoint resumes bitwise; CUDA matches the CPU (gpu)."""

from __future__ import annotations

import numpy as np
import pytest

from corpuscle import Simulation
from corpuscle.kinds import _sph_box

from test_sph_box import KINDS, fields, small


def stirred_by_id(sim, seed=1, speed=0.5, jitter=0.15):
    """test_sph_box.stirred with the perturbation applied in id order: the same state for
    indexes whose cells (and so sorted orders) differ."""
    rng = np.random.default_rng(seed)
    order = np.argsort(np.asarray(sim.core.download("id")))
    pos = np.asarray(sim.core.download("position"), dtype=np.float64)[order]
    rho = np.asarray(sim.core.download("density"), dtype=np.float32)[order]
    dp = sim.info["spacing"]
    pos = pos + rng.uniform(-jitter, jitter, pos.shape) * dp
    hi = np.asarray(sim.params["box_hi"])
    pos = np.clip(pos, 1e-4, hi - 1e-4)
    vel = rng.normal(0.0, speed, pos.shape)
    sim.set_particles(pos, vel)  # ids restart at 0..n-1 in this order
    rho = rho * (1.0 + rng.uniform(-0.01, 0.01, rho.shape)).astype(np.float32)
    sim.core.upload("density", rho.astype(np.float32))
    return sim


def by_id(sim, name):
    return np.asarray(sim.core.download(name))[np.argsort(np.asarray(sim.core.download("id")))]


def rebuilds(sim):
    return int(sim.core.scalars()["rebuilds"])


@pytest.mark.parametrize("kind", list(KINDS))
def test_skin_zero_is_grid_bit_for_bit(kind):
    out = {}
    for idx in ("grid", "lists"):
        sim = stirred_by_id(small(kind, neighbors=idx, sph__skin=0.0))
        sim.evaluate()
        out[idx] = fields(sim)
    for name in ("id", "acceleration", "density_rate", "pressure"):
        assert np.array_equal(out["grid"][name], out["lists"][name]), name
    sims = [stirred_by_id(small(kind, neighbors=idx, sph__skin=0.0)) for idx in ("grid", "lists")]
    for s in sims:
        s.step(15)
    for name in ("position", "velocity", "density", "wall_density"):
        assert np.array_equal(sims[0].core.download(name), sims[1].core.download(name)), name
    assert rebuilds(sims[1]) == 15  # skin 0: every step relists


@pytest.mark.parametrize("kind", list(KINDS))
def test_lists_give_grids_and_allpairs_pair_sums(kind):
    g = stirred_by_id(small(kind, neighbors="grid"))
    ap = stirred_by_id(small(kind, neighbors="allpairs"))
    lst = stirred_by_id(small(kind, neighbors="lists", sph__skin=0.15))
    for s in (g, ap, lst):
        s.evaluate()
    assert lst.state()["mean_neighbors"] == g.state()["mean_neighbors"]  # the same pairs within h
    for ref in (g, ap):
        for name in ("acceleration", "density_rate"):
            a, b = by_id(ref, name), by_id(lst, name)
            scale = np.abs(a).max()
            assert scale > 0
            np.testing.assert_allclose(b, a, rtol=0, atol=2e-5 * scale, err_msg=name)
    # the walls' densities feel the same fluid
    np.testing.assert_array_equal(by_id(g, "position"), by_id(lst, "position"))


def test_relists_exactly_when_a_particle_moved_half_the_skin():
    skin = 0.1
    sim = stirred_by_id(small("dam-break-2d", neighbors="lists", sph__skin=skin), speed=0.3)
    d = 0.5 * skin * sim.info["h"]
    x_build = by_id(sim, "position").astype(np.float64)  # the first step lists this state
    sim.step(1)
    assert rebuilds(sim) == 1
    seen_reuse = seen_rebuild = 0
    for _ in range(60):
        x = by_id(sim, "position").astype(np.float64)
        moved = np.sqrt(((x - x_build) ** 2).sum(1)).max()
        before = rebuilds(sim)
        sim.step(1)
        got = rebuilds(sim) - before
        if abs(moved - d) < 1e-4 * d:
            continue  # too close to call in float32
        assert got == (1 if moved > d else 0), (moved, d)
        if got:
            x_build = x
            seen_rebuild += 1
        else:
            seen_reuse += 1
    assert seen_rebuild >= 2 and seen_reuse >= 10, (seen_rebuild, seen_reuse)


@pytest.mark.parametrize("kind", ["dam-break-2d", "dam-break"])
def test_reused_lists_match_relisting_every_step(kind):
    steps = 40
    reuse = stirred_by_id(small(kind, neighbors="lists", sph__skin=0.2))
    every = stirred_by_id(small(kind, neighbors="lists", sph__skin=0.0))
    grid = stirred_by_id(small(kind, neighbors="grid"))
    for s in (reuse, every, grid):
        s.step(steps)
    assert 2 <= rebuilds(reuse) < steps // 2
    assert rebuilds(every) == steps
    dp = reuse.info["spacing"]
    for other in (every, grid):
        assert reuse.time == pytest.approx(other.time, rel=1e-5)
        np.testing.assert_allclose(by_id(reuse, "position"), by_id(other, "position"), rtol=0, atol=1e-4 * dp)
        np.testing.assert_allclose(by_id(reuse, "density"), by_id(other, "density"), rtol=1e-5)


def test_overflowing_lists_grow_and_repeat_the_step(monkeypatch):
    ref = stirred_by_id(small("dam-break", neighbors="lists"))
    ref.step(5)
    build = _sph_box.SphBox.build

    def tiny(self, scene, target, checkpoint=None):
        b = build(self, scene, target, checkpoint)
        b.params["max_neighbors"] = 4
        return b

    monkeypatch.setattr(_sph_box.SphBox, "build", tiny)
    sim = stirred_by_id(small("dam-break", neighbors="lists"))  # (its first evaluation grew them)
    assert sim.core.scalars()["list_capacity"] > 4
    assert sim.step(5) == 5
    assert sim.state()["bad"] == 0
    for name in ("position", "velocity", "density"):
        assert np.array_equal(by_id(sim, name), by_id(ref, name)), name
    assert sim.core.scalars()["list_capacity"] > 4


def test_serial_and_openmp_bitwise():
    a, b = (stirred_by_id(small("dam-break-2d", backend=be, neighbors="lists", sph__skin=0.2)) for be in ("serial", "cpu"))
    a.step(30)
    b.step(30)
    for name in ("position", "velocity", "density", "wall_density"):
        assert np.array_equal(a.core.download(name), b.core.download(name)), name
    assert rebuilds(a) == rebuilds(b) >= 2


def test_checkpoint_resumes_bitwise():
    a = stirred_by_id(small("dam-break-2d", neighbors="lists", sph__skin=0.2))
    a.step(7)
    ck = a.checkpoint()
    a.step(20)
    b = small("dam-break-2d", neighbors="lists", sph__skin=0.2)
    b.restore(ck)
    b.step(20)
    for name in ("position", "velocity", "density", "wall_density"):
        assert np.array_equal(a.core.download(name), b.core.download(name)), name
    assert a.time == b.time


def test_skin_is_checked():
    from cli_script import assert_one_line_error, corpuscle

    assert_one_line_error(corpuscle("run", "dam-break-2d", "--neighbors", "lists", "--set", "sph.skin=-0.1",
                                    "--backend", "serial"), "sph.skin")


# ---- CUDA against the CPU (the device machine) ------------------------------------------


def assert_matches_cpu(make, check=None, backends=("cpu", "cuda")):
    """The second backend (CUDA) against the first (the CPU): the pair sums of one stirred state,
    then 50 steps from the lattice start, reusing and rebuilding the lists (the same particles
    in the same places). make(backend, stirred) builds a simulation; check(first, second)
    checks the evaluated stirred pair further."""
    cpu, gpu = (stirred_by_id(make(b, True)) for b in backends)
    cpu.evaluate()
    gpu.evaluate()
    if check is not None:
        check(cpu, gpu)
    for name in ("acceleration", "density_rate"):
        a, b = by_id(cpu, name), by_id(gpu, name)
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-4 * np.abs(a).max(), err_msg=name)
    cpu, gpu = (make(b, False) for b in backends)
    cpu.step(50)
    gpu.step(50)
    assert gpu.time == pytest.approx(cpu.time, rel=1e-4)
    np.testing.assert_allclose(by_id(gpu, "position"), by_id(cpu, "position"), rtol=0, atol=1e-3 * cpu.info["spacing"])
    np.testing.assert_allclose(by_id(gpu, "density"), by_id(cpu, "density"), rtol=1e-4)
    assert rebuilds(gpu) >= 1


@pytest.mark.gpu
@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("skin", [0.0, 0.1])
def test_cuda_lists_match_cpu(kind, skin):
    if not Simulation.cuda_available():
        pytest.skip("no CUDA")

    def same_ids(cpu, gpu):
        assert np.array_equal(by_id(cpu, "id"), by_id(gpu, "id"))

    assert_matches_cpu(lambda b, _: small(kind, backend=b, neighbors="lists", particles=2000, sph__skin=skin), same_ids)


@pytest.mark.gpu
@pytest.mark.parametrize("kind", list(KINDS))
def test_cuda_skin_zero_is_cuda_grid_bit_for_bit(kind):
    """The CUDA build lists a slot's neighbours with several lanes a slot; at skin 0 and one
    lane in the pair pass its lists must hold grid's neighbours in grid's walk order: the same
    sums, bit for bit, as the CUDA grid index (same device, same fast math)."""
    if not Simulation.cuda_available():
        pytest.skip("no CUDA")
    out = {}
    for idx in ("grid", "lists"):
        sim = stirred_by_id(small(kind, backend="cuda", neighbors=idx, particles=3000, sph__skin=0.0, sph__lanes=1))
        sim.evaluate()
        out[idx] = fields(sim)
    for name in ("id", "acceleration", "density_rate", "pressure"):
        assert np.array_equal(out["grid"][name], out["lists"][name]), name
    sims = [stirred_by_id(small(kind, backend="cuda", neighbors=idx, particles=3000, sph__skin=0.0, sph__lanes=1))
            for idx in ("grid", "lists")]
    for s in sims:
        s.step(15)
    for name in ("position", "velocity", "density", "wall_density"):
        assert np.array_equal(sims[0].core.download(name), sims[1].core.download(name)), name


@pytest.mark.gpu
def test_cuda_lists_grow_on_overflow(monkeypatch):
    if not Simulation.cuda_available():
        pytest.skip("no CUDA")
    build = _sph_box.SphBox.build

    def tiny(self, scene, target, checkpoint=None):
        b = build(self, scene, target, checkpoint)
        b.params["max_neighbors"] = 4
        return b

    ref = small("fluid-box", backend="cuda", neighbors="lists", particles=4000)
    ref.step(40)
    monkeypatch.setattr(_sph_box.SphBox, "build", tiny)
    sim = small("fluid-box", backend="cuda", neighbors="lists", particles=4000)
    assert sim.step(40) == 40
    np.testing.assert_array_equal(by_id(sim, "position"), by_id(ref, "position"))


def _runtime_terms(mp, kind):
    """Build `kind` with fixed_terms = 0: the pair pass dispatches its terms per pair."""
    from corpuscle.kinds import get

    k = get(kind)
    build = k.build

    def runtime_build(*a, **kw):
        built = build(*a, **kw)
        built.params["fixed_terms"] = 0
        return built

    mp.setattr(k, "build", runtime_build)


def _fixed_and_runtime(kind, monkeypatch, backend, neighbors, **over):
    """The same stirred state with the pair terms fixed (the default) and dispatched per pair
    (fixed_terms = 0): each run's evaluated sums, then its state after 30 steps."""
    runs = {}
    for fixed in (1, 0):
        with monkeypatch.context() as mp:
            if not fixed:
                _runtime_terms(mp, kind)
            sim = stirred_by_id(small(kind, backend=backend, neighbors=neighbors, **over))
            assert sim.core.scalars()["fixed_terms"] == fixed
            sim.evaluate()
            out = [by_id(sim, n) for n in ("acceleration", "density_rate")]
            sim.step(30)
            runs[fixed] = out + [by_id(sim, n) for n in ("position", "velocity", "density")]
            spacing = sim.info["spacing"]
    assert np.abs(runs[1][1]).max() > 0  # (the diffusion and the pair terms did something)
    return zip(("acceleration", "density_rate", "position", "velocity", "density"), runs[1], runs[0]), spacing


@pytest.mark.parametrize("backend", ["serial", "cpu"])
@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("neighbors,lanes", [("lists", 1), ("lists", 4), ("grid", 0), ("compact", 0), ("allpairs", 0)])
def test_fixed_default_terms_are_the_runtime_terms_bit_for_bit(kind, neighbors, lanes, backend, monkeypatch):
    # the default model (Wendland C2, artificial viscosity, Fourtakas) runs every index's pair
    # pass with its terms fixed at compile time; with fixed_terms = 0 it dispatches them per
    # pair: the same functions, so on the CPU the same sums and the same run
    over = {"sph__lanes": lanes} if neighbors == "lists" else {}
    pairs, _ = _fixed_and_runtime(kind, monkeypatch, backend, neighbors, **over)
    for name, a, b in pairs:
        np.testing.assert_array_equal(a, b, err_msg=name)


@pytest.mark.gpu
@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("neighbors,lanes", [("lists", 1), ("lists", 4), ("grid", 0), ("compact", 0), ("allpairs", 0)])
def test_cuda_fixed_default_terms_are_the_runtime_terms(kind, neighbors, lanes, monkeypatch):
    # on CUDA the compiler contracts the fixed pass's multiplies and adds into FMAs where the
    # dispatch (a switch between them) keeps them apart: the same sums up to float32 rounding
    if not Simulation.cuda_available():
        pytest.skip("no CUDA")
    over = {"sph__lanes": lanes} if neighbors == "lists" else {}
    pairs, dp = _fixed_and_runtime(kind, monkeypatch, "cuda", neighbors, **over)
    for name, a, b in pairs:
        if name == "position":
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-4 * dp, err_msg=name)
        else:
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-5 * np.abs(b).max(), err_msg=name)


@pytest.mark.parametrize("neighbors", ["lists", "grid"])
def test_other_models_dispatch_their_terms(neighbors):
    assert small("dam-break-2d", neighbors=neighbors).core.scalars()["fixed_terms"] == 1
    for over in ({"sph__kernel": "cubic-spline"}, {"sph__viscosity": "laminar"}, {"sph__diffusion": "molteni"}):
        assert small("dam-break-2d", neighbors=neighbors, **over).core.scalars()["fixed_terms"] == 0, over
