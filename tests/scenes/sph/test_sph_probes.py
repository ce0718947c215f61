"""The SPH box's probes as the experiments have them (scenes/sph/probe.h): a face (a disc or
square of a given size with a normal) reads the mean over its sample points of the Shepard
interpolation of the fluid (a dry point reads 0), against a float64 NumPy reference on a
static field; each probe keeps a series on its own interval (every step by default), drained
from the core's ring, whose impulse is the trapezoid of the series; the keys are checked
with one-line errors; the series goes into the .cps frames and reads back; CUDA equals the CPU."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corpuscle import Simulation
from corpuscle import _core
from corpuscle.kinds._sph_box import PROBE_SERIES, pressure_impulse
from corpuscle.scene import load_scene
from corpuscle.schema import SceneError

from cli_script import assert_one_line_error, corpuscle
from test_sph_box import fields, kernel_grad, small, stirred


# ---- the sample points ------------------------------------------------------------------------

def test_sample_points_2d_segment():
    pts = _core.probe_samples([1.0, 0.2], [-2.0, 0.0], 1, 0.1, 5)
    assert pts.shape == (5, 2)
    np.testing.assert_allclose(pts[:, 0], 1.0, atol=1e-7)  # on the face (across the normal x)
    np.testing.assert_allclose(np.sort(pts[:, 1]), 0.2 + 0.1 * (np.arange(5) + 0.5) / 5 - 0.05, atol=1e-6)
    np.testing.assert_array_equal(_core.probe_samples([1.0, 0.2], [1.0, 0.0], 0, 0.0, 1), np.float32([[1.0, 0.2]]))


@pytest.mark.parametrize("normal", [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.3, -0.5, 0.8]])
def test_sample_points_3d(normal):
    n = np.asarray(normal) / np.linalg.norm(normal)
    c = np.array([0.5, 0.4, 0.3])
    sq = _core.probe_samples(c.tolist(), normal, 2, 0.2, 16)
    assert sq.shape == (16, 3)
    np.testing.assert_allclose((sq - c) @ n, 0.0, atol=1e-6)  # in the face's plane
    np.testing.assert_allclose(sq.mean(0), c, atol=1e-6)
    d = np.sort(np.linalg.norm(sq[:, None] - sq[None], axis=-1), axis=1)[:, 1]
    np.testing.assert_allclose(d, 0.05, rtol=1e-4)  # a 4 x 4 grid of pitch side / 4
    disc = _core.probe_samples(c.tolist(), normal, 1, 0.2, 200)
    np.testing.assert_allclose((disc - c) @ n, 0.0, atol=1e-6)
    r = np.linalg.norm(disc - c, axis=1)
    assert r.max() <= 0.1 * (1 + 1e-5)
    # equal areas: the fraction within radius rho is (rho / R)^2
    for q in (0.25, 0.5, 0.75):
        assert np.mean(r < q * 0.1) == pytest.approx(q * q, abs=0.01)
    np.testing.assert_allclose(disc.mean(0), c, atol=0.1 * 0.02)


# ---- the reading on a static field ------------------------------------------------------------

def _face_reference(sim, pts):
    f = fields(sim)
    p = sim.params
    vals, wsum = [], []
    for x in pts:
        d = x - f["position"].astype(np.float64)
        r = np.sqrt((d * d).sum(1))
        w, _ = kernel_grad("wendland", sim.kind.dim, p["h"], d, r)
        wv = w * p["mass"] / f["density"].astype(np.float64)
        wsum.append(wv.sum())
        vals.append((wv * f["pressure"]).sum() / wv.sum() if wv.sum() > 0 else 0.0)  # dry: 0
    return float(np.mean(vals)), float(np.mean(wsum))


@pytest.mark.parametrize("kind,probe", [
    ("dam-break-2d", {"name": "wall", "position": [0.146, 0.02], "shape": "disc", "size": 0.03,
                      "normal": [-1.0, 0.0], "samples": 7}),
    ("dam-break-2d", {"name": "wet_dry", "position": [0.08, 0.3], "shape": "square", "size": 0.1,
                      "normal": [1.0, 0.0], "samples": 15}),  # across the free surface: part dry
    ("dam-break", {"name": "floor", "position": [0.07, 0.04, 0.0], "shape": "disc", "size": 0.03,
                   "normal": [0.0, 0.0, 1.0], "samples": 12}),
    ("dam-break", {"name": "sq", "position": [0.146, 0.03, 0.05], "shape": "square", "size": 0.02,
                   "normal": [1.0, 0.0, 0.0], "samples": 9}),
])
def test_face_is_the_mean_of_its_sample_points(kind, probe):
    sim = stirred(small(kind, particles=400 if kind == "dam-break-2d" else 800, probes=[probe]))
    sim.evaluate()
    got = sim.state()["probes"][probe["name"]]
    pts = _core.probe_samples(probe["position"], probe["normal"], {"disc": 1, "square": 2}[probe["shape"]],
                              probe["size"], probe["samples"])
    ref_p, ref_w = _face_reference(sim, pts)
    scale = float(np.abs(fields(sim)["pressure"]).max())
    assert got["pressure"] == pytest.approx(ref_p, rel=1e-4, abs=1e-4 * scale)
    assert got["weight"] == pytest.approx(ref_w, rel=1e-4)
    if probe["name"] == "wet_dry":
        # some points dry: the face reads less than the mean over its wet points alone
        wet = [_face_reference(sim, [x]) for x in pts]
        assert any(w == 0 for _, w in wet) and any(w > 0 for _, w in wet)


def test_samples_from_the_spacing():
    probe = {"name": "s", "position": [0.146, 0.02], "shape": "disc", "size": 0.03, "normal": [-1.0, 0.0]}
    sim = small("dam-break-2d", particles=400, probes=[probe])
    dp = sim.info["spacing"]
    assert sim.params["probe_samples"] == [float(math.ceil(2 * 0.03 / dp))]  # at most dp / 2 apart
    assert sim.params["probe_shape"] == [1.0] and sim.params["probe_normal"] == [-1.0, 0.0]


# ---- the series -------------------------------------------------------------------------------

def _series_sim(interval=0.0, backend="serial"):
    probes = [{"name": "every", "position": [0.146, 0.02], "shape": "disc", "size": 0.02, "normal": [-1.0, 0.0]},
              {"name": "slow", "position": [0.05, 0.01], "interval": interval}]
    return small("dam-break-2d", backend=backend, particles=200, probes=probes)


def test_series_every_step_and_on_an_interval():
    dt_interval = 2e-3
    sim = _series_sim(dt_interval)
    times = [sim.time]
    for _ in range(3):  # calls longer and shorter than the ring
        sim.step(PROBE_SERIES + 7)
        sim.step(5)
        times.append(sim.time)
    n = 3 * (PROBE_SERIES + 12)
    t, p = sim.probe_series("every")
    assert len(t) == len(p) == n == sim.steps
    assert t[0] == 0.0 and np.all(np.diff(t) > 0)
    # the last sample is of the state the last step started from, the one before the current
    assert t[-1] < sim.time
    # the sample of a step is the probe's reading of that state: the last equals the state's
    # probe value read after stepping back to it is not possible; the current reading is the
    # next step's first sample
    ts, ps = sim.probe_series("slow")
    assert ts[0] == 0.0 and np.all(np.diff(ts) > 0)
    # one sample in each interval the run covered (the first step at or after each multiple)
    k = np.floor(ts / dt_interval + 1e-9)
    assert np.array_equal(k, np.arange(len(ts)))
    assert len(ts) == int(np.floor(t[-1] / dt_interval + 1e-9)) + 1
    with pytest.raises(KeyError, match="no probe 'nope'"):
        sim.probe_series("nope")


def test_the_series_sample_is_the_reading():
    sim = _series_sim()
    sim.step(4)
    sim.evaluate()  # the reading of the current state (no sample: not a step)
    now = sim.state()["probes"]["every"]["pressure"]
    assert len(sim.probe_series("every")[0]) == 4
    sim.step(1)
    t, p = sim.probe_series("every")
    assert len(t) == 5 and p[-1] == np.float32(now)


def test_impulse_is_the_trapezoid_of_the_series():
    sim = _series_sim()
    sim.step(60)
    t, p = sim.probe_series("every")
    i0, i1 = 10, 50
    ref = float(np.sum(0.5 * (p[i0 + 1:i1 + 1] + p[i0:i1]) * np.diff(t[i0:i1 + 1])))
    assert sim.probe_impulse("every", t[i0], t[i1]) == pytest.approx(ref, rel=1e-12)
    # a window between samples: the series interpolated at its ends
    a, b = 0.5 * (t[i0] + t[i0 + 1]), t[i1]
    pa = 0.5 * (p[i0] + p[i0 + 1])
    ref2 = ref - 0.5 * (p[i0] + p[i0 + 1]) * (t[i0 + 1] - t[i0]) + 0.5 * (pa + p[i0 + 1]) * (t[i0 + 1] - a)
    assert sim.probe_impulse("every", a, b) == pytest.approx(ref2, rel=1e-9)
    with pytest.raises(ValueError, match="outside the series"):
        sim.probe_impulse("every", -1.0, t[5])
    assert pressure_impulse(np.array([0.0, 1.0, 3.0]), np.array([0.0, 2.0, 2.0]), 0.0, 3.0) == pytest.approx(5.0)


# ---- the keys -----------------------------------------------------------------------------------

@pytest.mark.parametrize("kind,entry,words", [
    ("dam-break-2d", {"shape": "hexagon"}, ["shape", "hexagon"]),
    ("dam-break-2d", {"shape": "disc"}, ["probes[1].size", "size > 0"]),
    ("dam-break-2d", {"shape": "disc", "size": 0.01, "normal": [0.0, 0.0]}, ["probes[1].normal", "non-zero"]),
    ("dam-break-2d", {"size": 0.01}, ["probes[1].size", "point"]),
    ("dam-break-2d", {"samples": 3}, ["probes[1].samples", "point"]),
    ("dam-break-2d", {"shape": "disc", "size": 0.01, "samples": 5000}, ["samples", "5000"]),
    ("dam-break-2d", {"interval": -1.0}, ["interval", "-1"]),
    ("dam-break-2d", {"shape": "square", "size": 0.5, "normal": [1.0, 0.0]}, ["probes[1].size", "outside the tank"]),
    ("dam-break", {"shape": "square", "size": 0.01, "normal": [1.0, 0.0, 0.0], "samples": 10},
     ["probes[1].samples", "square number"]),
])
def test_bad_probe_keys(kind, entry, words):
    pos = [0.1, 0.05] if kind == "dam-break-2d" else [0.1, 0.03, 0.05]
    probe = {"name": "p", "position": pos, **entry}
    with pytest.raises(SceneError) as e:
        load_scene(kind).with_overrides({"probes": [probe]})
    msg = str(e.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg, msg


def test_cli_bad_probe_is_one_line(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text('[scene]\nkind = "dam-break-2d"\n[fluid]\nparticles = 200\n'
                     '[[probes]]\nname = "p"\nposition = [0.1, 0.05]\nshape = "disc"\n')
    assert_one_line_error(corpuscle("run", scene, "--steps", "1", "--out", tmp_path / "o.cps"), "size")


# ---- water-level gauges (shape = "gauge") -------------------------------------------------------

def _gauge_reference(sim, x0, length, samples):
    """The level by the header's definition, in float64: the filling C = sum_j W V_j over fluid
    and wall particles at the samples from x0 up by length; the first fall below 1/2 from the
    lower end, linearly interpolated."""
    f = fields(sim)
    p = sim.params
    pos = np.concatenate([f["position"], f["wall_position"]]).astype(np.float64)
    vol = p["mass"] / np.concatenate([f["density"], f["wall_density"]]).astype(np.float64)
    up = np.zeros(sim.kind.dim)
    up[-1] = 1.0
    fill = []
    for s in range(samples):
        x = np.asarray(x0, dtype=np.float64) + up * length * s / (samples - 1)
        d = x - pos
        w, _ = kernel_grad("wendland", sim.kind.dim, p["h"], d, np.sqrt((d * d).sum(1)))
        fill.append(float((w * vol).sum()))
    ds = length / (samples - 1)
    if fill[0] < 0.5:
        return 0.0, fill[0]
    for s in range(1, samples):
        if fill[s] < 0.5:
            return ds * (s - 1 + (fill[s - 1] - 0.5) / (fill[s - 1] - fill[s])), fill[0]
    return length, fill[0]


@pytest.mark.parametrize("kind", ["dam-break-2d", "dam-break"])
def test_gauge_is_the_filling_crossing(kind):
    # stirred: the surface is ragged, the crossing lies between samples somewhere
    dim = 2 if kind == "dam-break-2d" else 3
    col = [0.07, 0.0] if dim == 2 else [0.07, 0.03, 0.0]
    dry = [0.5, 0.0] if dim == 2 else [0.5, 0.03, 0.0]
    probes = [{"name": "col", "position": col, "shape": "gauge", "size": 0.35, "samples": 41},
              {"name": "dry", "position": dry, "shape": "gauge", "size": 0.2}]
    sim = stirred(small(kind, particles=400 if dim == 2 else 800, probes=probes))
    sim.evaluate()
    st = sim.state()["probes"]
    level, bottom = _gauge_reference(sim, col, 0.35, 41)
    assert 0.05 < level < 0.35  # the crossing is inside the line, not at an end
    assert st["col"]["level"] == pytest.approx(level, abs=1e-5)
    assert st["col"]["weight"] == pytest.approx(bottom, rel=1e-4)
    assert st["col"]["elevation"] == pytest.approx(col[-1] + st["col"]["level"])
    assert "pressure" not in st["col"]
    # a dry floor: the wall layers' half support, C about 1/2 at the floor's face, so the level
    # is 0 or within a few hundredths of dp of it (the wall densities' scatter)
    assert st["dry"]["level"] < 0.05 * sim.info["spacing"] and st["dry"]["weight"] < 0.55


def test_gauge_reads_a_still_column_height():
    # unstirred: a still column of height H on the floor reads H within a fraction of dp
    # (the continuum surface of particles on a lattice: the last row's centres at H - dp/2)
    sim = small("dam-break-2d", particles=1600,
                probes=[{"name": "g", "position": [0.073, 0.0], "shape": "gauge", "size": 0.35}])
    sim.evaluate()
    H = sim.info["fluid_height"]
    dp = sim.info["spacing"]
    assert sim.state()["probes"]["g"]["level"] == pytest.approx(H, abs=0.05 * dp)


def test_gauge_series_result_and_frames(tmp_path):
    from corpuscle.io import Run

    probes = [{"name": "g", "position": [0.3, 0.0], "shape": "gauge", "size": 0.2, "interval": 0.002}]
    sim = small("dam-break-2d", particles=200, probes=probes)
    sim.run(until=0.15)
    t, lv = sim.probe_series("g")
    assert len(t) > 10 and np.all(np.diff(t) > 0)
    assert lv[0] == 0.0 and lv.max() > 0.0  # dry until the surge arrives at x = 0.3 m
    assert np.all((lv >= 0.0) & (lv <= 0.2))
    with pytest.raises(ValueError, match="gauge"):
        sim.probe_impulse("g", 0.0, 0.1)
    assert sim.diagnostics()["probe_g_level"] == pytest.approx(sim.state()["probes"]["g"]["level"])
    scene = tmp_path / "s.toml"
    scene.write_text('[scene]\nkind = "dam-break-2d"\n[fluid]\nparticles = 200\n[run]\nrecord_every = 16\n'
                     '[[probes]]\nname = "g"\nposition = [0.1, 0.0]\nshape = "gauge"\nsize = 0.3\n')
    out = tmp_path / "o.cps"
    r = corpuscle("run", scene, "--steps", "40", "--backend", "serial", "--out", out, "--no-progress", "--json")
    assert r.returncode == 0, r.stderr
    assert "probe_g_level" in r.stdout
    levels = np.concatenate([np.asarray(fr["probe.g.level"]) for fr in Run(out)])
    assert len(levels) == 40 and np.all(levels > 0.0)


@pytest.mark.parametrize("entry,words", [
    ({"size": 0.0}, ["probes[1].size", "gauge"]),
    ({"size": 0.1, "samples": 1}, ["probes[1].samples", "2 points"]),
    ({"size": 0.1, "normal": [0.0, -1.0]}, ["probes[1].normal", "vertical"]),
    ({"size": 5.0}, ["probes[1].size", "above the tank"]),
])
def test_bad_gauge_keys(entry, words):
    probe = {"name": "g", "position": [0.1, 0.0], "shape": "gauge", **entry}
    with pytest.raises(SceneError) as e:
        load_scene("dam-break-2d").with_overrides({"probes": [probe]})
    msg = str(e.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg, msg


# ---- the output ---------------------------------------------------------------------------------

def test_series_in_the_cps_and_export(tmp_path):
    from corpuscle.io import Run

    scene = tmp_path / "s.toml"
    scene.write_text('[scene]\nkind = "dam-break-2d"\n[fluid]\nparticles = 200\n[run]\nrecord_every = 16\n'
                     '[[probes]]\nname = "wall"\nposition = [0.146, 0.02]\nshape = "disc"\nsize = 0.02\n'
                     'normal = [-1.0, 0.0]\n'
                     '[[probes]]\nname = "pt"\nposition = [0.05, 0.02]\ninterval = 0.002\n')
    out = tmp_path / "o.cps"
    r = corpuscle("run", scene, "--steps", "100", "--backend", "serial", "--out", out, "--no-progress")
    assert r.returncode == 0, r.stderr
    run = Run(out)
    t, p = [], []
    for fr in run:
        t.append(np.asarray(fr["probe.wall.time"]))
        p.append(np.asarray(fr["probe.wall.pressure"]))
    t, p = np.concatenate(t), np.concatenate(p)
    assert len(t) == 100 and t[0] == 0.0 and np.all(np.diff(t) > 0) and np.all(np.isfinite(p))
    assert np.all(np.asarray(run[1]["probe.wall.position"]) == np.float32([0.146, 0.02]))
    e = corpuscle("export", out, tmp_path / "vtk", "--format", "vtk", "-q")
    assert e.returncode == 0, e.stderr


# ---- CUDA -----------------------------------------------------------------------------------------

@pytest.mark.gpu
@pytest.mark.parametrize("kind", ["dam-break-2d", "dam-break"])
def test_cuda_matches_cpu(kind):
    if not Simulation.cuda_available():
        pytest.skip("no CUDA device")
    if kind == "dam-break-2d":
        probes = [{"name": "f", "position": [0.146, 0.02], "shape": "disc", "size": 0.02, "normal": [-1.0, 0.0]},
                  {"name": "q", "position": [0.05, 0.01], "interval": 0.003}]
    else:
        probes = [{"name": "f", "position": [0.146, 0.03, 0.02], "shape": "square", "size": 0.02,
                   "normal": [-1.0, 0.0, 0.0], "samples": 16},
                  {"name": "q", "position": [0.05, 0.03, 0.01], "interval": 0.003}]
    probes.append({"name": "g", "position": [0.1] + [0.03] * (len(probes[0]["position"]) - 2) + [0.0],
                   "shape": "gauge", "size": 0.3})
    sims = [small(kind, backend=b, particles=400, probes=probes) for b in ("cpu", "cuda")]
    for s in sims:
        s.step(150)
    for name in ("f", "q", "g"):
        (tc, pc), (tg, pg) = (s.probe_series(name) for s in sims)
        assert len(tc) == len(tg) > 1
        np.testing.assert_allclose(tg, tc, rtol=1e-5)
        scale = float(np.abs(pc).max()) + 1.0
        np.testing.assert_allclose(pg, pc, rtol=1e-3, atol=1e-3 * scale)
