"""Particles keep their identity in frames: every kind records each particle's ``id`` (its
index in the initial arrays, reordered with it), so a particle can be followed across the
engine's re-sorts, on every backend, in frames, checkpoints and exports."""

import numpy as np
import pytest

from corpuscle import io
from corpuscle.simulation import Simulation


# kind -> (particles, frames, steps between frames, overrides)
KINDS = {
    "fluid-box": (2000, 6, 40, {}),
    "dam-break-2d": (1500, 6, 40, {}),
    "magic8ball": (3000, 6, 40, {}),
    "wind-tunnel": (4000, 6, 40, {}),
    "wind-tunnel-3d": (4000, 4, 30, {}),
}


def _sim(kind, backend):
    if backend == "cuda" and not Simulation.cuda_available():
        pytest.skip("no usable CUDA device")
    n, _, _, ovr = KINDS[kind]
    return Simulation.from_scene(kind, backend, overrides=ovr, particles=n)


def _record(sim, path, frames, every):
    with io.FrameWriter(path, sim.header()) as w:
        for k in range(frames):
            if k:
                assert sim.step(every) == every
            w.write_frame(k * every, sim.time, 0.0,
                          **sim.frame(velocity=True))


@pytest.mark.parametrize("kind", list(KINDS))
def test_ids_follow_particles_across_resorts(kind, backend, tmp_path):
    sim = _sim(kind, backend)
    _, frames, every, _ = KINDS[kind]
    path = tmp_path / "run.cps"
    _record(sim, path, frames, every)
    run = io.open(path)
    try:
        assert "id" in run.field_names
        n = len(run[0]["position"])
        assert n == sim.n_particles
        by_id, by_index, times, speed = [], [], [], []
        for f in run:
            ids = np.asarray(f["id"])
            assert ids.dtype == np.int32
            # a permutation of the initial indexes
            assert np.array_equal(np.sort(ids), np.arange(n))
            pos = np.asarray(f["position"], np.float64)
            x = np.empty_like(pos)
            x[ids] = pos
            by_id.append(x)
            by_index.append(pos)
            times.append(f.time)
            speed.append(float(np.max(np.linalg.norm(np.asarray(f["velocity"], np.float64), axis=1))))
        extent = np.ptp(np.concatenate(by_index), axis=0)
        moved_by_index = 0
        for k in range(1, len(by_id)):
            # no particle moves farther than the fastest one's speed (at either end, doubled
            # for the acceleration between) times the time between the frames
            reach = 2.0 * max(speed[k - 1], speed[k]) * (times[k] - times[k - 1])
            d_id = np.linalg.norm(by_id[k] - by_id[k - 1], axis=1)
            d_index = np.linalg.norm(by_index[k] - by_index[k - 1], axis=1)
            jumped = np.zeros(n, bool)
            if kind.startswith("wind-tunnel"):
                # a particle leaving at the outflow re-enters at the inflow: the same slot and id,
                # the tunnel's length upstream
                jumped = (by_id[k - 1][:, 0] - by_id[k][:, 0]) > 0.5 * extent[0]
                assert jumped.mean() < 0.2
            assert np.all(d_id[~jumped] <= reach + 1e-6), (kind, k, d_id[~jumped].max(), reach)
            moved_by_index += int(np.sum(d_index > reach + 1e-6))
        # the engine re-sorted its particles between frames: by index they jump
        assert moved_by_index > n // 20
    finally:
        run.close()


@pytest.mark.parametrize("kind", ["fluid-box", "magic8ball", "wind-tunnel"])
def test_ids_in_checkpoints_and_exports(kind, tmp_path):
    from corpuscle.export import export_run

    sim = _sim(kind, "serial")
    sim.step(30)
    ids = np.array(sim.field("id", copy=True))
    assert not np.array_equal(ids, np.arange(len(ids)))  # re-sorted
    state = sim.checkpoint()
    assert np.array_equal(np.asarray(state["id"]).reshape(-1), ids)
    back = Simulation(sim.scene, "serial", checkpoint=state)
    assert np.array_equal(np.array(back.field("id", copy=True)), ids)
    path = tmp_path / "run.cps"
    with io.FrameWriter(path, sim.header()) as w:
        w.write_frame(30, sim.time, 0.0, **sim.frame())
    with io.open(path) as run:
        out = export_run(run, tmp_path / "vtk", format="vtk", progress=False)
    vtu = sorted(out.parent.rglob("*.vtu")) if out.is_file() else sorted(out.rglob("*.vtu"))
    text = "".join(p.read_text(errors="replace") for p in vtu)
    assert 'Name="id"' in text and 'type="Int32"' in text


def test_batch_ids_stay_within_their_scene():
    from corpuscle.batch import Batch

    b = Batch.from_scene("magic8ball", n=3, backend="serial", particles=600, settle=0.0)
    b.step(40)
    ids = np.asarray(b.field("id", copy=True))
    n = len(ids) // 3
    assert not np.array_equal(ids, np.arange(len(ids)))  # re-sorted
    for s in range(3):  # scene s holds ids s n ... (s + 1) n - 1
        assert np.array_equal(np.sort(ids[s * n:(s + 1) * n]), np.arange(s * n, (s + 1) * n))
