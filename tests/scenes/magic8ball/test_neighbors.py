"""The Magic 8-Ball's index plug-ins (--neighbors): lists (cells on rebuilds, lists with a
skin in between), grid (cells every step), compact (the cells in chunks through shared
memory) and allpairs (every pair) visit the same
neighbours within h, so they give the same densities, pressures and accelerations to float
rounding, and the same motion over a few steps; the CUDA backend agrees with the CPU for each."""
import numpy as np
import pytest

pytest.importorskip("corpuscle._core")

import corpuscle

INDEXES = ["lists", "grid", "compact", "allpairs"]


def make(neighbors, backend="cpu", n=600):
    return corpuscle.Simulation.from_scene("magic8ball", backend=backend, particles=n, neighbors=neighbors)


def by_id(sim, name):
    ids = sim.field("id", copy=True)
    v = sim.field(name, copy=True)
    out = np.empty_like(v)
    out[ids] = v
    return out


def test_every_index_is_registered_with_lists_first():
    from corpuscle import _core

    kinds = _core.kinds()
    assert kinds["magic8ball"] == INDEXES
    assert make(None).neighbors == "lists"
    with pytest.raises(ValueError, match=r"--neighbors must be one of lists, grid, compact, allpairs \(the indexes of magic8ball\), got 'octree'"):
        make("octree")


@pytest.mark.parametrize("neighbors", ["grid", "compact", "allpairs"])
def test_indexes_give_the_same_evaluation(neighbors):
    ref, sim = make("lists"), make(neighbors)
    for s in (ref, sim):
        s.evaluate()
    rho0 = ref.scene["fluid.rest_density"]
    rho = by_id(ref, "density")
    np.testing.assert_allclose(by_id(sim, "density"), rho, rtol=2e-6, atol=1e-6 * rho0)
    # Tait: dp = gamma B (rho/rho0)^(gamma-1) drho/rho0, with drho up to the density tolerance
    gamma, stiff = ref.scene["fluid.gamma"], ref.scene["fluid.stiffness"]
    p_tol = gamma * stiff * (rho / rho0) ** (gamma - 1) * 3e-6 * rho / rho0 + 1e-3
    assert np.all(np.abs(by_id(sim, "pressure") - by_id(ref, "pressure")) <= p_tol)
    a, b = by_id(sim, "acceleration"), by_id(ref, "acceleration")
    scale = np.abs(b).max()
    assert np.abs(a - b).max() < 1e-5 * scale
    # lists mirror the fluid within h (1 + skin) of the wall, the others within h
    assert 0 < sim.state()["n_ghost"] <= ref.state()["n_ghost"]


@pytest.mark.parametrize("neighbors", ["grid", "compact", "allpairs"])
def test_indexes_give_the_same_motion(neighbors):
    ref, sim = make("lists"), make(neighbors)
    ref.step(20)
    sim.step(20)
    assert sim.time == pytest.approx(ref.time, rel=1e-5)
    # float rounding in different summation orders grows a little over 20 steps
    assert np.abs(by_id(sim, "position") - by_id(ref, "position")).max() < 1e-6
    d1, d2 = sim.state()["die"], ref.state()["die"]
    assert np.abs(np.subtract(d1["position"], d2["position"])).max() < 1e-6


@pytest.mark.parametrize("backend", ["serial", "cpu"])
def test_compact_visits_what_grid_visits_in_the_same_order(backend):
    # the chunks walk the cells, tags and slots in the cell walk's order: on the CPU the same sums
    a, b = make("grid", backend, 500), make("compact", backend, 500)
    a.step(8)
    b.step(8)
    for name in ("position", "velocity", "density", "pressure"):
        assert np.array_equal(a.field(name, copy=True), b.field(name, copy=True)), name
    assert a.state()["die"] == b.state()["die"]


def test_a_batch_refuses_compact_naming_the_kind_and_the_index():
    with pytest.raises(ValueError, match=r"^magic8ball: the compact index runs one scene; a batch of scenes uses lists, grid or allpairs$"):
        corpuscle.Batch.from_scene("magic8ball", n=2, particles=300, neighbors="compact", backend="serial")


def test_the_serial_and_openmp_backends_agree_bitwise_for_every_index():
    for neighbors in INDEXES:
        a, b = make(neighbors, "serial", 400), make(neighbors, "cpu", 400)
        a.step(5)
        b.step(5)
        assert np.array_equal(a.field("position", copy=True), b.field("position", copy=True)), neighbors


@pytest.mark.gpu
@pytest.mark.parametrize("neighbors", INDEXES)
def test_cuda_matches_the_cpu_for_every_index(neighbors):
    if not corpuscle.Simulation.cuda_available():
        pytest.skip("no usable CUDA device")
    cpu, gpu = make(neighbors, "cpu", 3500), make(neighbors, "cuda", 3500)
    rho0 = cpu.scene["fluid.rest_density"]
    np.testing.assert_allclose(by_id(gpu, "density"), by_id(cpu, "density"), rtol=1e-5, atol=1e-5 * rho0)
    a, b = by_id(gpu, "acceleration"), by_id(cpu, "acceleration")
    assert np.abs(a - b).max() < 1e-4 * np.abs(b).max()
    cpu.step(10)
    gpu.step(10)
    assert gpu.steps == cpu.steps == 10
    assert np.abs(by_id(gpu, "position") - by_id(cpu, "position")).max() < 1e-5
