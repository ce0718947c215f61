"""The Magic 8-Ball's chip path (scenes/magic8ball/chip.h: a block per scene, the scene in
shared memory, K steps a launch) against the general path.

Tolerances come from float reordering, nothing else:

- Both paths visit the same neighbours of every particle (the chip path walks the cells of
  the last rebuild; the lists hold that walk's hits). On the CPU (the chip path's tiles
  emulated lane by lane, ``path="chip-emulated"``) with ``sph.list_build = cells`` they visit
  them in the same order too, so every per-particle sum is bit for bit the general path's;
  only the per-scene reductions (a step's sums over the particles) are added in another
  order. The maxima that choose dt are exact in any order, so one step from the same state
  gives the same fluid bit for bit, and sums of positive terms (kinetic energy, density
  sum) differ by at most 2 (n - 1) u of their value (Higham, Accuracy and Stability of
  Numerical Algorithms, 2nd ed., eq. 4.4: the error of a recursive sum of n positive terms
  in any order is at most (n - 1) u of it, u = 2^-24; two orders: twice that).
- Over many steps the dynamics amplify any rounding difference. The bound there is what
  another valid summation order of the general path itself gives: on the CPU the lists
  built by a scan of the scene (index order) instead of the cells (cell order) reorder
  every particle's density and force sums, a larger reordering than the chip path's (which
  reorders the reductions only); on the device the general path's lanes 8 against 32 reorder
  them (the chip path runs 8 lanes a particle, and its own reductions). The chip
  path must stay within twice that spread (two independent reorderings of the same size add
  at most linearly), plus the one-step bound as a floor.
- Over many seeds the answers (the faces shown) of both paths are draws of the same
  distribution: a chi-square test of homogeneity.

Device tests are ``gpu``-marked: the lead runs them on the GPU machine."""
import math

import numpy as np
import pytest

pytest.importorskip("corpuscle._core")

from corpuscle import _core
from corpuscle.batch import Batch

U = 2.0 ** -24  # float32 unit roundoff


def make(path, backend="cpu", n=3, particles=300, build="cells", **kw):
    kw.setdefault("settle", 0.0)
    kw.setdefault("randomize", False)
    return Batch.from_scene("magic8ball", n=n, backend=backend, particles=particles, path=path,
                            sph__list_build=build, **kw)


def by_id(b, name):
    """A field of every scene, in particle-id order within each scene."""
    ids = b.field("id", copy=True)
    v = np.asarray(b.field(name, copy=True))
    out = np.zeros_like(v)  # (a scene's unused slots: zero)
    n = b.slots
    for s in range(b.n_scenes):
        k = ids[s * n:s * n + b.n_active[s]] - s * n
        out[s * n + k] = v[s * n:s * n + b.n_active[s]]
    return out


def scal(b, name):
    return np.asarray(b.core.scalar_of_scenes(name), dtype=np.float64)


# --- CPU: the chip path's code on emulated tiles --------------------------------------

def test_chip_path_is_chosen_and_reported():
    assert make("general").path == "general"
    assert make("chip-emulated").path == "chip"
    assert make("auto").path == "general"  # the CPU backends step the general path
    with pytest.raises(ValueError, match="path = chip runs on the cuda backend"):
        make("chip")
    with pytest.raises(ValueError, match="path must be one of auto, general, chip"):
        make("fast")


def test_one_step_is_the_general_step_to_the_reductions_order():
    g, c = make("general"), make("chip-emulated")
    assert g.step(1) == c.step(1) == 1
    # every per-particle sum in the same order: the fluid bit for bit
    for name in ("position", "velocity", "density", "pressure"):
        assert np.array_equal(by_id(g, name), by_id(c, name)), name
    assert np.array_equal(scal(g, "dt"), scal(c, "dt"))
    # positive sums in another order: within 2 (n - 1) u of their value
    n = g.n_active.astype(np.float64)
    for name in ("sums_ke", "sums_rho_sum"):
        a, b = scal(g, name), scal(c, name)
        assert np.all(np.abs(a - b) <= 2 * (n - 1) * U * np.abs(a)), name
    assert np.array_equal(scal(g, "sums_vmax2"), scal(c, "sums_vmax2"))
    assert np.array_equal(scal(g, "sums_contacts"), scal(c, "sums_contacts"))


def test_launches_of_any_length_take_the_same_steps():
    # K steps in one launch or one a launch: the same state bit for bit (a launch that
    # starts without a rebuild marks its cells from the last rebuild's positions)
    one, many = make("chip-emulated"), make("chip-emulated")
    for _ in range(40):
        one.step(1)
    assert many.step(40) == 40
    for name in ("position", "velocity", "density"):
        assert np.array_equal(by_id(one, name), by_id(many, name)), name
    for name in ("die_position", "die_orientation", "time", "rebuilds", "sums_ke"):
        assert np.array_equal(scal(one, name), scal(many, name)), name


def test_many_steps_stay_within_the_general_paths_own_reordering():
    g, c, other = make("general"), make("chip-emulated"), make("general", build="scan")
    for b in (g, c, other):
        assert b.step(60) == 60
    assert np.array_equal(scal(g, "step"), scal(c, "step"))
    for name in ("die_position", "die_velocity", "time"):
        spread = np.abs(scal(g, name) - scal(other, name))
        floor = 64 * U * (np.abs(scal(g, name)) + 1e-3)
        assert np.all(np.abs(scal(g, name) - scal(c, name)) <= 2 * spread + floor), name
    # the fluid's statistics: mean density and kinetic energy
    for name in ("sums_rho_sum", "sums_ke"):
        spread = np.abs(scal(g, name) - scal(other, name))
        floor = 2 * (g.n_active - 1) * U * np.abs(scal(g, name))
        assert np.all(np.abs(scal(g, name) - scal(c, name)) <= 2 * spread + floor), name


def test_scenes_of_different_sizes_and_parameters_on_chip():
    kw = dict(n=3, particles=np.array([300, 220, 260]), fluid__viscosity=np.array([8.0, 12.0, 16.0]),
              die__side=np.array([0.064, 0.05, 0.07]))
    g, c = make("general", **kw), make("chip-emulated", **kw)
    assert list(c.n_active) == [300, 220, 260]
    g.step(1), c.step(1)
    for name in ("position", "velocity", "density"):
        assert np.array_equal(by_id(g, name), by_id(c, name)), name
    g.step(30), c.step(30)
    assert np.array_equal(scal(g, "step"), scal(c, "step"))
    assert np.allclose(scal(g, "die_position"), scal(c, "die_position"), atol=1e-4)


def test_a_scene_on_chip_is_its_own_batch_of_one():
    # scenes never interact: each scene of a chip batch is bitwise the same scene alone
    # (placed each as its own run)
    together = make("chip-emulated", n=3, placement="each")
    together.step(40)
    for s in range(3):
        alone = Batch.from_scene("magic8ball", n=1, backend="cpu", particles=300, path="chip-emulated",
                                 sph__list_build="cells", settle=0.0, randomize=False, placement="each", seed=together.scene_params["run.seed"][s])
        alone.step(40)
        n = 300
        for name in ("position", "velocity"):
            a = by_id(together, name)[s * n:(s + 1) * n]
            assert np.array_equal(a, by_id(alone, name)[:n]), (s, name)
        assert np.array_equal(scal(together, "die_position")[s], scal(alone, "die_position")[0])


def test_control_reaches_only_its_scene_on_chip():
    a, b = make("chip-emulated"), make("chip-emulated")
    act = np.zeros((3, 6))
    act[1, 0] = 30.0  # scene 1 shaken along x
    b.set_control(act)
    a.step(25), b.step(25)
    for s in (0, 2):
        assert np.array_equal(scal(a, "die_position")[s], scal(b, "die_position")[s])
    assert not np.array_equal(scal(a, "die_position")[1], scal(b, "die_position")[1])


def test_reset_on_chip_restores_the_chosen_scenes_exactly():
    b = make("chip-emulated", settle=0.02)
    start = {k: scal(b, k).copy() for k in ("die_position", "time", "step")}
    b.step(20)
    moved = scal(b, "die_position").copy()
    b.reset(np.array([True, False, True]))
    now = scal(b, "die_position")
    assert np.array_equal(now[[0, 2]], start["die_position"][[0, 2]])
    assert np.array_equal(now[1], moved[1])
    assert np.array_equal(scal(b, "time")[[0, 2]], [0.0, 0.0])
    # the restored scenes step as they did from the start
    fresh = make("chip-emulated", settle=0.02)
    b.step(15), fresh.step(15)
    for s in (0, 2):
        assert np.array_equal(scal(b, "die_position")[s], scal(fresh, "die_position")[s])


def test_advance_lands_every_scene_on_its_end_time_on_chip():
    b = make("chip-emulated")
    b.advance(0.02)
    assert np.allclose(scal(b, "time"), 0.02, rtol=0, atol=1e-12)
    g = make("general")
    g.advance(0.02)
    assert np.array_equal(scal(g, "step"), scal(b, "step"))


# --- the device: the chip path against the general path -------------------------------

@pytest.fixture
def cuda():
    from corpuscle.simulation import cuda_status

    ok, why = cuda_status()
    if not ok:
        pytest.skip(f"no usable CUDA backend: {why}")


def cuda_pair(n, particles, **kw):
    return (make("general", backend="cuda", n=n, particles=particles, **kw),
            make("chip", backend="cuda", n=n, particles=particles, **kw))


@pytest.mark.gpu
def test_cuda_auto_takes_the_general_path_and_chip_runs_where_it_fits(cuda):
    # auto is general (the chip path measured slower: docs/magic8ball.md); chip when forced
    assert make("auto", backend="cuda", n=64, particles=1000).path == "general"
    assert make("chip", backend="cuda", n=64, particles=1000).path == "chip"
    assert make("auto", backend="cuda", n=1, particles=1000).path == "general"
    assert make("auto", backend="cuda", n=8, particles=20000).path == "general"  # does not fit a block
    with pytest.raises(ValueError, match="shared memory a block"):
        make("chip", backend="cuda", n=8, particles=20000)


@pytest.mark.gpu
def test_cuda_chip_against_general_within_the_general_paths_reordering(cuda):
    # the general path at 32 lanes a particle and at 8 (another order of every particle's
    # sums: the reordering spread); the chip path runs 8 lanes a particle
    g = make("general", backend="cuda", n=64, particles=1000, sph__lanes=32)
    c = make("chip", backend="cuda", n=64, particles=1000)
    other = make("general", backend="cuda", n=64, particles=1000, sph__lanes=8)
    for b in (g, c, other):
        assert b.step(1) == 1
    # one step: same neighbours, other orders; dt from maxima (a max of values that differ by rounding)
    n = g.n_active.astype(np.float64)
    for name in ("sums_ke", "sums_rho_sum"):
        spread = np.abs(scal(g, name) - scal(other, name))
        assert np.all(np.abs(scal(g, name) - scal(c, name)) <= 2 * spread + 2 * (n - 1) * U * np.abs(scal(g, name))), name
    rho_g, rho_c, rho_o = by_id(g, "density"), by_id(c, "density"), by_id(other, "density")
    spread = np.max(np.abs(rho_g - rho_o))
    # a density sum of k ~ 130 terms in two orders differs by at most 2 (k - 1) u of it
    assert np.max(np.abs(rho_g - rho_c)) <= 2 * spread + 2 * 200 * U * np.max(rho_g)
    for b in (g, c, other):
        b.step(99)
    for name in ("die_position", "die_velocity", "time"):
        spread = np.abs(scal(g, name) - scal(other, name))
        floor = 64 * U * (np.abs(scal(g, name)) + 1e-3)
        assert np.all(np.abs(scal(g, name) - scal(c, name)) <= 2 * spread + floor), name
    # density statistics over the batch: mean and spread of the mean densities
    md_g = scal(g, "sums_rho_sum") / n
    md_c = scal(c, "sums_rho_sum") / n
    md_o = scal(other, "sums_rho_sum") / n
    assert abs(md_g.mean() - md_c.mean()) <= 2 * abs(md_g.mean() - md_o.mean()) + 64 * U * md_g.mean()
    assert abs(md_g.std() - md_c.std()) <= 2 * abs(md_g.std() - md_o.std()) + 64 * U * md_g.mean()


@pytest.mark.gpu
def test_cuda_chip_answers_have_the_general_paths_distribution(cuda):
    # 512 scenes a path, shaken at random for 0.4 s from starts of their own (other seeds:
    # independent samples): the faces shown are draws of one distribution
    B = 512
    g = make("general", backend="cuda", n=B, particles=1000, randomize=True, settle=0.3)
    c = make("chip", backend="cuda", n=B, particles=1000, randomize=True, settle=0.3, seed=10_000)
    rng = np.random.default_rng(7)
    for _ in range(8):
        act = np.concatenate([rng.uniform(-20, 20, (B, 3)), rng.uniform(-2e-3, 2e-3, (B, 3))], axis=1)
        g.set_control(act), c.set_control(act)
        g.advance(0.05), c.advance(0.05)
    fg = np.bincount(np.asarray(g.observations("numpy")["answer_face"]), minlength=7)[1:]
    fc = np.bincount(np.asarray(c.observations("numpy")["answer_face"]), minlength=7)[1:]
    # chi-square test of homogeneity (5 degrees of freedom): statistic below its 0.999
    # quantile, 20.52 (a false alarm one run in a thousand)
    table = np.array([fg, fc], dtype=np.float64)
    expected = table.sum(axis=1, keepdims=True) * table.sum(axis=0, keepdims=True) / table.sum()
    keep = expected.sum(axis=0) > 0
    stat = float(np.sum((table[:, keep] - expected[:, keep]) ** 2 / expected[:, keep]))
    assert stat < 20.52, (fg, fc, stat)
    assert not np.any(scal(c, "bad"))


@pytest.mark.gpu
def test_cuda_chip_isolation_and_reset(cuda):
    a, b = make("chip", backend="cuda", n=8, particles=1000), make("chip", backend="cuda", n=8, particles=1000)
    act = np.zeros((8, 6))
    act[3, 1] = 30.0
    b.set_control(act)
    a.step(40), b.step(40)
    others = [s for s in range(8) if s != 3]
    # each scene is its own block: the others bit for bit
    assert np.array_equal(scal(a, "die_position")[others], scal(b, "die_position")[others])
    assert not np.array_equal(scal(a, "die_position")[3], scal(b, "die_position")[3])
    r = make("chip", backend="cuda", n=8, particles=1000, settle=0.02)
    start = scal(r, "die_position").copy()
    r.step(20)
    moved = scal(r, "die_position").copy()
    mask = np.zeros(8, dtype=bool)
    mask[[1, 5]] = True
    r.reset(mask)
    now = scal(r, "die_position")
    assert np.array_equal(now[mask], start[mask])
    assert np.array_equal(now[~mask], moved[~mask])


@pytest.mark.gpu
def test_cuda_chip_launch_length_changes_nothing(cuda):
    one, many = (make("chip", backend="cuda", n=16, particles=1000) for _ in range(2))
    for _ in range(40):
        one.step(1)
    many.step(40)
    for name in ("die_position", "die_orientation", "time", "rebuilds"):
        assert np.array_equal(scal(one, name), scal(many, name)), name
    assert np.array_equal(by_id(one, "position"), by_id(many, "position"))


def test_bench_path_errors_are_one_line(tmp_path):
    import subprocess
    import sys

    env = {"PYTHONPATH": str(__import__("pathlib").Path(_core.__file__).parent.parent)}
    r = subprocess.run([sys.executable, "-m", "corpuscle", "bench", "magic8ball", "--backend", "cpu", "--particles",
                        "300", "--batch", "2", "--path", "chip", "--no-progress"], capture_output=True, text=True,
                       env={**__import__("os").environ, **env})
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "--path chip runs on the cuda backend" in r.stderr
