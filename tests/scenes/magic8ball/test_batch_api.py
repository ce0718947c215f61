"""corpuscle.Batch: B independent 8-balls in one state. A batch of B scenes evolves each
exactly as its single run (bitwise on the CPU backends, also with per-scene particle counts),
per-scene parameters change only their scene, reset(mask) restores exactly the chosen scenes
and leaves the others bitwise untouched, a randomised reset is a symmetry of the settled
state, observations match the scalars, actions are validated, and CUDA (gpu-marked) agrees
with the CPU and hands its observations out without copies."""
import math

import numpy as np
import pytest

pytest.importorskip("corpuscle._core")

import corpuscle
from corpuscle import Batch, Simulation
from corpuscle.batch import _qmul, _rotate, cube_rotations

N = 260  # particles a scene: small, so each test takes a second or two


def batch(n=3, backend="serial", **kw):
    kw.setdefault("particles", N)
    kw.setdefault("neighbors", "lists")
    kw.setdefault("settle", 0.0)
    kw.setdefault("randomize", False)
    kw.setdefault("shake", [])
    return Batch.from_scene("magic8ball", n=n, backend=backend, **kw)


def by_id(values, ids, count):
    # one scene's slots in particle-id order (ids of scene s are s*slots + 0..count-1)
    out = np.empty_like(values[:count])
    out[ids[:count] - ids[:count].min()] = values[:count]
    return out


def scene_fields(b, s, name):
    k = b.slots
    ids = b.field("id", copy=True)[s * k:(s + 1) * k]
    v = b.field(name, copy=True)[s * k:(s + 1) * k]
    return by_id(v, ids, int(b.n_active[s]))


def single_fields(sim, name):
    ids = sim.field("id", copy=True)
    return by_id(sim.field(name, copy=True), ids, sim.n_particles)


@pytest.mark.parametrize("backend,neighbors", [("serial", "lists"), ("cpu", "lists"), ("serial", "grid"),
                                               ("serial", "allpairs")])
def test_a_batch_equals_its_single_runs_bitwise(backend, neighbors):
    # per-scene seeds and particle counts: scene 1 uses 60 fewer slots than the batch holds
    counts, seeds = [N, N - 60, N], [4, 5, 6]
    b = batch(3, backend, particles=counts, seed=seeds, placement="each", neighbors=neighbors)
    assert b.slots == N and b.n_active.tolist() == counts and b.n_particles == sum(counts)
    singles = [Simulation.from_scene("magic8ball", backend=backend, particles=c, seed=s, shake=[], neighbors=neighbors,
                                     overrides={"sph.h": b.h, "sph.scale_h": False}) for c, s in zip(counts, seeds)]
    for sim in singles:
        sim.set_end_time(math.inf)
        assert sim.step(30) == 30
    assert b.step(30) == 30
    for s, sim in enumerate(singles):
        for name in ("position", "velocity", "density"):
            assert np.array_equal(scene_fields(b, s, name), single_fields(sim, name)), (s, name)
        got, want = b.scalars(s), sim.scalars()
        for key in ("time", "step", "dt", "die_position", "die_orientation", "die_velocity", "rebuilds", "sums_ke",
                    "sums_force", "n_ghost", "mean_density"):
            assert got[key] == want[key], (s, key)


def test_per_scene_parameters_change_only_their_scene():
    same = batch(3, placement="each", seed=[1, 2, 3])
    varied = batch(3, placement="each", seed=[1, 2, 3], fluid__viscosity=[10.0, 10.0, 40.0],
                   fluid__stiffness=[12000.0, 12000.0, 12000.0], die__side=[0.064, 0.064, 0.064])
    sided = batch(3, placement="each", seed=[1, 2, 3], die__side=[0.064, 0.05, 0.064], die__density=[1000, 1000, 1500])
    for x in (same, varied, sided):
        x.step(25)
    for s in (0, 1):
        assert np.array_equal(scene_fields(varied, s, "position"), scene_fields(same, s, "position"))
    assert not np.array_equal(scene_fields(varied, 2, "position"), scene_fields(same, 2, "position"))
    for s in (0, 2):
        assert np.array_equal(scene_fields(sided, s, "position"), scene_fields(same, s, "position")) == (s == 0)
    assert not np.array_equal(scene_fields(sided, 1, "position"), scene_fields(same, 1, "position"))
    # the stiffer sound speed sets the acoustic dt limit of its own scene only
    stiff = batch(2, placement="each", seed=[1, 2], fluid__stiffness=[12000.0, 48000.0], timestep__dt_max=1.0)
    stiff.step(3)
    dt = [stiff.scalars(s)["dt"] for s in range(2)]
    assert dt[1] < dt[0]
    # the record holds each scene's own die
    assert sided.params["scenes"][1]["die_half"] == [0.025] * 3
    assert sided.params["scenes"][2]["die_mass"] == pytest.approx(1500 * 0.064 ** 3)


def test_scenes_at_the_same_coordinates_do_not_interact():
    # placement "rotated" with one seed: every scene starts from the same particles (turned
    # by its seed's rotation); seeds equal -> the same coordinates in both scenes
    b = batch(2, seed=[7, 7], fluid__viscosity=[10.0, 30.0])
    pos = b.field("position", copy=True)
    assert np.array_equal(pos[:N], pos[N:])
    alone = [batch(1, seed=[7], fluid__viscosity=[v]) for v in (10.0, 30.0)]
    for x in (b, *alone):
        x.step(20)
    for s in range(2):
        assert np.array_equal(scene_fields(b, s, "position"), scene_fields(alone[s], 0, "position"))
    assert not np.array_equal(scene_fields(b, 0, "position"), scene_fields(b, 1, "position"))


def test_reset_restores_exactly_the_chosen_scenes():
    b = batch(3, seed=[1, 2, 3])
    ref = batch(3, seed=[1, 2, 3])
    fresh = {k: v.copy() for k, v in b.observations().items()}
    fresh_pos = b.field("position", copy=True)
    b.step(20)
    ref.step(20)
    before = {k: v.copy() for k, v in b.observations().items()}
    before_pos = b.field("position", copy=True)
    assert before["time"][1] > 0
    assert b.reset(np.array([False, True, False])).tolist() == [1]
    after = b.observations()
    pos = b.field("position", copy=True)
    sl = slice(N, 2 * N)
    assert np.array_equal(pos[sl], fresh_pos[sl])
    for s in (0, 2):
        assert np.array_equal(pos[s * N:(s + 1) * N], before_pos[s * N:(s + 1) * N])
    for k in after:
        assert np.array_equal(after[k][1], fresh[k][1]), k
        assert np.array_equal(after[k][[0, 2]], before[k][[0, 2]]), k
    # the untouched scenes go on as if nothing happened; the restored one as a fresh start
    b.step(15)
    ref.step(15)
    restart = batch(3, seed=[1, 2, 3])
    restart.step(15)
    for s in (0, 2):
        assert np.array_equal(scene_fields(b, s, "position"), scene_fields(ref, s, "position"))
    assert np.array_equal(scene_fields(b, 1, "position"), scene_fields(restart, 1, "position"))
    assert b.scalars(1)["step"] == 15 and b.scalars(0)["step"] == 35
    # indices work as a mask too; bad masks are one-line errors
    assert b.reset([0, 2]).tolist() == [0, 2]
    for bad, msg in (([True, False], r"mask must be 3 booleans"), ([0, 0], "distinct"), ([3], r"in 0\.\.2"),
                     (np.zeros(3), "booleans or scene indices")):
        with pytest.raises(ValueError, match=msg):
            b.reset(bad)


def test_a_batch_of_one_resets_exactly_too():
    # a single scene takes the single-scene sort path: the restore keys it all the same
    b = batch(1, seed=[2])
    fresh = b.field("position", copy=True)
    b.step(10)
    first = b.field("position", copy=True)
    b.reset()
    assert np.array_equal(b.field("position", copy=True), fresh)
    b.step(10)
    assert np.array_equal(b.field("position", copy=True), first)


def test_a_randomised_reset_is_a_symmetry_of_the_cached_scene():
    b = batch(2, seed=[3, 4], randomize=False)
    cached = b.observations()
    q0 = cached["die_orientation"].astype(np.float64).copy()
    x0 = cached["die_position"].astype(np.float64).copy()
    pos0 = b.field("position", copy=True).astype(np.float64)
    faces = set()
    for _ in range(12):
        b.reset(randomize=True)
        o = b.observations()
        pos = b.field("position", copy=True).astype(np.float64)
        q = o["die_orientation"].astype(np.float64)
        for s in range(2):
            sl = slice(s * N, (s + 1) * N)
            # the fluid and the die turned together about the vertical (gravity) axis
            r0, r = np.linalg.norm(pos0[sl], axis=1), np.linalg.norm(pos[sl], axis=1)
            assert np.allclose(r, r0, atol=1e-6)
            assert np.allclose(pos[sl, 2], pos0[sl, 2], atol=1e-6)
            assert np.allclose(o["die_position"][s, 2], x0[s, 2], atol=1e-6)
            # the particles in the die's body frame are those of the cached scene, up to a
            # rotation of the cube onto itself
            body0 = _rotate(q0[s] * [1, -1, -1, -1], pos0[sl] - x0[s])
            body = _rotate(q[s] * [1, -1, -1, -1], pos[sl] - o["die_position"][s].astype(np.float64))
            assert np.allclose(np.sort(np.abs(body).max(axis=1)), np.sort(np.abs(body0).max(axis=1)), atol=1e-5)
            assert o["time"][s] == 0.0
        faces.update(o["answer_face"].tolist())
    assert len(faces) >= 4  # the up face is drawn over the cube's rotations
    b.step(5)
    assert b.core.scalar_of_scenes("bad").tolist() == [0, 0]


def test_cube_rotations_are_the_cube_group():
    q = cube_rotations()
    assert q.shape == (24, 4) and np.allclose(np.linalg.norm(q, axis=1), 1.0)
    mats = np.stack([np.stack([_rotate(x, e) for e in np.eye(3)], axis=1) for x in q])
    assert np.allclose(np.abs(mats).sum(axis=1), 1.0)  # axes onto axes
    keys = {tuple(np.round(m, 6).ravel()) for m in mats}
    assert len(keys) == 24
    # closed under composition
    prod = _qmul(q[:, None, :], q[None, :, :]).reshape(-1, 4)
    pm = {tuple(np.round(np.stack([_rotate(x, e) for e in np.eye(3)], axis=1), 6).ravel()) for x in prod}
    assert pm == keys


def test_observations_match_the_scalars():
    b = batch(3, seed=[1, 2, 3], randomize=True)
    b.set_control(np.array([[0, 0, 0, 0, 0, 0], [4.0, 0, 0, 0, 0, 0.01], [0, -3.0, 0, 0.01, 0, 0]]))
    b.step(12)
    o = b.observations()
    assert set(o) >= {"die_position", "die_orientation", "die_velocity", "die_angular_velocity", "answer_face", "time"}
    assert isinstance(o["time"], np.ndarray) and o["time"].dtype == np.float64 and o["answer_face"].dtype == np.int32
    for s in range(3):
        sc = b.scalars(s)
        assert o["die_position"][s].tolist() == sc["die_position"]
        assert o["die_orientation"][s].tolist() == sc["die_orientation"]
        assert o["die_velocity"][s].tolist() == sc["die_velocity"]
        w = [sc["die_angular_velocity_x"], sc["die_angular_velocity_y"], sc["die_angular_velocity_z"]]
        assert o["die_angular_velocity"][s].tolist() == w
        assert o["answer_face"][s] == sc["answer_face"] and o["time"][s] == sc["time"]
    # the control reached each scene alone: the shaken ones moved differently
    assert o["time"][0] > 0


def test_advance_lands_every_scene_on_the_same_time():
    b = batch(2, seed=[1, 2], fluid__stiffness=[12000.0, 40000.0], timestep__dt_max=0.004)
    b.advance(0.02)
    b.advance(0.01)
    assert b.observations()["time"].tolist() == [0.03, 0.03]
    assert b.scalars(0)["step"] != b.scalars(1)["step"]  # each with its own dt
    with pytest.raises(ValueError, match="duration must be a positive number"):
        b.advance(-1)


def test_actions_are_validated_with_one_line_errors():
    b = batch(2)
    for bad, msg in ((np.zeros((3, 6)), r"actions must be a \(2, 6\) array, got shape \(3, 6\)"),
                     (np.zeros(6), r"got shape \(6,\)"),
                     (np.array([["a"] * 6] * 2), "must be numbers"),
                     (np.array([[0, 0, np.nan, 0, 0, 0], [0] * 6]), r"actions\[0, 2\] \(acceleration_z\) must be finite"),
                     (np.array([[0] * 6, [0, 0, 0, 0, np.inf, 0]]), r"actions\[1, 4\] \(torque_y\) must be finite")):
        with pytest.raises(ValueError, match=msg) as e:
            b.set_control(bad)
        assert "\n" not in str(e.value)
    b.set_control([[1, 2, 3, 0, 0, 0], [0, 0, 0, 0.1, 0.2, 0.3]])  # lists and ints are fine


def test_batch_arguments_are_checked():
    with pytest.raises(ValueError, match=r"fluid\.viscosity must be one value or one per scene \(2\)"):
        batch(2, fluid__viscosity=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"fluid\.gamma cannot vary per scene"):
        batch(2, fluid__gamma=np.array([7.0, 6.0]))
    with pytest.raises(ValueError, match="placement must be"):
        batch(2, placement="grid")
    with pytest.raises(ValueError, match="n must be"):
        batch(0)
    with pytest.raises(corpuscle.scene.SceneError, match="die.side"):
        batch(2, die__side=[0.064, 0.4])
    with pytest.raises(TypeError, match="from_scene"):
        Batch()


def test_settling_then_reset_starts_every_scene_settled():
    b = batch(2, seed=[1, 2], settle=0.05, particles=200)
    o = b.observations()
    assert o["time"].tolist() == [0.0, 0.0]
    s = b.scalars(0)
    assert s["step"] == 0 and s["rebuilds"] > 0  # the settling steps were taken, the clock restarted


# ---------------------------------------------------------------------------
# CUDA (run on the GPU machine)
# ---------------------------------------------------------------------------

cuda = pytest.mark.skipif(not Simulation.cuda_available(), reason="no usable CUDA device")


@pytest.mark.gpu
@cuda
def test_cuda_batch_agrees_with_the_cpu():
    kw = dict(seed=[1, 2, 3, 4], particles=[400, 300, 400, 350], fluid__viscosity=[10.0, 20.0, 10.0, 15.0])
    c, g = batch(4, "cpu", **kw), batch(4, "cuda", **kw)
    acts = np.array([[2.0, 0, 0, 0, 0, 0.01]] * 4)
    for x in (c, g):
        x.set_control(acts)
        x.advance(0.05)
    oc, og = c.observations(), g.observations(like="numpy")
    for k in ("die_position", "die_velocity"):
        assert np.allclose(og[k], oc[k], atol=2e-3), k
    assert og["time"].tolist() == oc["time"].tolist()
    for s in range(4):
        assert np.allclose(scene_fields(g, s, "position"), scene_fields(c, s, "position"), atol=2e-3)
    # reset on the device: the restored scene equals the fresh one
    fresh = batch(4, "cuda", **kw).observations(like="numpy")
    g.reset([2])
    o = g.observations(like="numpy")
    assert np.array_equal(o["die_position"][2], fresh["die_position"][2])


@pytest.mark.gpu
@cuda
def test_cuda_observations_are_zero_copy_through_dlpack():
    torch = pytest.importorskip("torch")
    g = batch(4, "cuda")
    o = g.observations(like="torch")
    assert o["die_position"].is_cuda and o["die_position"].shape == (4, 3)
    ptr = o["time"].data_ptr()
    g.advance(0.01)
    o2 = g.observations(like="torch")
    # the same device buffer, written in place: the first tensor sees the new values
    assert o2["time"].data_ptr() == ptr
    assert torch.equal(o["time"], o2["time"]) and float(o["time"][0]) == pytest.approx(0.01)
    cupy = pytest.importorskip("cupy")
    c = g.observations(like="cupy")
    assert c["time"].data.ptr == ptr


def test_the_core_checks_per_scene_parameters():
    from corpuscle import _core

    b = batch(2)
    params = dict(b.params)
    arrays = {"position": b.field("position", copy=True), "velocity": b.field("velocity", copy=True)}
    for scenes, msg in (([{"n_fluid": 0}, {}], r"scenes\[0\]\.n_fluid must be in 1\.\.260"),
                        ([{}, {"n_fluid": 261}], r"scenes\[1\]\.n_fluid must be in 1\.\.260"),
                        ([{}, {"viscosity": -1.0}], r"scenes\[1\]: mass, stiffness"),
                        ([{}], "scenes needs 2 tables")):
        with pytest.raises(ValueError, match=msg):
            _core.Simulation("magic8ball", "serial", "lists", {**params, "scenes": scenes}, arrays)
    one = {**params, "n_scenes": 1, "scenes": [{"n_fluid": 100}], "die_initial_scenes": params["die_initial_scenes"][:1]}
    with pytest.raises(ValueError, match="a single scene has n_fluid particles"):
        _core.Simulation("magic8ball", "serial", "lists", one, {k: v[:N] for k, v in arrays.items()})
    # the wind tunnel has no reset cache
    wt = Simulation.from_scene("wind-tunnel", backend="serial", particles=2000)
    with pytest.raises(ValueError, match="wind-tunnel: this kind has no reset cache"):
        wt.core.cache_scenes()
