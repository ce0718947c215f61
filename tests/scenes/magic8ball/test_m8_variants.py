"""The 8-ball's pair-pass variants. sph.lanes: the CUDA threads per particle of the density and
force passes (a warp, or groups of 16, 8 or 4 lanes of one). The key is checked, the width
chosen is reported, the CPU (one lane per particle whatever the key) gives bit for bit the same
results with every width, and (gpu-marked) CUDA agrees with the CPU with every width, for a
single scene and a batch, with every neighbour index. sph.list_build: the lists rebuilt from
the cells or by a scan of the whole scene list the same neighbours (the same physics to float
rounding), auto picks the scan for small scenes, and CUDA agrees with the CPU for both. A batch
sorts 32-bit keys (segment above the cell key) where they fit, bit for bit as the 64-bit ones."""
import numpy as np
import pytest

pytest.importorskip("corpuscle._core")

from corpuscle import Batch, Simulation
from corpuscle.scene import SceneError

WIDTHS = (32, 16, 8, 4)
cuda = pytest.mark.skipif(not Simulation.cuda_available(), reason="no usable CUDA device")


def single(lanes, backend="serial", particles=300, neighbors="lists", steps=0, **ovr):
    sim = Simulation.from_scene("magic8ball", backend=backend, particles=particles, seed=3, neighbors=neighbors,
                                overrides={"sph.lanes": lanes, "shake": [], **ovr})
    if steps:
        sim.step(steps)
    return sim


def by_id(sim, name):
    ids = sim.field("id", copy=True)
    v = sim.field(name, copy=True)
    out = np.empty_like(v)
    out[ids] = v
    return out


def batch(lanes, backend="serial", n=3, **kw):
    kw.setdefault("particles", 260)  # (a test may give per-scene counts)
    return Batch.from_scene("magic8ball", n=n, backend=backend, neighbors="lists", settle=0.0,
                            randomize=False, shake=[], overrides={"sph.lanes": lanes}, **kw)


@pytest.mark.parametrize("bad", [7, 64, 3, -1, "warp", "8", 8.5])
def test_a_bad_width_is_refused_naming_the_key(bad):
    with pytest.raises((SceneError, ValueError), match=r"sph\.lanes"):
        single(bad)


def test_the_core_checks_the_width():
    from corpuscle import _core

    sim = single(0)
    params = dict(sim.params)
    params["lanes"] = 12
    arrays = {"position": sim.field("position", copy=True), "velocity": sim.field("velocity", copy=True)}
    with pytest.raises(ValueError, match="lanes must be 4, 8, 16 or 32"):
        _core.Simulation("magic8ball", "serial", "lists", params, arrays)


def test_the_width_is_reported_and_0_gives_a_single_scene_a_warp():
    assert single(0).core.scalars()["lanes"] == 32
    for w in WIDTHS:
        assert single(w).core.scalars()["lanes"] == w
    assert batch(8).scalars(0)["lanes"] == 8


def test_the_cli_refuses_a_bad_width_in_one_line(tmp_path):
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "corpuscle", "run", "magic8ball", "--backend", "serial",
                        "--set", "sph.lanes=12", "--steps", "1", "--out", str(tmp_path / "x.cps")],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "sph.lanes" in r.stderr and "12" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_the_cpu_runs_one_lane_whatever_the_width():
    # bit for bit the same motion with every width (single scene, and a batch)
    ref = single(32, steps=12)
    for w in (16, 4):
        sim = single(w, steps=12)
        assert np.array_equal(by_id(sim, "position"), by_id(ref, "position"))
        assert np.array_equal(by_id(sim, "density"), by_id(ref, "density"))
    b32, b8 = batch(32), batch(8)
    b32.step(8)
    b8.step(8)
    assert np.array_equal(b32.field("position", copy=True), b8.field("position", copy=True))


@pytest.mark.gpu
@cuda
@pytest.mark.parametrize("lanes", WIDTHS)
@pytest.mark.parametrize("neighbors", ["lists", "grid", "allpairs"])
def test_cuda_single_scene_agrees_with_the_cpu_with_every_width(lanes, neighbors):
    # 20 steps from rest: positions to 1e-5 m, as tests/scenes/magic8ball/test_neighbor_reuse.py asks of CUDA
    c = single(lanes, "cpu", particles=1000, neighbors=neighbors, steps=20)
    g = single(lanes, "cuda", particles=1000, neighbors=neighbors, steps=20)
    assert g.core.scalars()["lanes"] == lanes
    np.testing.assert_allclose(by_id(g, "position"), by_id(c, "position"), atol=1e-5)
    np.testing.assert_allclose(by_id(g, "density"), by_id(c, "density"), rtol=1e-4)
    assert abs(g.state()["rebuilds"] - c.state()["rebuilds"]) <= 2


@pytest.mark.gpu
@cuda
@pytest.mark.parametrize("lanes", WIDTHS)
def test_cuda_batch_agrees_with_the_cpu_with_every_width(lanes):
    # as tests/scenes/magic8ball/test_batch_api.py::test_cuda_batch_agrees_with_the_cpu, with per-scene counts
    # (groups of one warp then straddle scenes and inactive slots)
    kw = dict(seed=[1, 2, 3, 4], particles=[260, 200, 260, 230], fluid__viscosity=[10.0, 20.0, 10.0, 15.0])
    c, g = batch(lanes, "cpu", n=4, **kw), batch(lanes, "cuda", n=4, **kw)
    acts = np.array([[2.0, 0, 0, 0, 0, 0.01]] * 4)
    for x in (c, g):
        x.set_control(acts)
        x.advance(0.05)
    oc, og = c.observations(), g.observations(like="numpy")
    for k in ("die_position", "die_velocity"):
        assert np.allclose(og[k], oc[k], atol=2e-3), k
    assert og["time"].tolist() == oc["time"].tolist()
    assert g.scalars(0)["lanes"] == lanes


def lists(build, backend="cpu", particles=600, steps=0):
    sim = Simulation.from_scene("magic8ball", backend=backend, particles=particles, seed=3,
                                overrides={"sph.list_build": build, "shake": []})
    if steps:
        sim.step(steps)
    return sim


def test_list_build_is_checked_and_auto_scans_small_scenes():
    with pytest.raises((SceneError, ValueError), match=r"sph\.list_build"):
        lists("octree")
    assert lists("cells").core.scalars()["list_scan"] == 0
    assert lists("scan").core.scalars()["list_scan"] == 1
    assert lists("auto", particles=400).core.scalars()["list_scan"] == 1
    assert lists("auto").core.scalars()["list_scan"] == 0  # 600 particles


def test_scan_and_cells_list_the_same_neighbours():
    # the same evaluation to float rounding (only the order of the sums differs), and the same
    # motion over 20 steps (with rebuilds in between, each relisting by its own method)
    cells, scan = lists("cells"), lists("scan")
    for sim in (cells, scan):
        sim.evaluate()
    rho = by_id(cells, "density")
    np.testing.assert_allclose(by_id(scan, "density"), rho, rtol=2e-6)
    a, b = by_id(scan, "acceleration"), by_id(cells, "acceleration")
    assert np.abs(a - b).max() < 1e-5 * np.abs(b).max()
    cells.step(20)
    scan.step(20)
    assert scan.state()["rebuilds"] >= 2
    np.testing.assert_allclose(by_id(scan, "position"), by_id(cells, "position"), atol=1e-5)


@pytest.mark.gpu
@cuda
@pytest.mark.parametrize("lanes", [32, 8])
@pytest.mark.parametrize("build", ["cells", "scan"])
def test_cuda_list_builds_agree_with_the_cpu(build, lanes):
    c = lists(build, "cpu", particles=1000, steps=20)
    g = Simulation.from_scene("magic8ball", backend="cuda", particles=1000, seed=3,
                              overrides={"sph.list_build": build, "sph.lanes": lanes, "shake": []})
    g.step(20)
    assert g.core.scalars()["list_scan"] == (build == "scan")
    np.testing.assert_allclose(by_id(g, "position"), by_id(c, "position"), atol=1e-5)
    assert abs(g.state()["rebuilds"] - c.state()["rebuilds"]) <= 2


def _key_width_runs(backend, particles, seeds, steps):
    """A batch stepped with 32-bit cell keys, then 64-bit ones (`wide_keys`), from one start:
    (positions, ids, each scene's rebuilds) of each."""
    from corpuscle import _core

    n = len(particles)
    b = Batch.from_scene("magic8ball", n=n, backend="serial", particles=particles, seed=seeds, neighbors="lists",
                         settle=0.0, randomize=False, shake=[], overrides={"sph.skin": 0.05})
    arrays = {"position": b.field("position", copy=True), "velocity": b.field("velocity", copy=True)}
    runs = []
    for wide in (0, 1):
        sim = _core.Simulation("magic8ball", backend, "lists", {**b.params, "wide_keys": wide}, arrays)
        sim.step(steps)
        runs.append((np.array(sim.download("position")), np.array(sim.download("id")),
                     [sim.scalars(s)["rebuilds"] for s in range(n)]))
    return runs


@pytest.mark.parametrize("backend", ["serial", "cuda"])
def test_a_batch_sorts_32_bit_keys_bit_for_bit_as_64_bit_ones(backend):
    if backend == "cuda" and not Simulation.cuda_available():
        pytest.skip("no usable CUDA device")
    # per-scene counts: inactive slots (keyed past every cell) at each segment's tail
    runs = _key_width_runs(backend, [260, 200, 260], [1, 2, 3], 25)
    assert runs[0][2][0] >= 3  # the scenes relisted (and sorted) several times
    assert np.array_equal(runs[0][0], runs[1][0]) and np.array_equal(runs[0][1], runs[1][1])
    assert runs[0][2] == runs[1][2]


# A batch with 32-bit keys sorts only the segments (a scene's fluid or ghosts) whose scene
# rebuilds, each by its cell keys (CUDA: a block a segment, sized to it); the 64-bit keys take
# the sort of every segment at once. The same order, so bit for bit the same run, for segments
# that take each of CUDA's block sizes (up to 1,024 slots: the test above; 2,048, 4,096, 8,192).
@pytest.mark.parametrize("backend", [
    "serial", pytest.param("cuda", marks=[pytest.mark.gpu, cuda])])
@pytest.mark.parametrize("particles", [[1500, 1200], [3000, 2900], [5000, 4600]])
def test_the_segment_sort_runs_bit_for_bit_as_the_sort_of_every_segment(backend, particles):
    runs = _key_width_runs(backend, particles, [4, 5], 6)
    assert min(runs[0][2]) >= 2  # sorted more than once
    assert np.array_equal(runs[0][0], runs[1][0]) and np.array_equal(runs[0][1], runs[1][1])
    assert runs[0][2] == runs[1][2]
