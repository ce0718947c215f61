"""The `lists` index's delta-coded storage (sph.list_storage = "delta", spatial/delta_list.h):
the same entries in the same order as the slot lists, so a run is bitwise the same on the CPU
(every kind, lanes, periodic axes, an overflow that grows the lists, serial and OpenMP); its
memory is about a quarter of the slot lists'; CUDA's delta lists give CUDA's slot lists' run
bit for bit (gpu)."""

from __future__ import annotations

import numpy as np
import pytest

from corpuscle import Simulation
from corpuscle import _core
from corpuscle.kinds import _sph_box

from test_sph_box import KINDS, small
from test_sph_lists import by_id, rebuilds, stirred_by_id

NAMES = ("position", "velocity", "density", "wall_density", "id")


def _pair(kind, backend="serial", steps=25, **over):
    out = {}
    for storage in ("slots", "delta"):
        sim = stirred_by_id(small(kind, backend=backend, neighbors="lists", sph__list_storage=storage, **over))
        sim.step(steps)
        out[storage] = sim
    return out["slots"], out["delta"]


def _same(a, b):
    for name in NAMES:
        assert np.array_equal(np.asarray(a.core.download(name)), np.asarray(b.core.download(name))), name
    sa, sb = a.state(), b.state()
    assert rebuilds(a) == rebuilds(b) >= 2
    assert sa["mean_neighbors"] == sb["mean_neighbors"]
    assert sa["time"] == sb["time"]


@pytest.mark.parametrize("kind", list(KINDS))
def test_delta_lists_run_bitwise_as_slot_lists(kind):
    a, b = _pair(kind, sph__skin=0.2)
    _same(a, b)


@pytest.mark.parametrize("lanes", [2, 8])
def test_delta_lists_with_lanes_bitwise(lanes):
    a, b = _pair("dam-break", sph__skin=0.2, sph__lanes=lanes)
    _same(a, b)


def test_delta_lists_openmp_and_periodic_bitwise():
    # a periodic axis: a wrapped row is walked as two ranges, the second before the first
    # (a negative difference: an escape)
    a, b = _pair("poiseuille", backend="cpu", steps=60, sph__skin=0.01)  # (periodic in x)
    assert a.params["periodic"] == 1
    _same(a, b)


def test_delta_lists_grow_on_overflow_bitwise(monkeypatch):
    ref = stirred_by_id(small("dam-break", neighbors="lists", sph__list_storage="delta"))
    ref.step(5)
    build = _sph_box.SphBox.build

    def tiny(self, scene, target, checkpoint=None):
        b = build(self, scene, target, checkpoint)
        b.params["max_neighbors"] = 8  # bytes
        return b

    monkeypatch.setattr(_sph_box.SphBox, "build", tiny)
    sim = stirred_by_id(small("dam-break", neighbors="lists", sph__list_storage="delta"))
    assert sim.core.scalars()["list_capacity"] > 8
    assert sim.step(5) == 5
    assert sim.state()["bad"] == 0
    for name in ("position", "velocity", "density"):
        assert np.array_equal(by_id(sim, name), by_id(ref, name)), name


def test_delta_lists_take_a_quarter_of_the_memory():
    """The core's estimate (what the memory check and the run summary use): the lists' part
    falls from 4 bytes an entry to about one."""
    from corpuscle.kinds import Target, find

    from corpuscle.scene import load_scene

    kind = find("dam-break")
    need, cap = {}, {}
    for storage in ("slots", "delta"):
        sc = load_scene("dam-break-dsph-building").with_overrides({"fluid.spacing": 0.03,
                                                                   "sph.list_storage": storage})
        p = kind.build(sc, Target("cpu", "lists")).params
        need[storage] = _core.bytes_needed("dam-break", "lists", p) / (p["n_fluid"] + p["n_wall"])
        cap[storage] = p["max_neighbors"]
    assert cap["slots"] % 32 == 0 and cap["delta"] % 32 == 0
    # slots: (capacity + 1) x 4 bytes; delta: capacity bytes + a 4-byte count (all else equal)
    assert need["slots"] - need["delta"] == pytest.approx((cap["slots"] + 1) * 4 - (cap["delta"] + 4), rel=1e-12)
    assert need["delta"] < 0.45 * need["slots"]


def test_list_storage_bad_value_is_one_line():
    from cli_script import assert_one_line_error, corpuscle

    assert_one_line_error(corpuscle("run", "dam-break-2d", "--backend", "serial", "--set", "sph.list_storage=bits",
                                    "--time", "0.001"), "sph.list_storage")


@pytest.mark.gpu
@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("lanes", [1, 4])
def test_cuda_delta_lists_are_cuda_slot_lists_bit_for_bit(kind, lanes):
    """CUDA builds a slot's delta list with several lanes (a ballot orders the hits and places
    the escapes): the lists must decode to the slot lists' entries in their order, so the two
    storages give the same CUDA run bit for bit."""
    if not Simulation.cuda_available():
        pytest.skip("no CUDA")
    a, b = _pair(kind, backend="cuda", steps=40, particles=3000, sph__skin=0.1, sph__lanes=lanes)
    _same(a, b)


def test_info_memory_lists_each_index():
    import json as _json

    from cli_script import corpuscle

    proc = corpuscle("info", "--memory", "dam-break-dsph-building", "--backend", "cpu", "--json", timeout=300)
    assert proc.returncode == 0, proc.stderr
    data = _json.loads(proc.stdout)
    rows = {(r["index"], r["list_storage"]): r for r in data["rows"]}
    assert {("lists", "slots"), ("lists", "delta"), ("grid", None), ("compact", None)} <= set(rows)
    assert rows[("lists", "delta")]["bytes_per_particle"] < 0.5 * rows[("lists", "slots")]["bytes_per_particle"]
    for r in rows.values():
        if r["memory"]:
            assert r["largest_particles"] == int(r["memory"] / r["bytes_per_particle"])
    from cli_script import assert_one_line_error

    assert_one_line_error(corpuscle("info", "--memory", "magic8ball"), "--memory")
