"""Walls of one DBC layer (walls.layers, DualSPHysics's drawing) against the kernel support's,
DualSPHysics's dam break with its building (dam-break-dsph-building), and the time-to-solution
and memory figures of `run --json` and `bench`."""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pytest

from corpuscle import Simulation
from corpuscle.scene import load_scene

from cli_script import assert_one_line_error, corpuscle


def _hydrostatic(*argv):
    from corpuscle.validation import hydrostatic

    p = argparse.ArgumentParser()
    hydrostatic.add_arguments(p)
    return hydrostatic.run(p.parse_args(["--backend", "serial", *argv]))


def _leak_checks(checks):
    return {c.name: c for c in checks if c.name.startswith(("fluid mass inside", "fluid outside", "volume sum",
                                                            "free surface", "pressure"))}


def test_one_layer_walls_hold_a_hydrostatic_column_2d():
    """One layer of DBC particles in 2-D: no particle leaves the tank at any step, the mass
    stays in it, the pressure against depth and the surface hold as with the support's
    layers (measured: within 1.9 %). The near-wall particles keep moving (the largest speed,
    1.6 % of sqrt(2 g H) at t = 1 s against 0.03 % with the support's layers, is the one
    check of the validation one layer fails; docs/sph_box.md)."""
    checks = _hydrostatic("--particles", "450", "--time", "1.0", "--wall-layers", "1")
    held = _leak_checks(checks)
    assert len(held) == 6
    bad = [c for c in held.values() if not c.passed]
    assert not bad, bad
    assert held["fluid outside the box (any step)"].measured == 0.0


@pytest.mark.xfail(strict=True, reason="one DBC layer leaks in 3-D at CI size: fluid particles pass through the "
                   "gaps of the square wall lattice (docs/sph_box.md, 'Wall layers')")
def test_one_layer_walls_hold_a_hydrostatic_column_3d():
    checks = _hydrostatic("--dim", "3", "--particles", "400", "--time", "0.5", "--wall-layers", "1")
    bad = [c for c in _leak_checks(checks).values() if not c.passed]
    assert not bad, bad


def test_two_layer_walls_hold_a_hydrostatic_column_3d():
    """Two layers close the gaps one leaves in 3-D: no particle leaves the tank."""
    checks = _hydrostatic("--dim", "3", "--particles", "400", "--time", "0.5", "--wall-layers", "2")
    held = _leak_checks(checks)
    assert held["fluid outside the box (any step)"].measured == 0.0
    assert held["fluid mass inside the box"].passed


def _wall_count(nb, layers):
    return int(np.prod(np.asarray(nb) + 2 * layers) - np.prod(nb))


@pytest.mark.parametrize("kind", ["dam-break-2d", "dam-break"])
def test_wall_layers_set_the_wall_particles(kind):
    over = {"fluid.particles": 300 if kind == "dam-break" else 200}
    sims = {L: Simulation(load_scene(kind).with_overrides(over | {"walls.layers": L}), "serial") for L in (0, 1, 2)}
    support = sims[0].info["support_layers"]
    assert sims[0].info["layers"] == support == math.ceil(sims[0].info["h"] / sims[0].info["spacing"] - 1e-6)
    for L, sim in sims.items():
        nb = np.rint(np.asarray(sim.info["box"]) / sim.info["spacing"]).astype(int)
        assert sim.info["layers"] == (L or support)
        assert sim.info["n_wall"] == _wall_count(nb, L or support)
        wall = np.asarray(sim.core.download("wall_position"), dtype=np.float64)
        assert len(wall) == sim.info["n_wall"]
        # every wall particle within `layers` spacings outside the box, none inside it
        box = np.asarray(sim.info["box"])
        dp = sim.info["spacing"]
        assert not np.any(np.all((wall > 0) & (wall < box), axis=1))
        assert np.all(wall > -(sim.info["layers"]) * dp) and np.all(wall < box + sim.info["layers"] * dp)
    assert sims[1].info["n_fluid"] == sims[0].info["n_fluid"]


def test_wall_layers_bad_value_is_one_line():
    assert_one_line_error(corpuscle("run", "dam-break-2d", "--backend", "serial", "--set", "walls.layers=-1",
                                    "--time", "0.001"), "walls.layers")


def test_dam_break_dsph_building_scene():
    """DualSPHysics's 01_DamBreak: the tank, column, building and settings of issue 33."""
    scene = load_scene("dam-break-dsph-building")
    v = scene.values
    assert v["sph.kernel"] == "cubic-spline" and v["sph.smoothing"] == pytest.approx(math.sqrt(3.0))
    assert v["fluid.sound_speed"] == pytest.approx(20.0 * math.sqrt(9.81 * 0.3), rel=1e-6)
    assert (v["sph.alpha"], v["sph.diffusion"], v["sph.delta"]) == (0.1, "fourtakas", 0.1)
    assert (v["timestep.cfl"], v["timestep.integrator"], v["timestep.verlet_steps"]) == (0.2, "verlet", 40)
    assert v["walls.layers"] == 2  # the thinnest DBC wall that holds in 3-D (one leaks: the xfail above)
    a = v["dam.a"]
    assert [a * v["dam.tank_length"], a * v["dam.depth"], a * v["dam.tank_height"]] == pytest.approx([1.6, 0.67, 0.4])
    assert [a, a * v["dam.depth"], a * v["dam.height"]] == pytest.approx([0.4, 0.67, 0.3])
    (b,) = scene.arrays["bodies"]
    lo = np.asarray(b["position"]) - 0.5 * np.asarray(b["size"])
    assert lo == pytest.approx([0.9, 0.24, 0.0]) and b["size"][:2] == pytest.approx([0.12, 0.12])
    # dp 4.5 mm by default: the column's volume over dp^3
    assert (0.4 * 0.67 * 0.3 / v["fluid.particles"]) ** (1 / 3) == pytest.approx(0.0045, rel=1e-4)

    # a coarse copy with DualSPHysics's one layer builds and steps: the building is one layer
    # of wall particles, no fluid in it
    sim = Simulation(scene.with_overrides({"fluid.spacing": 0.03, "walls.layers": 1}), "serial")
    dp = sim.info["spacing"]
    assert sim.info["layers"] == 1 and sim.info["support_layers"] == 4
    assert sim.info["c0"] == pytest.approx(34.31035)
    nb = np.rint(np.asarray(sim.info["box"]) / dp).astype(int)
    n_body = sim.info["n_body_particles"]
    assert n_body > 0 and sim.info["n_wall"] == _wall_count(nb, 1) + n_body
    wall = np.asarray(sim.core.download("wall_position"), dtype=np.float64)
    hi = lo + np.asarray(b["size"])
    in_body = np.all((wall > lo) & (wall < hi), axis=1)
    assert in_body.sum() == n_body
    # one layer: every body particle within one spacing of the building's surface
    gap = np.minimum(wall[in_body] - lo, hi - wall[in_body]).min(axis=1)
    assert np.all(gap < dp)
    pos = np.asarray(sim.core.download("position"), dtype=np.float64)
    assert not np.any(np.all((pos > lo) & (pos < lo + np.asarray(b["size"])), axis=1))
    sim.step(5)
    assert sim.check_health() is None or not sim.check_health()
    assert sim.info["obstacles"] and sim.info["obstacles"][0]["type"] == "box"


def test_run_json_reports_time_to_solution_and_memory(tmp_path):
    proc = corpuscle("run", "dam-break-2d", "--backend", "serial", "--particles", "200", "--time", "0.02",
                     "--json", "--out", tmp_path / "r.cps")
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert s["wall_seconds_per_sim_second"] == pytest.approx(s["wall_time"] / s["sim_time"], rel=1e-9)
    assert s["fluid_particles"] == s["particles"] and s["wall_particles"] > 0
    assert s["bytes_per_particle"] == pytest.approx(s["bytes_needed"] / (s["fluid_particles"] + s["wall_particles"]))
    assert s["largest_particles"] is None or s["largest_particles"] > s["fluid_particles"] + s["wall_particles"]
    text = corpuscle("run", "dam-break-2d", "--backend", "serial", "--particles", "200", "--time", "0.02",
                     "--out", tmp_path / "r2.cps")
    assert text.returncode == 0, text.stderr
    assert "wall s per simulated s" in text.stdout and "fluid / wall particles" in text.stdout
    assert "bytes a particle" in text.stdout


def test_bench_json_reports_time_to_solution(tmp_path):
    out = tmp_path / "b.json"
    proc = corpuscle("bench", "dam-break-2d", "--backend", "serial", "--particles", "200", "--steps", "20",
                     "--repeats", "2", "--warmup", "2", "--json", out)
    assert proc.returncode == 0, proc.stderr
    (row,) = json.loads(out.read_text())
    w = row["wall_seconds_per_sim_second"]
    assert w is not None and w > 0
    assert row["fluid_particles"] == row["particles"] and row["wall_particles"] > 0
    assert row["bytes_per_particle"] > 0
    assert "wall s/sim s" in proc.stdout and "fluid +" in proc.stdout
