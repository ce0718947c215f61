"""render, plot and export through the real ``corpuscle`` console script: bad input is one
line and exit code 2 with nothing written, a truncated run is one warning line, and a run
that fails part-way leaves no partial output behind."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest

import viz_runs
from cli_script import assert_one_line_error, corpuscle, corrupt_frame, cut_last_frame, listing


def _nested_header_run(path):
    """A stream whose header JSON is 100 000 arrays deep (a RecursionError for a naive reader)."""
    import struct
    import zlib

    body = b"[" * 100_000 + b"]" * 100_000
    first = -(-(32 + len(body)) // 64) * 64
    fixed = struct.pack("<8sIIQI", b"\x89CPS\r\n\x1a\n", 1, 0, len(body), 0)
    pad = bytes(first - 32 - len(body))
    path.write_bytes(fixed + struct.pack("<I", zlib.crc32(pad, zlib.crc32(body, zlib.crc32(fixed)))) + body + pad)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Runs and bad files shared by the bad-input cases (none of them writes into this folder)."""
    d = tmp_path_factory.mktemp("runs")
    viz_runs.write_magic8ball(d / "m8.cps", frames=3)
    viz_runs.write_tunnel(d / "wt.cps", frames=2)
    viz_runs.write_magic8ball(d / "bad.cps", frames=3)
    corrupt_frame(d / "bad.cps", 1)
    (d / "notarun.cps").write_bytes(b"hello, not a frame stream\n" * 10)
    (d / "notes.txt").write_text("a text file\n")
    _nested_header_run(d / "deep.cps")
    (d / "cut.cps").write_bytes((d / "m8.cps").read_bytes()[:20])
    (d / "afile").write_text("x")
    (d / "folder.cps").mkdir()
    os.mkfifo(d / "pipe.cps")
    return d


BAD_INPUT = [
    # render: options
    (["render", "{d}/m8.cps", "-o", "{o}/x.png", "--color", "vorticity"], "unknown --color field 'vorticity'"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.png", "--color", "nosuchfield"], "unknown --color field 'nosuchfield'"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.png", "--range", "5:1"], "lo < hi"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.png", "--range", "abc"], "--range must be lo:hi"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.png", "--range", "0:nan"], "finite"),
    (["render", "{d}/m8.cps", "-o", "{o}/no/such/dir/x.mp4"], "does not exist"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.avi"], ".mp4, .gif or .png"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.png", "--frame", "99"], "out of range"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.mp4", "--frames", "5:2"], "--frames '5:2' selects no frames"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.mp4", "--frames", "0:3:0"], "step"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.png", "--size", "0x0"], "--size must be between 16 and 8192"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.png", "--size", "12x9000"], "--size"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.png", "--size", "big"], "--size must be WxH"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.mp4", "--size", "161x120"], "even"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.png", "--camera", "30"], "--camera"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.png", "--camera", "30,95"], "elevation"),
    (["render", "{d}/wt.cps", "-o", "{o}/x.png", "--camera", "30,20"], "3-D"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.mp4", "--fps", "0"], "--fps"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.mp4", "--frame", "1"], "--frame picks the frame of a .png"),
    # render: argparse's own errors (one line once corpuscle.cli's parser prints them so)
    (["render", "{d}/m8.cps", "-o", "{o}/x.png", "--ramp", "rainbow"], "invalid choice: 'rainbow'"),
    (["render", "{d}/m8.cps"], "required"),
    (["render", "{d}/m8.cps", "-o", "{o}/x.png", "--bogus"], "--bogus"),
    # render: runs that cannot be read
    (["render", "{d}/missing.cps", "-o", "{o}/x.png"], "run file not found"),
    (["render", "{d}/notarun.cps", "-o", "{o}/x.png"], "not a corpuscle frame stream"),
    (["render", "{d}/notes.txt", "-o", "{o}/x.png"], "not a corpuscle frame stream"),
    (["render", "{d}/deep.cps", "-o", "{o}/x.png"], "nested 100000 deep"),
    (["render", "{d}/cut.cps", "-o", "{o}/x.png"], "file header is truncated"),
    (["render", "{d}/folder.cps", "-o", "{o}/x.png"], "directory"),
    (["render", "{d}/pipe.cps", "-o", "{o}/x.png"], "special file"),
    (["render", "{d}/bad.cps", "-o", "{o}/x.mp4", "--range", "0:1"], "frame 1 is corrupted (checksum mismatch)"),
    (["render", "{d}/bad.cps", "-o", "{o}/frames"], "frame 1 is corrupted"),
    # plot
    (["plot", "{d}/missing.cps", "-o", "{o}/p.png"], "run file not found"),
    (["plot", "{d}/m8.cps", "-o", "{o}/p.txt"], ".png"),
    (["plot", "{d}/m8.cps", "-o", "{o}/nope/p.png"], "does not exist"),
    (["plot", "{d}/m8.cps", "-o", "{o}/p.png", "--series", "vorticity"], "unknown series 'vorticity'"),
    (["plot", "{d}/m8.cps", "-o", "{o}/p.png", "--dpi", "x"], "--dpi"),
    (["plot", "{d}/m8.cps", "-o", "{o}/p.png", "--dpi", "5"], "--dpi"),
    (["plot", "{d}/notarun.cps", "-o", "{o}/p.png"], "not a corpuscle frame stream"),
    (["plot", "{d}/deep.cps", "-o", "{o}/p.png"], "nested 100000 deep"),
    (["plot", "{d}/folder.cps", "-o", "{o}/p.png"], "directory"),
    (["plot", "{d}/m8.cps"], "required"),
    # export
    (["export", "{d}/missing.cps", "{o}/out"], "run file not found"),
    (["export", "{d}/m8.cps", "{o}/out", "--format", "stl"], "unknown --format 'stl'"),
    (["export", "{d}/m8.cps", "{d}/afile"], "not a directory"),
    (["export", "{d}/m8.cps", "{o}/out", "--frames", "7:"], "selects no frames"),
    (["export", "{d}/m8.cps", "{o}/out", "--frames", "5:2"], "--frames '5:2' selects no frames"),
    (["export", "{d}/notarun.cps", "{o}/out"], "not a corpuscle frame stream"),
    (["export", "{d}/deep.cps", "{o}/out"], "nested 100000 deep"),
    (["export", "{d}/bad.cps", "{o}/out"], "frame 1 is corrupted"),
    (["export", "{d}/bad.cps", "{o}/out", "--format", "vtkhdf"], "frame 1 is corrupted"),
    (["export", "{d}/m8.cps"], "required"),
]


@pytest.mark.parametrize("argv, words", BAD_INPUT, ids=[" ".join(a).replace("{d}/", "").replace("{o}/", "") for a, _ in BAD_INPUT])
def test_bad_input_is_one_line_exit_2_and_writes_nothing(runs, tmp_path, argv, words):
    before = listing(runs)
    proc = corpuscle(*[a.format(d=runs, o=tmp_path) for a in argv], cwd=tmp_path)
    assert_one_line_error(proc, words)
    # nothing written: not the output, not a temporary, not a folder for it
    assert listing(tmp_path) == set() and listing(runs) == before


def test_an_unreadable_run_is_one_line(runs, tmp_path):
    if os.geteuid() == 0:
        pytest.skip("root reads a file whatever its mode")
    locked = tmp_path / "locked.cps"
    locked.write_bytes((runs / "m8.cps").read_bytes())
    locked.chmod(0)
    try:
        for argv in (["render", locked, "-o", tmp_path / "x.png"], ["plot", locked, "-o", tmp_path / "p.png"],
                     ["export", locked, tmp_path / "out"]):
            assert_one_line_error(corpuscle(*argv, cwd=tmp_path), "Permission denied")
    finally:
        locked.chmod(stat.S_IRUSR | stat.S_IWUSR)


# ---- a truncated run: one warning line -----------------------------------------------------------


def test_truncated_run_warns_in_one_clean_line(tmp_path):
    run = tmp_path / "m8.cps"
    viz_runs.write_magic8ball(run, frames=3)
    kept = cut_last_frame(run, keep_bytes=100)
    warning = f"corpuscle: warning: {run}: file ends inside frame 2 ({kept} trailing bytes ignored); read 2 whole frames"
    for argv, made in ((["render", run, "-o", tmp_path / "m8.png", "-q"], "m8.png"),
                       (["plot", run, "-o", tmp_path / "p.png"], "p.png"),
                       (["export", run, tmp_path / "out", "-q"], "out/m8.pvd")):
        proc = corpuscle(*argv, cwd=tmp_path)
        # the whole frames are rendered/plotted/exported; stderr is exactly the warning line
        assert proc.returncode == 0, proc.stderr
        assert proc.stderr.splitlines() == [warning]
        assert (tmp_path / made).is_file()


def test_the_python_api_keeps_a_normal_warning(tmp_path):
    from corpuscle.io import TruncatedRunWarning
    from corpuscle.render import render_run

    run = tmp_path / "m8.cps"
    viz_runs.write_magic8ball(run, frames=3)
    cut_last_frame(run)
    with pytest.warns(TruncatedRunWarning, match="read 2 whole frames"):
        res = render_run(run, tmp_path / "m8.png", size=(64, 48), progress=False)
    assert res.frames == 1


# ---- a run that fails part-way: no partial output ------------------------------------------------


@pytest.mark.parametrize("out", ["x.mp4", "x.gif", "frames"])
def test_render_failing_part_way_leaves_nothing(tmp_path, out):
    run = tmp_path / "runs" / "m8.cps"
    run.parent.mkdir()
    viz_runs.write_magic8ball(run, frames=20, n=200)
    corrupt_frame(run, 8)  # frames 0-7 render, frame 8 (not one of the 12 sampled for the range) raises
    work = tmp_path / "work"
    work.mkdir()
    proc = corpuscle("render", run, "-o", work / out, "--size", "64x48", cwd=work)
    assert_one_line_error(proc, "frame 8 is corrupted (checksum mismatch)")
    assert listing(work) == set()


def test_failed_render_keeps_an_earlier_complete_output(tmp_path):
    run = tmp_path / "m8.cps"
    viz_runs.write_magic8ball(run, frames=20, n=200)
    assert corpuscle("render", run, "-o", tmp_path / "x.gif", "--size", "64x48", "-q").returncode == 0
    good = (tmp_path / "x.gif").read_bytes()
    corrupt_frame(run, 8)
    assert_one_line_error(corpuscle("render", run, "-o", tmp_path / "x.gif", "--size", "64x48"),
                          "frame 8 is corrupted")
    # the old GIF is untouched and no temporary is left next to it
    assert (tmp_path / "x.gif").read_bytes() == good
    assert listing(tmp_path) == {"m8.cps", "x.gif"}


@pytest.mark.parametrize("fmt", ["vtk", "vtkhdf"])
def test_export_failing_part_way_leaves_nothing(tmp_path, fmt):
    run = tmp_path / "m8.cps"
    viz_runs.write_magic8ball(run, frames=5)
    corrupt_frame(run, 3)
    proc = corpuscle("export", run, tmp_path / "out", "--format", fmt, "-q")
    assert_one_line_error(proc, "frame 3 is corrupted")
    # not one .vtu of the frames before, no .pvd, and not the folder the export created
    assert listing(tmp_path) == {"m8.cps"}


# ---- what works ------------------------------------------------------------------------------------


def test_render_writes_a_video_of_the_selected_frames(tmp_path):
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
    viz_runs.write_tunnel(tmp_path / "wt.cps", frames=3)
    proc = corpuscle("render", tmp_path / "wt.cps", "-o", tmp_path / "wt.mp4", "--size", "128x96", "--fps", "12")
    assert proc.returncode == 0 and proc.stderr == ""
    assert proc.stdout.startswith(f"wrote {tmp_path / 'wt.mp4'} (3 frames, 128x96")
    gen = imageio_ffmpeg.read_frames(str(tmp_path / "wt.mp4"))
    meta = next(gen)
    frames = [np.frombuffer(b, np.uint8) for b in gen]
    assert meta["size"] == (128, 96) and meta["fps"] == pytest.approx(12) and len(frames) == 3
    assert listing(tmp_path) == {"wt.cps", "wt.mp4"}


def test_plot_writes_a_png_of_the_figure(tmp_path):
    from PIL import Image

    viz_runs.write_tunnel(tmp_path / "wt.cps", frames=2)
    proc = corpuscle("plot", tmp_path / "wt.cps", "-o", tmp_path / "p.png", "--dpi", "50")
    assert proc.returncode == 0 and proc.stderr == "" and proc.stdout == f"wrote {tmp_path / 'p.png'}\n"
    with Image.open(tmp_path / "p.png") as im:
        # 11 inches wide at 50 dpi; some pixels are the lines' colours, not all white
        assert im.format == "PNG" and im.size[0] == 550
        assert len(np.unique(np.asarray(im.convert("RGB")).reshape(-1, 3), axis=0)) > 10
    assert listing(tmp_path) == {"wt.cps", "p.png"}


# ---- a header whose scene description is malformed -----------------------------------------------

MALFORMED_HEADERS = [
    ({"dim": 3, "container": {"type": "sphere", "radius": "big"}}, "container.radius must be a finite number"),
    ({"dim": 3, "container": {"type": "box", "min": [0, 0, 0], "max": 1}}, "container.max must be a list"),
    ({"dim": 3, "bodies": 5}, "bodies must be a list"),
    ({"dim": 3, "bodies": [{"name": "die", "shape": "box", "half_extents": [0.1, None, 0.1]}]}, "half_extents"),
    ({"dim": 3, "bodies": ["die"]}, "bodies[0] must be an object"),
    ({"dim": 2, "obstacles": [{"points": [[0, "a"], [1, 0], [1, 1]]}]}, "obstacles[0].points"),
    ({"dim": "three"}, "dim must be 1, 2 or 3"),
    ({"dim": 3, "particle_radius": [1]}, "particle_radius"),
]


@pytest.mark.parametrize("header, words", MALFORMED_HEADERS, ids=[w for _, w in MALFORMED_HEADERS])
def test_a_malformed_scene_header_is_one_line_for_render_and_export_and_plot_still_works(tmp_path, header, words):
    from corpuscle.io import FrameWriter

    run = tmp_path / "h.cps"
    dim = 2 if header.get("dim") == 2 else 3
    with FrameWriter(run, header) as w:
        w.write_frame(0, 0.0, 1e-3, {"position": np.zeros((4, dim), np.float32)}, diagnostics={"e": 1.0})
    out = tmp_path / "out"
    out.mkdir()
    proc = corpuscle("render", run, "-o", out / "x.png", "--size", "64x48")
    assert_one_line_error(proc, words)
    assert proc.stderr.startswith("corpuscle: error: run header: ")
    assert_one_line_error(corpuscle("export", run, out / "vtk", "-q"), words)
    assert listing(out) == set()
    # the time series do not depend on the scene's geometry
    proc = corpuscle("plot", run, "-o", out / "p.png")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
