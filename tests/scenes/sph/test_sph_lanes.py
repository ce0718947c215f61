"""The SPH box's `lists` pair pass with several lanes per particle (`sph.lanes`): G lanes split
a particle's slot list (lane l takes the entries l, l + G, ...) and merge their partial sums in
a fixed butterfly. The CPU runs the G lanes in turn and merges them in the same order as the
CUDA shuffles, so every width is checked here: the same pair sums as one lane up to float
reordering, the same neighbours counted, serial and OpenMP bitwise equal for each width, runs
that reuse their lists staying with one lane's; a bad width is a one-line error; CUDA matches
the CPU at every width (gpu)."""

from __future__ import annotations

import numpy as np
import pytest

from corpuscle import Simulation
from corpuscle.scene import SceneError

from test_sph_box import KINDS, small
from test_sph_lists import assert_matches_cpu, by_id, rebuilds, stirred_by_id

WIDTHS = (2, 4, 8)


def lanes_sim(kind, lanes, backend="serial", **kw):
    return small(kind, backend=backend, neighbors="lists", sph__lanes=lanes, **kw)


@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("lanes", WIDTHS)
def test_lanes_give_one_lanes_pair_sums(kind, lanes):
    one = stirred_by_id(lanes_sim(kind, 1, sph__skin=0.15))
    many = stirred_by_id(lanes_sim(kind, lanes, sph__skin=0.15))
    one.evaluate()
    many.evaluate()
    assert many.core.scalars()["lanes"] == lanes and one.core.scalars()["lanes"] == 1
    # every neighbour is visited once: the same count (an integer sum, exact)
    assert many.state()["mean_neighbors"] == one.state()["mean_neighbors"]
    np.testing.assert_array_equal(by_id(one, "id"), by_id(many, "id"))
    for name in ("acceleration", "density_rate"):
        a, b = by_id(one, name), by_id(many, name)
        scale = np.abs(a).max()
        assert scale > 0
        # the same float32 terms summed in another order
        np.testing.assert_allclose(b, a, rtol=0, atol=2e-6 * scale, err_msg=name)
        assert not np.array_equal(a, b) or lanes == 1  # (the order did change: the lanes ran)
    np.testing.assert_array_equal(by_id(one, "pressure"), by_id(many, "pressure"))


@pytest.mark.parametrize("lanes", WIDTHS)
def test_lanes_runs_stay_with_one_lane(lanes):
    one, many = (stirred_by_id(lanes_sim("dam-break-2d", w, sph__skin=0.2)) for w in (1, lanes))
    one.step(40)
    many.step(40)
    assert 2 <= rebuilds(many) < 20  # the lists were reused and rebuilt
    assert many.time == pytest.approx(one.time, rel=1e-5)
    dp = one.info["spacing"]
    np.testing.assert_allclose(by_id(many, "position"), by_id(one, "position"), rtol=0, atol=1e-4 * dp)
    np.testing.assert_allclose(by_id(many, "density"), by_id(one, "density"), rtol=1e-5)


@pytest.mark.parametrize("lanes", [1, 4])
def test_lanes_serial_and_openmp_bitwise(lanes):
    a, b = (stirred_by_id(lanes_sim("dam-break-2d", lanes, backend=be, sph__skin=0.2)) for be in ("serial", "cpu"))
    a.step(30)
    b.step(30)
    assert rebuilds(a) == rebuilds(b) >= 2
    for name in ("position", "velocity", "density", "wall_density"):
        assert np.array_equal(a.core.download(name), b.core.download(name)), name


def test_lanes_automatic_on_the_cpu_is_one():
    sim = small("dam-break-2d", neighbors="lists")
    assert sim.core.scalars()["lanes"] == 1


@pytest.mark.parametrize("bad", [3, 5, 6, 7])
def test_bad_lanes_is_a_scene_error(bad):
    with pytest.raises(SceneError, match=r"sph\.lanes must be 0 \(automatic\), 1, 2, 4 or 8, got %d" % bad):
        small("fluid-box", neighbors="lists", sph__lanes=bad)


@pytest.mark.parametrize("bad", ["3", "16", "-1"])
def test_bad_lanes_is_a_one_line_error(bad):
    from cli_script import assert_one_line_error, corpuscle

    assert_one_line_error(corpuscle("run", "dam-break-2d", "--neighbors", "lists", "--set", f"sph.lanes={bad}",
                                    "--backend", "serial", "--steps", "1"), "sph.lanes")


# ---- CUDA against the CPU (the device machine) ------------------------------------------


@pytest.mark.gpu
@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("lanes", (0, 1) + WIDTHS)
def test_cuda_lanes_match_cpu(kind, lanes):
    if not Simulation.cuda_available():
        pytest.skip("no CUDA")

    def width(cpu, gpu):
        if lanes:
            assert gpu.core.scalars()["lanes"] == lanes
        assert gpu.state()["mean_neighbors"] == cpu.state()["mean_neighbors"]

    # the stirred state with a skin of 0.1, the stepped one with the default
    assert_matches_cpu(lambda b, stirred: lanes_sim(kind, lanes, backend=b, particles=2000,
                                                    **({"sph__skin": 0.1} if stirred else {})), width)


@pytest.mark.gpu
@pytest.mark.parametrize("lanes", WIDTHS)
def test_cuda_lanes_are_reproducible(lanes):
    if not Simulation.cuda_available():
        pytest.skip("no CUDA")
    a, b = (lanes_sim("fluid-box", lanes, backend="cuda", particles=4000) for _ in range(2))
    a.step(30)
    b.step(30)
    for name in ("position", "velocity", "density", "wall_density"):
        assert np.array_equal(a.core.download(name), b.core.download(name)), name


_GRAPH_RUN = r"""
import os, sys
import numpy as np
sys.path[:0] = [sys.argv[1], os.path.dirname(os.path.dirname(sys.argv[1]))]  # and tests/
from test_sph_lists import by_id, rebuilds, stirred_by_id
from test_sph_lanes import lanes_sim
sim = stirred_by_id(lanes_sim("dam-break-2d", int(sys.argv[3]), backend="cuda", particles=2000, sph__skin=0.2))
sim.step(100)
np.savez(sys.argv[2], position=by_id(sim, "position"), velocity=by_id(sim, "velocity"),
         density=by_id(sim, "density"), rebuilds=rebuilds(sim), time=sim.time)
"""


@pytest.mark.gpu
@pytest.mark.parametrize("lanes", [1, 4])
def test_cuda_skipped_sorts_change_nothing(tmp_path, lanes):
    """The steps that do not relist skip the sort and the marks inside the captured graph (a
    conditional node); with CORPUSCLE_GRAPH_CONDITIONALS=0 they run them (on unchanged keys):
    the two runs must be bitwise equal, over steps that relist inside the graphs too."""
    import os
    import subprocess
    import sys

    if not Simulation.cuda_available():
        pytest.skip("no CUDA")
    here = os.path.dirname(os.path.abspath(__file__))
    out = {}
    for flag in ("1", "0"):
        env = dict(os.environ, CORPUSCLE_GRAPH_CONDITIONALS=flag)
        path = tmp_path / f"run{flag}.npz"
        r = subprocess.run([sys.executable, "-c", _GRAPH_RUN, here, str(path), str(lanes)], env=env,
                           capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr
        out[flag] = np.load(path)
    assert int(out["1"]["rebuilds"]) >= 3  # relistings inside the captured steps too (the first is eager)
    assert int(out["1"]["rebuilds"]) == int(out["0"]["rebuilds"])
    assert float(out["1"]["time"]) == float(out["0"]["time"])
    for name in ("position", "velocity", "density"):
        assert np.array_equal(out["1"][name], out["0"][name]), name
