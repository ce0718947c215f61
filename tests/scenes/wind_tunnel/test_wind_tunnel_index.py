"""The wind tunnel's broad phase: the cell grid (the default), the Karras LBVH and the
all-pairs reference give the same contact set (per-particle contact counts equal, and equal to
a float64 NumPy count), the same number densities and the same forces (to float rounding: the
sums run in another order); all are listed and selectable; the LBVH is reproducible (serial
and OpenMP bitwise equal) and handles duplicate Morton codes."""

from __future__ import annotations

import numpy as np
import pytest

from corpuscle import Simulation, _core
from corpuscle.kinds import wind_tunnel as wt
from corpuscle.scene import load_scene


def make(index, n=3000, form="gather", backend="serial"):
    return Simulation.from_scene(load_scene("wind-tunnel"), backend=backend, particles=n, neighbors=index,
                                 overrides={"inflow.speed": 1.0, "inflow.speed_ratio": 1.0,
                                            "gas.solid_fraction": 0.3, "contact.form": form})


def _reference_contacts(sim, p):
    """float64: overlapping pairs, wall and airfoil contacts of every particle."""
    r = sim.radius
    d2 = ((p[:, None, :] - p[None, :, :]) ** 2).sum(-1)
    pp = (d2 < (2 * r) ** 2).sum(1) - 1
    lo, hi = sim.params["channel_lo"][1], sim.params["channel_hi"][1]
    walls = (p[:, 1] - lo < r).astype(int) + (hi - p[:, 1] < r).astype(int)
    foil = (wt.signed_distance(sim.info["airfoil"], p) < r).astype(int)
    return pp + walls + foil


def test_indexes_are_registered():
    assert dict(_core.kinds())["wind-tunnel"] == ["grid", "lbvh", "allpairs"]
    with pytest.raises(Exception, match=r"--neighbors must be one of grid, lbvh, allpairs \(the indexes of wind-tunnel\), got 'kd'"):
        make("kd", 500)


@pytest.mark.parametrize("other,form,backend", [("allpairs", "gather", "serial"), ("lbvh", "gather", "serial"),
                                                ("grid", "reflexive", "cpu"), ("lbvh", "reflexive", "cpu"),
                                                ("allpairs", "reflexive", "serial"), ("lbvh", "reflexive-warp", "cpu")])
def test_grid_and_the_other_indexes_give_the_same_contacts_and_forces(other, form, backend):
    """Every index in the gather form, and the reflexive form (each pair once, atomics; on
    OpenMP the atomics race as on the GPU), against the grid's gather."""
    a, b = make("grid"), make(other, form=form, backend=backend)
    checked = 0
    for _ in range(3):
        a.step(40)
        ia = np.argsort(a.field("id"))
        b.set_particles(a.positions[ia], a.velocities[ia])  # the same state, ids in order
        a.evaluate()
        b.evaluate()
        ia, ib = np.argsort(a.field("id")), np.argsort(b.field("id"))
        ca, cb = a.field("contacts")[ia], b.field("contacts")[ib]
        assert np.array_equal(ca, cb)
        ref = _reference_contacts(a, a.positions[ia].astype(np.float64))
        assert np.array_equal(ca, ref)
        assert np.array_equal(a.field("number_density")[ia], b.field("number_density")[ib])
        fa, fb = a.field("force")[ia].astype(np.float64), b.field("force")[ib].astype(np.float64)
        scale = np.abs(fa).max()
        assert np.abs(fa - fb).max() <= 1e-5 * scale
        pa, pb = a.field("pressure")[ia], b.field("pressure")[ib]
        assert np.abs(pa - pb).max() <= 1e-5 * np.abs(pa).max()
        checked += int((ca > 0).sum())
    assert checked > 300  # the comparison covers many contacts


@pytest.mark.parametrize("other", ["allpairs", "lbvh"])
def test_other_indexes_run_the_same_flow(other):
    a, b = make("grid", 1200), make(other, 1200)
    a.step(100)
    b.step(100)
    sa, sb = a.state(), b.state()
    assert sa["step"] == sb["step"] and abs(sa["time"] - sb["time"]) < 1e-9 * max(sa["time"], 1)
    assert sb["pushouts"] == 0 and sb["recycled"] > 0


def test_lbvh_is_reproducible_across_cpu_backends():
    a = Simulation.from_scene(load_scene("wind-tunnel"), backend="serial", particles=2000, neighbors="lbvh",
                              overrides={"inflow.speed": 1.0, "gas.solid_fraction": 0.3})
    b = Simulation.from_scene(load_scene("wind-tunnel"), backend="cpu", particles=2000, neighbors="lbvh",
                              overrides={"inflow.speed": 1.0, "gas.solid_fraction": 0.3})
    a.step(60)
    b.step(60)
    for name in ("position", "velocity", "id", "force", "pressure", "number_density"):
        assert np.array_equal(a.field(name), b.field(name)), name


def test_lbvh_with_duplicate_morton_codes():
    """Clusters of particles closer than one Morton cell (the channel / 65,536) share codes;
    the tree orders them by index and still finds every overlapping pair."""
    a, b = make("allpairs", 1500), make("lbvh", 1500)
    rng = np.random.default_rng(2)
    p = a.positions.astype(np.float64).copy()
    for c in range(0, 1500, 10):  # clusters of 10 within 1e-5 m
        p[c:c + 10] = p[c] + rng.uniform(-1e-5, 1e-5, (10, 2))
    p = p.astype(np.float32)
    v = np.zeros_like(p)
    for s in (a, b):
        s.set_particles(p, v)
        s.evaluate()
    ia, ib = np.argsort(a.field("id")), np.argsort(b.field("id"))
    assert np.array_equal(a.field("contacts")[ia], b.field("contacts")[ib])
    assert a.field("contacts").min() >= 9
    assert np.array_equal(a.field("number_density")[ia], b.field("number_density")[ib])


@pytest.mark.parametrize("index", ["grid", "lbvh"])
def test_reflexive_pairs_conserve_momentum(index):
    """Each pair's reaction is added once to the other particle: the particle-particle forces
    sum to zero, so the particles' total force is the walls' plus the airfoil's reaction."""
    s = make(index, 3000, form="reflexive", backend="cpu")
    s.step(40)
    s.evaluate()
    sc = s.scalars()
    f = s.field("force").astype(np.float64)
    pp_scale = np.abs(f).sum(axis=0).max()
    external = np.asarray(sc["wall_force"], dtype=np.float64) - np.asarray(sc["airfoil_force"], dtype=np.float64)
    assert np.abs(f.sum(axis=0) - external).max() <= 1e-5 * pp_scale
    assert (s.field("contacts") > 0).sum() > 100


def test_bench_sweeps_particles_and_indexes(tmp_path):
    import json

    from cli_script import corpuscle

    out = tmp_path / "b.json"
    r = corpuscle("bench", "wind-tunnel", "--backend", "serial", "--particles", "600,1200", "--neighbors",
                  "grid,lbvh", "--steps", "2", "--repeats", "1", "--warmup", "0", "--json", out, "--no-progress")
    assert r.returncode == 0, r.stderr
    rows = json.loads(out.read_text())
    assert [(row["particles"], row["neighbors"]) for row in rows] == [(600, "grid"), (600, "lbvh"), (1200, "grid"),
                                                                       (1200, "lbvh")]
    assert all(row["steps_per_second"] > 0 for row in rows)
    lines = r.stdout.splitlines()
    assert lines[0].split()[0] == "index"  # the sweep's table names each row's index
    assert [line.split()[0] for line in lines[1:5]] == ["grid", "lbvh", "grid", "lbvh"]


@pytest.mark.parametrize("index,form", [("lbvh", "gather"), ("lbvh", "reflexive")])
def test_no_particle_inside_the_airfoil_or_through_a_wall_with_the_tree(index, form):
    s = Simulation.from_scene(load_scene("wind-tunnel"), backend="cpu", particles=2500, neighbors=index,
                              overrides={"inflow.speed": 2.0, "inflow.speed_ratio": 2.0, "contact.form": form,
                                         "airfoil.shape": "naca0012", "airfoil.angle_of_attack": 15.0})
    lo, hi = np.asarray(s.params["channel_lo"]), np.asarray(s.params["channel_hi"])
    hits = 0
    for _ in range(8):
        s.step(25)
        p = s.positions.astype(np.float64)
        assert np.all((p >= lo) & (p <= hi))
        d = wt.signed_distance(s.info["airfoil"], p)
        assert d.min() > 0.0
        hits += int((d < s.radius).sum())
    assert hits > 0 and s.state()["bad"] == 0
    assert np.array_equal(np.sort(s.field("id")), np.arange(2500))


@pytest.mark.parametrize("factor", [1.7, 4.0, 0.0])
def test_larger_grid_cells_find_the_same_contacts_and_forces(factor):
    """grid.cell larger than a contact diameter: fewer cells, more candidates each; the same
    contact set (and the float64 count), the same forces to rounding (another summation order)."""
    a = Simulation.from_scene(load_scene("wind-tunnel"), backend="serial", particles=3000, neighbors="grid",
                              overrides={"inflow.speed": 1.0, "inflow.speed_ratio": 1.0, "gas.solid_fraction": 0.3,
                                         "grid.cell": 1e-9})  # cells of one contact diameter (the smallest)
    cell = factor * 2.0 * a.radius  # 0: the automatic size, about one cell per particle
    b = Simulation.from_scene(load_scene("wind-tunnel"), backend="serial", particles=3000, neighbors="grid",
                              overrides={"inflow.speed": 1.0, "inflow.speed_ratio": 1.0, "gas.solid_fraction": 0.3,
                                         "grid.cell": cell})
    assert b.radius == a.radius
    checked = 0
    for _ in range(2):
        a.step(40)
        ia = np.argsort(a.field("id"))
        b.set_particles(a.positions[ia], a.velocities[ia])
        a.evaluate()
        b.evaluate()
        ia, ib = np.argsort(a.field("id")), np.argsort(b.field("id"))
        ca, cb = a.field("contacts")[ia], b.field("contacts")[ib]
        assert np.array_equal(ca, cb)
        assert np.array_equal(ca, _reference_contacts(a, a.positions[ia].astype(np.float64)))
        fa, fb = a.field("force")[ia].astype(np.float64), b.field("force")[ib].astype(np.float64)
        assert np.abs(fa - fb).max() <= 1e-5 * np.abs(fa).max()
        checked += int((ca > 0).sum())
    assert checked > 200


def test_grid_cell_key_is_checked():
    with pytest.raises(Exception, match="grid.cell"):
        Simulation.from_scene(load_scene("wind-tunnel"), backend="serial", particles=500,
                              overrides={"grid.cell": -1.0})
