"""corpuscle.Simulation over a kind: what comes from the kind (state, setters, header,
result, frames), the generic parts (checkpoint layout, controls), and one core scalar
snapshot per state however many readers ask."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("corpuscle._core")

import corpuscle  # noqa: E402
from corpuscle import kinds  # noqa: E402
from corpuscle.kinds import magic8ball  # noqa: E402
from corpuscle.simulation import CoreHandle  # noqa: E402


class CountingCore:
    """Wraps the compiled simulation and counts its scalars() calls."""

    def __init__(self, raw):
        self.raw, self.calls = raw, 0

    def scalars(self):
        self.calls += 1
        return self.raw.scalars()

    def __getattr__(self, name):
        return getattr(self.raw, name)


@pytest.fixture(scope="module")
def made():
    return corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=300)


def counted(sim):
    counter = CountingCore(sim.core.raw)
    sim.core = CoreHandle(counter)
    return counter


def read_everything(sim):
    return (sim.time, sim.dt, sim.steps, sim.n_ghosts, sim.state(), sim.check_health(), sim.diagnostics(),
            sim.result(), sim.rigid_poses(), sim.frame(ghosts=True, velocity=True), sim.scalars())


def test_one_scalar_snapshot_per_state():
    sim = corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=300)
    c = counted(sim)
    read_everything(sim)
    assert c.calls == 1
    sim.step(3)
    assert c.calls == 1  # nothing read yet
    read_everything(sim)
    read_everything(sim)
    assert c.calls == 2 and sim.steps == 3
    # every call that changes the state drops the snapshot, and the next read sees the change
    before = sim.time
    sim.step(1)
    assert sim.time > before and c.calls == 3
    sim.set_die(position=(0.0, 0.01, 0.0))
    assert sim.state()["die"]["position"] == [0.0, np.float32(0.01), 0.0] and c.calls == 4
    sim.set_control(acceleration=(1.0, 0.0, 0.0))
    sim.time
    assert c.calls == 5
    sim.set_end_time(1.0)
    assert sim.state()["end_time"] == 1.0 and c.calls == 6
    sim.evaluate()  # evaluates, then reads the new state once
    sim.state()
    assert c.calls == 7
    pos = sim.field("position", copy=True)
    sim.set_particles(pos * 0.5)
    sim.time, sim.dt
    assert c.calls == 8
    state = sim.checkpoint()
    sim.step(2)
    sim.time
    sim.restore(state)
    assert sim.steps == state["step"] and c.calls == 10


def test_the_snapshot_cannot_be_changed_through_what_readers_get():
    sim = corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=300)
    st = sim.state()
    st["die"]["position"][0] = 99.0
    st["time"] = -1.0
    sim.scalars()["die_position"][1] = 99.0
    assert sim.state()["die"]["position"][0] != 99.0 and sim.scalars()["die_position"][1] != 99.0
    assert sim.time == 0.0


def test_kind_methods_and_values_are_attributes(made):
    assert made.kind is magic8ball.KIND
    assert "set_die" in dir(made) and "h" in dir(made) and "spacing" in dir(made)
    assert made.set_die.__doc__.startswith("Set the die's pose")
    assert made.h == made.info["h"] == made.params["h"] and made.mass == made.params["mass"]
    assert made.spacing > 0 and made.answers == list(magic8ball.DEFAULT_ANSWERS)
    with pytest.raises(AttributeError, match="Simulation of kind 'magic8ball' has no attribute 'set_wing'"):
        made.set_wing()


def test_header_describes_the_kind(made):
    h = made.header()
    assert h["kind"] == "magic8ball" and h["dim"] == 3 and h["scene"] == "magic8ball"
    assert h["container"] == {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": 0.15}
    assert h["obstacles"] == []
    (die,) = h["bodies"]
    assert die["name"] == "die" and die["shape"] == "box" and die["half_extents"] == [0.032] * 3
    assert die["faces"] == {str(k): list(v) for k, v in magic8ball.DIE_FACES.items()}
    assert die["answers"] == made.answers
    assert h["gravity"] == [0.0, 0.0, -9.81] and h["units"]["pressure"] == "Pa"
    assert h["particles"] == 300 and h["particle_radius"] == made.spacing / 2 and h["h"] == made.h
    assert h["parameters"] == made.scene.to_dict()
    # everything the frames' bodies are named by is described
    assert set(made.frame()["rigid"]) == {b["name"] for b in h["bodies"]}


def test_frame_fields_and_groups_come_from_the_core(made):
    f = made.frame(ghosts=True, velocity=True)
    assert list(f["fields"]) == ["id", "position", "density", "pressure", "velocity", "ghost_position"]
    assert f["groups"] == {"id": "fluid", "position": "fluid", "density": "fluid", "pressure": "fluid", "velocity": "fluid",
                           "ghost_position": "ghost"}
    assert set(f["diagnostics"]) <= set(made.header()["units"])


def test_checkpoint_layout_is_the_cores(made):
    assert made.checkpoint_fields == {"position": "fluid", "velocity": "fluid", "id": "fluid"}
    assert made.checkpoint_float64 == ("time", "spacing")
    c = made.checkpoint()
    assert c["spacing"] == made.spacing and isinstance(c["time"], float)
    core_names = {f["name"] for f in made.field_info() if f["checkpointed"]}
    assert core_names == set(made.checkpoint_fields)


def test_result_and_summary(made):
    res = made.result()
    lines, rest = made.kind.summary(res)
    assert lines == [f"8-ball says: {res['answer']} (face {res['answer_face']})"]
    assert set(rest) == {"die_position", "die_orientation"}


def test_particles_shorthand_is_the_kinds_particle_key():
    sim = corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=256, seed=3,
                                          overrides={"sph.skin": 0.1})
    assert sim.n_particles == 256 and sim.scene["run.seed"] == 3 and sim.scene["sph.skin"] == 0.1


def test_default_control_takes_the_cores_controls_by_name():
    stub = SimpleNamespace(core=SimpleNamespace(controls=lambda: {"inflow": 2, "spin": 1}))
    k = kinds.Kind()
    assert k.control(stub, inflow=(1, 2)) == {"inflow": [1.0, 2.0], "spin": [0.0]}
    assert k.control(stub, (1, 2), [3]) == {"inflow": [1.0, 2.0], "spin": [3.0]}
    with pytest.raises(TypeError, match="unknown control 'torque' \\(controls: inflow, spin\\)"):
        k.control(stub, torque=(1, 2, 3))
    with pytest.raises(ValueError, match="inflow must be 2 numbers, got shape \\(3,\\)"):
        k.control(stub, inflow=(1, 2, 3))
    with pytest.raises(TypeError, match="given twice"):
        k.control(stub, (1, 2), inflow=(1, 2))


def test_a_checkpoint_missing_a_field_is_named(made):
    state = made.checkpoint()
    with pytest.raises(ValueError, match="^checkpoint: missing velocity$"):
        corpuscle.Simulation(made.scene, backend="serial", checkpoint={k: v for k, v in state.items() if k != "velocity"})
    with pytest.raises(ValueError, match="^checkpoint: missing position$"):
        corpuscle.Simulation(made.scene, backend="serial", checkpoint={k: v for k, v in state.items() if k != "position"})
    # fields a frame holds besides the checkpointed ones (density, ghosts) are left out
    extra = dict(state, density=made.field("density", copy=True), ghost_position=np.zeros((7, 3), np.float32))
    again = corpuscle.Simulation(made.scene, backend="serial", checkpoint=extra)
    assert again.steps == made.steps and np.array_equal(again.field("position", copy=True),
                                                         made.field("position", copy=True))
