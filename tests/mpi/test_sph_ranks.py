"""One SPH box scene split over MPI ranks (docs/distributed.md; launched by tests/mpi_launch.py,
skipped without mpi4py or an mpiexec): R = 1, 2, 3 ranks give the one-process run bit for bit,
through a dam break's impact, with the particles crossing the ranks' slabs many times.

Why bitwise and not within a tolerance: with `sph.order_by_id` (which a run over ranks forces on)
the sort breaks ties within a cell by the particle's id, so every particle's neighbours are
walked in the same order whichever rank holds it and wherever it sat before; every rank
combines the ranks' step sums in rank order with the struct's own combine (the dt is a max
over the ranks: the same value), and the halo copies carry their owners' exact values. So the
one-process run with the key is the reference, compared with ==. The only value that is not
bitwise is the kinetic-energy sum of the diagnostics (a float sum over particles, grouped by
rank): it is compared within float32 rounding of a sum of that many terms, n eps |KE|.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from mpi_launch import corpuscle, env, launch, single

pytest.importorskip("mpi4py", reason="mpi4py is not installed (pip install '.[mpi]')")

RUN = ["run", "dam-break-2d", "--backend", "cpu", "--particles", "300", "--no-progress"]

JOB = """
import sys
import numpy as np
from corpuscle import Simulation, _mpi
comm = _mpi.world()
scene, particles, steps, index = sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
extra = {"sph.order_by_id": True}
if len(sys.argv) > 6 and sys.argv[6].startswith("rebalance="):  # load balancing at this threshold
    extra["run.rebalance"] = float(sys.argv[6].split("=")[1])
elif len(sys.argv) > 6:  # the distributed path on one rank (MPI's COMM_SELF, no launcher)
    from mpi4py import MPI
    comm = MPI.COMM_SELF
    from corpuscle._ranks_sph import ranked_simulation
    from corpuscle.scene import load_scene
    sim = ranked_simulation(load_scene(scene).with_overrides({"fluid.particles": particles, "sph.order_by_id": True}),
                            "cpu", comm, neighbors=index)
if "sim" not in dir():
    sim = Simulation.from_scene(scene, backend="cpu", particles=particles, neighbors=index, comm=comm,
                                overrides=extra)
sim.set_end_time(1e9)
xs, cuts = [], getattr(sim.core, "cuts", np.zeros(0))
for k in range(steps // 10):
    sim.step(10)
    xs.append(np.asarray(sim.field("position"))[np.argsort(sim.field("id"))][:, 0])
st = sim.state()
out = dict(position=sim.field("position"), velocity=sim.field("velocity"), density=sim.field("density"),
           id=sim.field("id"), wall_density=sim.field("wall_density"), wall_id=sim.field("wall_id"),
           time=st["time"], step=st["step"], rebuilds=st["rebuilds"], ke=st["kinetic_energy"],
           vmax=st["vmax"], rho_max=st["rho_max"], nbrs=st["mean_neighbors"], x=np.array(xs), cuts=np.asarray(cuts),
           rebalances=getattr(sim.core, "rebalances", 0))
if comm is None or comm.Get_rank() == 0:
    np.savez(sys.argv[1], **out)
"""


def _job(tmp_path):
    p = tmp_path / "job.py"
    p.write_text(textwrap.dedent(JOB))
    return p


def _plain_env():
    return {k: v for k, v in env().items() if not k.startswith(("OMPI_", "PMI_", "PMIX_"))}


def _one_process(tmp_path, args, name="one.npz"):
    r = subprocess.run([sys.executable, str(_job(tmp_path)), str(tmp_path / name), *args], cwd=tmp_path,
                       env=_plain_env(), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return np.load(tmp_path / name)


def _same(a, b):
    by_id = np.argsort(a["id"]), np.argsort(b["id"])
    for k in ("position", "velocity", "density"):
        assert np.array_equal(a[k][by_id[0]], b[k][by_id[1]]), k
    w = np.argsort(a["wall_id"]), np.argsort(b["wall_id"])
    assert np.array_equal(a["wall_density"][w[0]], b["wall_density"][w[1]])
    for k in ("time", "step", "rebuilds", "vmax", "rho_max", "nbrs"):
        assert a[k] == b[k], k
    n = len(a["id"])
    assert abs(float(a["ke"]) - float(b["ke"])) <= n * np.finfo(np.float32).eps * abs(float(a["ke"])) + 1e-30


@pytest.mark.parametrize("ranks", [2, 3, pytest.param(4, marks=pytest.mark.slow)])
def test_dam_break_2d_over_ranks_is_the_one_process_run(tmp_path, ranks):
    # the lists index, through the impact on the far wall (T = 3.5; 2,000 steps at 300 particles),
    # the fluid crossing the slab cuts many times: bitwise. Three ranks rebalance (run.rebalance,
    # a threshold any measured imbalance passes: the cuts move as the fluid runs down the tank)
    args = ["dam-break-2d", "300", "1500", "lists"]
    one = _one_process(tmp_path, args)
    rebalance = ["rebalance=1.0001"] if ranks == 3 else []
    r = launch(ranks, [str(_job(tmp_path)), str(tmp_path / "many.npz"), *args, *rebalance], tmp_path, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    many = np.load(tmp_path / "many.npz")
    _same(one, many)
    # the particles crossed the ranks' boundaries many times (x sampled every 10 steps, by id)
    side = np.searchsorted(many["cuts"], many["x"], side="right")
    crossings = int(np.count_nonzero(np.diff(side, axis=0)))
    assert len(many["cuts"]) == ranks - 1 and crossings > 50, crossings
    assert int(many["rebalances"]) >= (1 if rebalance else 0)


def test_distributed_path_on_one_rank_and_the_grid_index(tmp_path):
    # the distributed path with one rank (halo and migration code with nothing to send), and the
    # grid index over two ranks (a migration every step): the one-process run bit for bit
    args = ["dam-break-2d", "300", "300", "grid"]
    one = _one_process(tmp_path, args)
    _same(one, _one_process(tmp_path, [*args, "self"], "self.npz"))
    r = launch(2, [str(_job(tmp_path)), str(tmp_path / "two.npz"), *args], tmp_path, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    _same(one, np.load(tmp_path / "two.npz"))


@pytest.mark.slow  # (30 s on a loaded 2-core machine)
def test_fluid_box_3d_over_two_ranks(tmp_path):
    args = ["fluid-box", "1000", "200", "lists"]
    one = _one_process(tmp_path, args)
    r = launch(2, [str(_job(tmp_path)), str(tmp_path / "two.npz"), *args], tmp_path, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    _same(one, np.load(tmp_path / "two.npz"))


def _frames(path):
    from corpuscle import io

    run = io.open(path)
    out = []
    for i in range(len(run)):
        f = run[i]
        d = {n: np.asarray(f[n]) for n in f.fields}
        o, w = np.argsort(d["id"]), np.argsort(d["wall_id"]) if "wall_id" in d else None
        for n in list(d):
            if n in ("position", "density", "pressure", "velocity", "velocity_prev", "density_prev", "id"):
                d[n] = d[n][o]
            elif n.startswith("wall_") and w is not None:
                d[n] = d[n][w]
        d.pop("state.sums_ke", None)  # (a float sum over particles grouped by rank)
        out.append((run.kinds[i], int(f.step), d))
    run.close()
    return out


def _same_frames(a, b):
    fa, fb = _frames(a), _frames(b)
    assert [(k, s) for k, s, _ in fa] == [(k, s) for k, s, _ in fb]
    for (_, step, x), (_, _, y) in zip(fa, fb):
        assert sorted(x) == sorted(y), step
        for n in x:
            assert np.array_equal(x[n], y[n], equal_nan=True), (step, n)


def test_run_over_ranks_writes_the_one_process_stream_and_resumes_on_any_count(tmp_path):
    common = [*RUN, "--steps", "300", "--every", "50", "--checkpoint-every", "100"]
    one = single([*common, "--set", "sph.order_by_id=true", "--out", str(tmp_path / "one.cps"), "--json"], tmp_path)
    assert one.returncode == 0, one.stderr
    two = corpuscle(2, [*common, "--out", str(tmp_path / "two.cps"), "--json"], tmp_path)
    assert two.returncode == 0, two.stdout + two.stderr
    summary = json.loads(two.stdout)  # one JSON object: rank 0 alone prints
    assert summary["ranks"] == 2 and summary["imbalance"] >= 1.0 and summary["steps"] == 300
    assert json.loads(one.stdout)["ranks"] == 1
    _same_frames(tmp_path / "one.cps", tmp_path / "two.cps")
    # resume the two-rank run on three ranks and on one (no launcher) and the one-process run on one
    more = ["--steps", "100", "--no-progress", "--json"]
    a = single(["run", "--resume", str(tmp_path / "one.cps"), *more, "--out", str(tmp_path / "a.cps")], tmp_path)
    b = corpuscle(3, ["run", "--resume", str(tmp_path / "two.cps"), *more, "--out", str(tmp_path / "b.cps")], tmp_path)
    c = single(["run", "--resume", str(tmp_path / "two.cps"), *more, "--out", str(tmp_path / "c.cps")], tmp_path)
    for r in (a, b, c):
        assert r.returncode == 0, r.stdout + r.stderr
    _same_frames(tmp_path / "a.cps", tmp_path / "b.cps")
    _same_frames(tmp_path / "a.cps", tmp_path / "c.cps")


def test_kinds_not_split_refuse_several_ranks(tmp_path):
    r = corpuscle(2, ["run", "wind-tunnel", "--backend", "serial", "--steps", "5"], tmp_path)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("corpuscle:")]
    assert len(lines) == 1 and "wind-tunnel" in lines[0] and "ranks" in lines[0], r.stderr
    assert "Traceback" not in r.stderr
    assert not list(tmp_path.glob("*.cps"))


def test_scene_file_missing_on_one_rank(tmp_path):
    # rank 1 runs in a folder without the scene file: every rank stops, rank 0 says which rank
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "box.toml").write_text('[scene]\nkind = "dam-break-2d"\n[fluid]\nparticles = 300\n')
    job = tmp_path / "cd.py"
    job.write_text(textwrap.dedent(f"""
        import os, sys
        from corpuscle import _mpi
        from corpuscle.cli import main
        os.chdir({str(tmp_path)!r} + ("/a" if _mpi.world().Get_rank() == 0 else "/b"))
        sys.exit(main(["run", "box.toml", "--backend", "cpu", "--steps", "5", "--no-progress"]))
    """))
    r = launch(2, [str(job)], tmp_path, timeout=120)
    assert r.returncode == 2, r.stdout + r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("corpuscle:")]
    assert len(lines) == 1 and "rank 1" in lines[0] and "box.toml" in lines[0], r.stderr
    assert not list(tmp_path.rglob("*.cps"))


def test_a_rank_killed_mid_run_ends_the_job(tmp_path):
    # rank 1 is killed by SIGKILL after some steps, while rank 0 waits for it in the step's
    # exchanges: the launcher ends the job (no hang), non-zero
    job = tmp_path / "kill.py"
    job.write_text(textwrap.dedent("""
        import os, signal
        from corpuscle import Simulation, _mpi
        comm = _mpi.world()
        sim = Simulation.from_scene("dam-break-2d", backend="cpu", particles=300, comm=comm)
        sim.set_end_time(1e9)
        for k in range(100):
            sim.step(5)
            if k == 4 and comm.Get_rank() == 1:
                os.kill(os.getpid(), signal.SIGKILL)
    """))
    r = launch(2, [str(job)], tmp_path, timeout=90)
    assert r.returncode != 0


def test_bad_input_under_ranks_is_one_line(tmp_path):
    r = corpuscle(2, [*RUN, "--set", "sph.skin=-1", "--steps", "5"], tmp_path)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("corpuscle:")]
    assert len(lines) == 1 and "sph.skin" in lines[0], r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.gpu
def test_two_ranks_sharing_one_gpu_are_one_rank(tmp_path):
    # on the device: 2 ranks on the one GPU (both device 0) against the same run on one rank of
    # the distributed path: the CUDA halo packing, staging through host memory and migration.
    # The pair pass is the same kernel over the same neighbours in the same order (id tie-break),
    # so the runs agree bit for bit
    from corpuscle.simulation import cuda_status

    ok, why = cuda_status()
    if not ok:
        pytest.skip(f"no usable CUDA backend: {why}")
    job = tmp_path / "gpu.py"
    job.write_text(JOB.replace('"cpu"', '"cuda"'))
    args = ["dam-break-2d", "2000", "400", "lists"]
    one = subprocess.run([sys.executable, str(job), str(tmp_path / "one.npz"), *args, "self"], cwd=tmp_path,
                         env=_plain_env(), capture_output=True, text=True, timeout=300)
    assert one.returncode == 0, one.stderr
    r = launch(2, [str(job), str(tmp_path / "two.npz"), *args], tmp_path, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    _same(np.load(tmp_path / "one.npz"), np.load(tmp_path / "two.npz"))
