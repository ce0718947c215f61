"""The scene as a batch dimension (engine level, the Magic 8-Ball): one state holding several
independent scenes evolves each exactly as it would alone on the CPU backends (bitwise),
scenes never interact even with particles at the same coordinates, and a control reaches
only its own scene. (The Python Batch API of the batch issue builds on this.)"""
import numpy as np
import pytest

pytest.importorskip("corpuscle._core")

from corpuscle import _core
from corpuscle.kinds import Target, registry
from corpuscle.scene import load_scene

KIND = registry()["magic8ball"]


def built(seed, n=300, backend="serial"):
    scene = load_scene("magic8ball", {"fluid.particles": n, "run.seed": seed})
    return KIND.build(scene, Target(backend, "lists"), None)


def single(b, backend="serial"):
    sim = _core.Simulation("magic8ball", backend, "lists", b.params, b.arrays)
    sim.evaluate()
    return sim


def batch(builds, backend="serial"):
    params = dict(builds[0].params)
    params["n_scenes"] = len(builds)
    params["die_initial_scenes"] = [b.params["die_initial"] for b in builds]
    arrays = {k: np.ascontiguousarray(np.concatenate([b.arrays[k] for b in builds])) for k in ("position", "velocity")}
    sim = _core.Simulation("magic8ball", backend, "lists", params, arrays)
    sim.evaluate()
    return sim


def by_id(sim, name, scene, n):
    # the batch's fluid of scene s sits in slots [s n, (s + 1) n); ids are global
    ids = sim.download("id")[scene * n:(scene + 1) * n]
    v = sim.download(name)[scene * n:(scene + 1) * n]
    out = np.empty_like(v)
    out[ids - scene * n] = v
    return out


@pytest.mark.parametrize("backend", ["serial", "cpu"])
def test_scenes_in_a_batch_evolve_exactly_as_alone(backend):
    builds = [built(1, backend=backend), built(2, backend=backend), built(3, backend=backend)]
    alone = [single(b, backend) for b in builds]
    together = batch(builds, backend)
    assert together.n_scenes == 3 and together.n_particles == 900
    for sim in (*alone, together):
        sim.set_end_time(1e9)
    for sim in alone:
        assert sim.step(40) == 40
    assert together.step(40) == 40
    for s, sim in enumerate(alone):
        n = 300
        for name in ("position", "velocity", "density"):
            assert np.array_equal(by_id(together, name, s, n), by_id(sim, name, 0, n)), (s, name)
        a, b = together.scalars(s), sim.scalars(0)
        for key in ("time", "step", "dt", "die_position", "die_orientation", "rebuilds", "sums_ke", "n_ghost"):
            assert a[key] == b[key], (s, key)


def test_scenes_do_not_interact_at_the_same_coordinates():
    # two scenes with the same particles at the same coordinates but different dies: each is
    # its own run (a batch that mixed them would give neither)
    b1, b2 = built(1), built(2)
    b2.arrays = {k: v.copy() for k, v in b1.arrays.items()}
    alone = [single(b1), single(b2)]
    together = batch([b1, b2])
    for sim in (*alone, together):
        sim.set_end_time(1e9)
        sim.step(25)
    for s in range(2):
        assert np.array_equal(by_id(together, "position", s, 300), by_id(alone[s], "position", 0, 300))
    assert not np.array_equal(by_id(together, "position", 0, 300), by_id(together, "position", 1, 300))


def test_a_control_reaches_only_its_scene():
    b = built(1)
    together = batch([b, b])
    together.set_end_time(1e9)
    together.set_control({"acceleration": [20.0, 0.0, 0.0], "torque": [0.0, 0.0, 0.0]}, 1)
    together.step(20)
    ref = single(b)
    ref.set_end_time(1e9)
    ref.step(20)
    assert np.array_equal(by_id(together, "position", 0, 300), by_id(ref, "position", 0, 300))
    assert not np.array_equal(by_id(together, "position", 1, 300), by_id(ref, "position", 0, 300))
    # shaken along +x, the fluid of scene 1 lags to -x relative to scene 0
    assert by_id(together, "position", 1, 300)[:, 0].mean() < by_id(together, "position", 0, 300)[:, 0].mean()


def test_scenes_stop_on_their_own_and_the_batch_when_all_have():
    b1, b2 = built(1), built(2)
    together = batch([b1, b2])
    together.set_end_time(0.01)
    taken = together.step(1000)
    assert 0 < taken < 1000
    for s in range(2):
        st = together.scalars(s)
        assert st["done"] == 1 and st["time"] == 0.01
    assert together.step(10) == 0
    with pytest.raises(ValueError, match="scene 2 out of range"):
        together.scalars(2)
    with pytest.raises(ValueError, match="not supported yet"):
        together.checkpoint()


def test_scalars_and_controls_of_every_scene_at_once():
    builds = [built(1), built(2), built(3)]
    together = batch(builds)
    together.set_end_time(1e9)
    acc = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, -5.0, 0.0]])
    together.set_control_of_scenes("acceleration", acc)
    together.step(15)
    pos = together.scalar_of_scenes("die_position")
    assert pos.shape == (3, 3) and pos.dtype == np.float32
    t = together.scalar_of_scenes("time")
    assert t.shape == (3,) and t.dtype == np.float64
    for s in range(3):
        assert pos[s].tolist() == together.scalars(s)["die_position"]
        assert t[s] == together.scalars(s)["time"]
    # each scene got its own row: the same as setting it scene by scene
    ref = batch(builds)
    ref.set_end_time(1e9)
    for s in range(3):
        ref.set_control({"acceleration": acc[s].tolist()}, s)
    ref.step(15)
    assert np.array_equal(ref.scalar_of_scenes("die_position"), pos)
    with pytest.raises(ValueError, match=r"acceleration must be a \(3, 3\) array"):
        together.set_control_of_scenes("acceleration", np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"acceleration\[1\] must be finite"):
        together.set_control_of_scenes("acceleration", np.array([[0, 0, 0], [np.nan, 0, 0], [0, 0, 0]], float))
