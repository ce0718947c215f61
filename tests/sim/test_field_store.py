"""Fields that own their storage (sim/field_store.h): the hidden `fields-test` kind declares
its fields in one table, and a field added there (`distance`: recorded, moving with the
particle, checkpointed, written by one line of physics) is found in frames, checkpoints and
Simulation.field; pack / unpack move one particle's record between slots."""

from __future__ import annotations

import numpy as np
import pytest

_core = pytest.importorskip("corpuscle._core")

from corpuscle import io, kinds  # noqa: E402
from corpuscle.scene import KeySpec, Scene, SceneKind  # noqa: E402
from corpuscle.simulation import Simulation  # noqa: E402

NAME = "fields-test"
BOX = 1.0


class FieldsTestKind(kinds.Kind):
    """The Python side of the core's test kind: n particles at random in a unit box."""

    name = NAME
    dim = 2
    particle_key = "gas.particles"
    frame_fields = ("position",)
    schema = SceneKind(name=NAME, description="free particles (a kind built for tests)", keys={
        "run.end_time": KeySpec("float", 1.0, "s", 0.0, 1e6, lo_open=True),
        "run.record_every": KeySpec("int", 10, "steps", 1, 10**9),
        "gas.particles": KeySpec("int", 2000, "", 1, 10**7),
        "gas.seed": KeySpec("int", 1, "", 0, 2**31),
    })

    def build(self, scene, target, checkpoint=None):
        n = int(scene["gas.particles"])
        rng = np.random.default_rng(int(scene["gas.seed"]))
        pos = rng.uniform(0.0, BOX, (n, 2)).astype(np.float32)
        vel = rng.normal(0.0, 1.0, (n, 2)).astype(np.float32)
        params = {"n": n, "lo": [0.0, 0.0], "hi": [BOX, BOX], "dt": 0.01, "cell": 0.05}
        return kinds.Build(params, {"position": pos, "velocity": vel})


@pytest.fixture(scope="module", autouse=True)
def registered():
    if NAME not in dict(_core.kinds(hidden=True)):
        pytest.skip("this core has no fields-test kind")
    from corpuscle import schema

    kinds.register(FieldsTestKind())
    yield
    # the other tests see the kinds a user has
    kinds._REGISTRY.pop(NAME, None)
    schema.KINDS.pop(NAME, None)


def make(backend="serial", n=2000):
    scene = Scene.from_dict({"scene": {"kind": NAME}, "gas": {"particles": n}}, name="t")
    return Simulation(scene, backend)


def test_hidden_from_the_kinds_list():
    assert NAME not in dict(_core.kinds())
    assert dict(_core.kinds(hidden=True))[NAME] == ["grid"]


def test_the_table_line_makes_a_stored_field():
    sim = make()
    info = {f["name"]: f for f in sim.field_info()}
    d = info["distance"]
    assert d["checkpointed"] and d["recorded"] and d["group"] == "fluid" and d["dtype"] == "<f4"
    assert not info["speed"]["checkpointed"] and not info["speed"]["recorded"]
    assert np.all(np.asarray(sim.field("distance", copy=True)) == 0.0)
    sim.step(20)
    dist = np.asarray(sim.field("distance", copy=True))
    speed = np.asarray(sim.field("speed", copy=True))
    ids = np.asarray(sim.field("id", copy=True))
    assert not np.array_equal(ids, np.arange(len(ids)))  # re-sorted by the cell grid
    # every particle's distance is its speed times the time (no acceleration: speed is kept
    # through reflections), so the distance moved with its particle through every re-sort
    np.testing.assert_allclose(dist, speed * sim.time, rtol=1e-4)


def test_found_in_frames_and_checkpoints(tmp_path):
    sim = make()
    sim.step(7)
    path = tmp_path / "run.cps"
    with io.FrameWriter(path, sim.header()) as w:
        w.write_frame(7, sim.time, 0.0, **sim.frame())
    with io.open(path) as run:
        f = run[0]
        assert set(f.fields) == {"id", "position", "distance"}  # the recorded ones
        np.testing.assert_array_equal(f["distance"], np.asarray(sim.field("distance", copy=True)))
    state = sim.checkpoint()
    np.testing.assert_array_equal(np.asarray(state["distance"]).reshape(-1), np.asarray(sim.field("distance", copy=True)))
    sim.step(5)
    after = np.asarray(sim.field("distance", copy=True)), np.asarray(sim.field("position", copy=True))
    back = Simulation(sim.scene, "serial", checkpoint=state)
    back.step(5)
    np.testing.assert_array_equal(np.asarray(back.field("distance", copy=True)), after[0])
    np.testing.assert_array_equal(np.asarray(back.field("position", copy=True)), after[1])


def test_pack_and_unpack_one_particle():
    sim = make(n=500)
    sim.step(3)
    core = sim.core
    # the checkpointed fluid fields in table order: position (2 f4), velocity (2 f4), id, distance
    assert core.packed_size() == 8 + 8 + 4 + 4
    before = {k: np.array(sim.field(k, copy=True)) for k in ("position", "velocity", "id", "distance")}
    rec = core.pack(17)
    assert len(rec) == core.packed_size()
    assert np.frombuffer(rec[:8], np.float32).tolist() == before["position"][17].tolist()
    assert np.frombuffer(rec[16:20], np.int32)[0] == before["id"][17]
    core.unpack(230, rec)
    for k, v in before.items():
        now = np.array(sim.field(k, copy=True))
        np.testing.assert_array_equal(now[230], v[17])
        np.testing.assert_array_equal(np.delete(now, 230, axis=0), np.delete(v, 230, axis=0))
    with pytest.raises(ValueError, match="out of range"):
        core.pack(500)
    with pytest.raises(ValueError, match="a record has 24 bytes"):
        core.unpack(0, rec[:10])


@pytest.mark.parametrize("kind", ["fluid-box", "wind-tunnel", "magic8ball"])
def test_pack_round_trips_every_kind(kind):
    sim = Simulation.from_scene(kind, "serial", particles=800)
    sim.step(2)
    core = sim.core
    fluid = [f for f in sim.field_info() if f["checkpointed"] and f["group"] == "fluid"]
    assert core.packed_size() == sum(int(f["components"]) * int(f["dtype"][2:]) for f in fluid)
    before = {f["name"]: np.array(sim.field(f["name"], copy=True)) for f in fluid}
    core.unpack(5, core.pack(40))
    for name, v in before.items():
        now = np.array(sim.field(name, copy=True))
        np.testing.assert_array_equal(now[5], v[40])
        np.testing.assert_array_equal(now[6:], v[6:])
