"""Several MPI ranks (``mpiexec -n 2``, launched by tests/mpi_launch.py; skipped without mpi4py or an
mpiexec): the polar sweep spread over ranks gives the one-process sweep bit for bit, bad input is
reported once and agreed on every rank, a failing or killed rank stops the others with one line
instead of a hang, and commands that do not run over ranks say so."""

from __future__ import annotations

import csv
import math
import textwrap

import pytest

from mpi_launch import corpuscle, launch, single

POLAR = ["polar", "wind-tunnel", "--aoa", "0,4,8", "--backend", "serial", "--particles", "1500",
         "--set", "inflow.speed=1.0", "--set", "wing.restitution=0.5", "--end-time", "0.1", "--no-plot", "--no-progress"]


def _rows(path):
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def test_polar_over_two_ranks_is_the_single_sweep(tmp_path):
    # every angle is an independent run on one rank (serial backend: bitwise), so the CSV that rank 0
    # gathers in angle order is the one-process CSV, byte for byte
    one = single([*POLAR, "--out", str(tmp_path / "one")], tmp_path)
    assert one.returncode == 0, one.stderr
    two = corpuscle(2, [*POLAR, "--out", str(tmp_path / "two")], tmp_path)
    assert two.returncode == 0, two.stdout + two.stderr
    assert two.stdout.count("wrote") == 1  # rank 0 alone writes and reports
    assert (tmp_path / "one.csv").read_bytes() == (tmp_path / "two.csv").read_bytes()
    rows = _rows(tmp_path / "two.csv")
    assert [float(r["angle_of_attack"]) for r in rows] == [0.0, 4.0, 8.0]
    assert all(math.isfinite(float(r["cl"])) and int(r["blocks"]) > 0 for r in rows)  # measured, not NaN
    assert len({r["cd"] for r in rows}) == 3


def test_bad_input_is_one_line_from_rank_zero(tmp_path):
    r = corpuscle(2, ["polar", "wind-tunnel", "--aoa", "0:x", "--no-plot"], tmp_path)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("corpuscle:")]
    assert len(lines) == 1 and "--aoa" in lines[0], r.stderr
    assert "Traceback" not in r.stderr


def test_commands_of_one_rank_refuse_several(tmp_path):
    r = corpuscle(2, ["bench", "dam-break-2d", "--backend", "serial"], tmp_path)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("corpuscle:")]
    assert len(lines) == 1 and "one rank" in lines[0] and "distributed.md" in lines[0], r.stderr
    assert not list(tmp_path.iterdir())  # nothing written by any rank


def test_info_under_mpiexec_prints_once(tmp_path):
    r = corpuscle(2, ["info"], tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.count("corpuscle ") == 1
    mpi = [ln for ln in r.stdout.splitlines() if ln.strip().startswith("MPI")]
    assert len(mpi) == 1 and "2 ranks" in mpi[0] and "mpi4py" in mpi[0], r.stdout


def _script(tmp_path, body: str):
    p = tmp_path / "job.py"
    p.write_text(textwrap.dedent(body))
    return p


@pytest.mark.parametrize("how", ["error", "signal"])
def test_a_failing_rank_stops_the_others(tmp_path, how):
    # rank 1 fails (an uncaught error, or SIGKILL) while rank 0 waits for it in a collective: the
    # job ends within the timeout, non-zero, with one corpuscle line naming rank 1 for the error
    fail = ("raise RuntimeError('boom on purpose')" if how == "error"
            else "os.kill(os.getpid(), signal.SIGKILL)")
    job = _script(tmp_path, f"""
        import os, signal, sys
        from corpuscle import _mpi
        comm = _mpi.world()
        _mpi.agree(comm, lambda: None)
        try:
            if comm.Get_rank() == 1:
                {fail}
            comm.barrier()
        except BaseException as exc:
            _mpi.abort(comm, f"{{type(exc).__name__}}: {{exc}}", 1)
    """)
    r = launch(2, [str(job)], tmp_path, timeout=60)
    assert r.returncode != 0
    if how == "error":
        lines = [ln for ln in r.stderr.splitlines() if ln.startswith("corpuscle:")]
        assert lines == ["corpuscle: rank 1 of 2: RuntimeError: boom on purpose"], r.stderr


def test_input_bad_on_one_rank_only_is_agreed(tmp_path):
    # a check that fails on rank 1 only: every rank raises, rank 0 reports it naming rank 1
    job = _script(tmp_path, """
        import sys
        from corpuscle import _mpi
        comm = _mpi.world()
        def check():
            if comm.Get_rank() == 1:
                raise ValueError("scene.toml: cannot read it here")
        try:
            _mpi.agree(comm, check)
        except _mpi.RankInputError as exc:
            if not exc.quiet:
                print(f"corpuscle: error: {exc}", file=sys.stderr)
            sys.exit(exc.exit_code)
    """)
    r = launch(2, [str(job)], tmp_path, timeout=60)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("corpuscle:")]
    assert lines == ["corpuscle: error: rank 1: scene.toml: cannot read it here"], r.stderr


def test_plain_run_never_loads_mpi(tmp_path):
    # without a launcher's environment nothing imports mpi4py: a plain install runs as before
    import subprocess
    import sys

    from mpi_launch import env

    plain = {k: v for k, v in env().items() if not k.startswith(("OMPI_", "PMI_", "PMIX_"))}
    r = subprocess.run([sys.executable, "-c", "import sys; from corpuscle import _mpi; from corpuscle import cli; "
                        "assert _mpi.world() is None and _mpi.launched_size() == 1; "
                        "assert 'mpi4py' not in sys.modules, 'mpi4py imported'"],
                       cwd=tmp_path, env=plain, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr


BATCH_JOB = """
import sys
import numpy as np
from corpuscle import Batch, _mpi
comm = _mpi.world()
backend = sys.argv[2] if len(sys.argv) > 2 else "serial"
b = Batch.from_scene("magic8ball", n=5, backend=backend, particles=[300, 240, 300, 270, 300], seed=[4, 5, 6, 7, 8],
                     neighbors="lists", settle=0.02, randomize=False, shake=[], comm=comm)
lo = b.scene_offset
assert b.n_total == 5 and b.n_scenes == (2 if comm is not None and comm.Get_rank() == 0 else 3 if comm else 5)
b.reset()
b.set_control(np.tile(np.array([0.5, 0.0, 0.0, 0.0, 0.0, 0.01]) * (1 + np.arange(lo, lo + b.n_scenes))[:, None], 1))
b.advance(0.02)
obs = b.gather_observations()
if obs is not None:
    np.savez(sys.argv[1], **obs)
"""


def test_batch_over_two_ranks_is_the_one_process_batch(tmp_path):
    # five 8-balls of different sizes, two on rank 0 and three on rank 1, settled, reset, steered and
    # advanced: the gathered observations are the one-process batch's bit for bit (the CPU runs each
    # scene of a batch as its single run)
    job = _script(tmp_path, BATCH_JOB)
    import subprocess
    import sys

    from mpi_launch import env

    plain = {k: v for k, v in env().items() if not k.startswith(("OMPI_", "PMI_", "PMIX_"))}
    one = subprocess.run([sys.executable, str(job), str(tmp_path / "one.npz")], cwd=tmp_path, env=plain,
                         capture_output=True, text=True, timeout=120)
    assert one.returncode == 0, one.stderr
    two = launch(2, [str(job), str(tmp_path / "two.npz")], tmp_path, timeout=120)
    assert two.returncode == 0, two.stdout + two.stderr
    import numpy as np

    a, b = np.load(tmp_path / "one.npz"), np.load(tmp_path / "two.npz")
    assert sorted(a.files) == sorted(b.files) and "die_position" in a.files
    for k in a.files:
        assert a[k].shape[0] == 5 and np.array_equal(a[k], b[k]), k
    assert np.allclose(a["time"], 0.02) and len(np.unique(a["die_position"][:, 0])) == 5


ENV_JOB = """
import sys
import numpy as np
from corpuscle import _mpi
from corpuscle.envs import Magic8BallVectorEnv
comm = _mpi.world()
env = Magic8BallVectorEnv(num_envs=4, target_face=[1, 2, 3, 4], backend="serial", particles=260, settle=0.02,
                          randomize=False, episode_time=0.1, control_period=0.05, comm=comm)
lo, n = env.batch.scene_offset, env.num_envs
assert env.num_envs_total == 4 and env.action_space.shape == (n, 6)
assert env.target_face.tolist() == [1, 2, 3, 4][lo:lo + n]
obs, _ = env.reset(seed=3)
rows = []
for k in range(3):  # through an episode's end and the autoreset
    a = np.sin(np.arange(lo * 6, (lo + n) * 6, dtype=np.float32).reshape(n, 6) + k)
    obs, rew, term, trunc, _ = env.step(a)
    rows.append(np.concatenate([obs.reshape(n, -1), rew[:, None], term[:, None], trunc[:, None]], axis=1))
mine = np.stack(rows, axis=1)
parts = [mine] if comm is None else comm.gather(mine, root=0)
if parts is not None:
    np.save(sys.argv[1], np.concatenate(parts))
"""


def test_vector_env_over_two_ranks_is_the_one_process_env(tmp_path):
    # the Gymnasium vector env of four 8-balls, two a rank: observations, rewards and episode ends
    # of every env, with actions that differ per env, are the one-process env's bit for bit
    pytest.importorskip("gymnasium")
    job = _script(tmp_path, ENV_JOB)
    import subprocess
    import sys

    import numpy as np

    from mpi_launch import env

    plain = {k: v for k, v in env().items() if not k.startswith(("OMPI_", "PMI_", "PMIX_"))}
    one = subprocess.run([sys.executable, str(job), str(tmp_path / "one.npy")], cwd=tmp_path, env=plain,
                         capture_output=True, text=True, timeout=120)
    assert one.returncode == 0, one.stderr
    two = launch(2, [str(job), str(tmp_path / "two.npy")], tmp_path, timeout=120)
    assert two.returncode == 0, two.stdout + two.stderr
    a, b = np.load(tmp_path / "one.npy"), np.load(tmp_path / "two.npy")
    assert a.shape[0] == 4 and a.shape == b.shape
    assert np.array_equal(a, b)
    assert a[:, :, -2].any() or a[:, :, -1].any()  # an episode ended within the three steps


def test_simulation_comm_of_one_rank_runs_and_of_two_splits_or_is_refused(tmp_path):
    job = _script(tmp_path, """
        import sys
        from corpuscle import Simulation, _mpi
        comm = _mpi.world()
        one = comm.Split(comm.Get_rank(), 0)  # a communicator of this rank alone
        sim = Simulation.from_scene("dam-break-2d", backend="serial", particles=400, comm=one)
        assert sim.step(3) == 3
        two = Simulation.from_scene("dam-break-2d", backend="serial", particles=400, comm=comm)  # split
        assert two.step(3) == 3 and two.core.size == 2
        try:
            Simulation.from_scene("magic8ball", backend="serial", particles=400, comm=comm)
        except ValueError as exc:
            assert "not split over ranks" in str(exc), exc
        else:
            sys.exit("no error")
    """)
    r = launch(2, [str(job)], tmp_path, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr


@pytest.mark.gpu
def test_batch_over_two_ranks_sharing_one_gpu(tmp_path):
    # two ranks on the one GPU (the node-local rank picks device rank % GPUs: both device 0 on a
    # machine of one) against one process: each scene's run does not depend on the rank holding it.
    # A CUDA batch of another composition launches other grids, so this compares as the CUDA-vs-CPU
    # batch test does (tests/scenes/magic8ball/test_batch_api.py): times exactly, the die within 2e-3 m
    from corpuscle.simulation import cuda_status

    ok, why = cuda_status()
    if not ok:
        pytest.skip(f"no usable CUDA backend: {why}")
    job = _script(tmp_path, BATCH_JOB)
    import subprocess
    import sys

    import numpy as np

    from mpi_launch import env

    plain = {k: v for k, v in env().items() if not k.startswith(("OMPI_", "PMI_", "PMIX_"))}
    one = subprocess.run([sys.executable, str(job), str(tmp_path / "one.npz"), "cuda"], cwd=tmp_path, env=plain,
                         capture_output=True, text=True, timeout=300)
    assert one.returncode == 0, one.stderr
    two = launch(2, [str(job), str(tmp_path / "two.npz"), "cuda"], tmp_path, timeout=300)
    assert two.returncode == 0, two.stdout + two.stderr
    a, b = np.load(tmp_path / "one.npz"), np.load(tmp_path / "two.npz")
    assert a["time"].tolist() == b["time"].tolist()
    for k in ("die_position", "die_velocity"):
        assert np.allclose(a[k], b[k], atol=2e-3), k


def test_a_launcher_of_several_ranks_whose_mpi_world_is_one_runs_as_one_process(tmp_path):
    # a launcher's variables say 2 ranks but MPI's world (a singleton: Open MPI ignores PMI_*) has
    # one: the whole sweep runs here, as without MPI, instead of half of it
    import subprocess
    import sys

    from mpi_launch import env, mpiexec

    if not mpiexec()[1]:
        pytest.skip("an MPI other than Open MPI may read PMI_* and wait for a launcher")

    e = {k: v for k, v in env().items() if not k.startswith(("OMPI_", "PMI_", "PMIX_"))}
    e.update(PMI_SIZE="2", PMI_RANK="0")
    r = subprocess.run([sys.executable, "-m", "corpuscle", *POLAR, "--out", str(tmp_path / "s")], cwd=tmp_path, env=e,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert len(_rows(tmp_path / "s.csv")) == 3
