"""corpuscle export --format surface: fluid surfaces reconstructed with splashsurf, written as OBJ, PLY
and VTK, read back with trimesh, meshio and VTK's own reader, and checked against the geometry the
particles fill (a block's volume, a sphere's area)."""

from __future__ import annotations

import math
import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from corpuscle.export import ExportError, export_run
from corpuscle.io import FrameWriter
from corpuscle.surface import SurfaceError, export_surfaces, reconstruct, surface_defaults

pytest.importorskip("pysplashsurf")
trimesh = pytest.importorskip("trimesh")
meshio = pytest.importorskip("meshio")

DP = 0.01  # lattice spacing of the test fluids (m)
SMOOTHING = 1.732  # hs / dp, the SPH kinds' default


def fluid_header(kind: str = "fluid-box", dim: int = 3, dp: float = DP) -> dict:
    """A run header as the SPH box kinds write it (spacing, kernel support h = 2 hs, radius dp / 2)."""
    return {"scene": kind, "kind": kind, "dim": dim, "spacing": dp, "h": 2 * SMOOTHING * dp, "particle_radius": dp / 2}


def lattice_block(n=(12, 10, 8), dp: float = DP) -> np.ndarray:
    """Particle centres of a block of n cells of dp (each particle fills one cell)."""
    axes = [(np.arange(k) + 0.5) * dp for k in n]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def write_run(path, positions, header=None, frames: int = 1, shift=(0.0, 0.0, 0.0)):
    """A run whose frame k holds the particles moved by k * shift."""
    with FrameWriter(path, header or fluid_header()) as w:
        for k in range(frames):
            w.write_frame(10 * k, 0.1 * k, 1e-3, {"position": (positions + k * np.asarray(shift)[:positions.shape[1]]).astype(np.float32)})


def canonical(points, triangles) -> np.ndarray:
    """A mesh as its triangles' corner coordinates, each triangle rotated (winding kept) to start
    at its lowest corner and the triangles sorted: the same for the same mesh whatever the order
    of its vertices and triangles (splashsurf's threads may number them differently run to run)."""
    c = np.asarray(points, np.float64)[np.asarray(triangles)]  # (m, 3 corners, 3)
    key = np.round(c / (DP * 1e-4)).astype(np.int64)  # coordinates on a grid far below the cells
    first = np.array([min(range(3), key=lambda k: tuple(t[k])) for t in key])
    rows = np.array([np.roll(t, -f, axis=0).reshape(-1) for t, f in zip(key, first)])
    return rows[np.lexsort(rows.T[::-1])]


def corpuscle(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "corpuscle", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=120)


def test_defaults_come_from_the_run_header():
    d = surface_defaults(fluid_header())
    assert d["particle_radius"] == pytest.approx(DP / 2)
    # splashsurf's support is twice its smoothing length: the run's support 2 hs -> hs, in radii
    assert d["smoothing_length"] * d["particle_radius"] * 2 == pytest.approx(2 * SMOOTHING * DP)
    assert d["cube_size"] == 1.0 and d["iso_threshold"] == 0.6


def test_static_block_is_closed_and_has_its_volume(tmp_path):
    n = (12, 10, 8)
    write_run(tmp_path / "block.cps", lattice_block(n))
    paths = export_surfaces(tmp_path / "block.cps", tmp_path / "out", mesh="obj", progress=False)
    assert [p.name for p in paths] == ["surface_00000.obj"]
    m = trimesh.load(paths[0], process=False)
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    # each particle fills a cell of dp: the block's faces lie half a spacing outside the outer
    # centres; the iso-surface of the smoothed colour field lies within half a spacing of them,
    # so the volume lies between the block shrunk and grown by one spacing in each direction
    L = np.array(n) * DP
    assert np.prod(L - DP) < m.volume < np.prod(L + DP)
    # the mesh spans the block within the same band
    lo, hi = m.bounds
    assert np.all(np.abs(lo - 0.0) < DP / 2) and np.all(np.abs(hi - L) < DP / 2)


def test_sphere_of_particles_has_a_spheres_area():
    # lattice particles within R: a sphere of the volume they fill, N dp^3
    R = 10.5 * DP
    p = lattice_block((24, 24, 24)) - 12 * DP
    p = p[np.linalg.norm(p, axis=1) < R]
    r_eff = (3 * len(p) * DP ** 3 / (4 * math.pi)) ** (1 / 3)
    m = reconstruct(p, particle_radius=DP / 2, smoothing_length=2 * SMOOTHING)
    tm = trimesh.Trimesh(m.vertices, m.triangles, process=False)
    assert tm.is_watertight
    # the surface within half a spacing of the sphere the particles fill
    assert 4 * math.pi * (r_eff - DP / 2) ** 2 < m.area() < 4 * math.pi * (r_eff + DP / 2) ** 2
    assert m.volume() == pytest.approx(tm.volume)
    radii = np.linalg.norm(m.vertices, axis=1)
    assert np.all(np.abs(radii - r_eff) < DP / 2 + 0.5 * DP / 2)  # plus half a marching-cubes cell


def test_every_format_reads_back_as_the_same_mesh(tmp_path):
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import vtk_to_numpy

    write_run(tmp_path / "b.cps", lattice_block((6, 6, 6)), frames=3, shift=(DP, 0, 0))
    frame1 = (lattice_block((6, 6, 6)) + (DP, 0, 0)).astype(np.float32)  # as recorded
    ref = reconstruct(frame1, particle_radius=DP / 2, smoothing_length=2 * SMOOTHING, normals=True)
    for mesh in ("obj", "ply", "vtk"):
        paths = export_surfaces(tmp_path / "b.cps", tmp_path / mesh, mesh=mesh, frames="1:", normals=True,
                                progress=False)
        ext = {"obj": ".obj", "ply": ".ply", "vtk": ".vtu"}[mesh]
        assert [p.name for p in paths if p.suffix == ext] == [f"surface_00001{ext}", f"surface_00002{ext}"]
        m = meshio.read(paths[0])
        assert [c.type for c in m.cells] == ["triangle"]
        # the same triangles, wound the same way (PLY stores float32: a grid of DP 1e-4 holds it)
        np.testing.assert_array_equal(canonical(m.points, m.cells[0].data), canonical(ref.vertices, ref.triangles))
        t = trimesh.load(paths[0], process=False, force="mesh") if mesh != "vtk" else None
        if t is not None:
            assert t.is_watertight and len(t.faces) == len(ref.triangles)
    # ParaView's reader of the .vtu, and the .pvd series with the frames' times
    r = vtk.vtkXMLUnstructuredGridReader()
    r.SetFileName(str(tmp_path / "vtk" / "surface_00001.vtu"))
    r.Update()
    out = r.GetOutput()
    assert out.GetNumberOfCells() == len(ref.triangles)
    cells = vtk_to_numpy(out.GetCells().GetConnectivityArray()).reshape(-1, 3)
    np.testing.assert_array_equal(canonical(vtk_to_numpy(out.GetPoints().GetData()), cells),
                                  canonical(ref.vertices, ref.triangles))
    assert vtk_to_numpy(out.GetPointData().GetArray("Normals")).shape == ref.vertices.shape
    sets = list(ET.parse(tmp_path / "vtk" / "b_surface.pvd").getroot().iter("DataSet"))
    assert [(float(d.get("timestep")), d.get("file")) for d in sets] == [
        (pytest.approx(0.1), "surface_00001.vtu"), (pytest.approx(0.2), "surface_00002.vtu")]


def test_export_run_and_cli_take_the_surface_format(tmp_path):
    write_run(tmp_path / "b.cps", lattice_block((5, 5, 5)), frames=2)
    last = export_run(tmp_path / "b.cps", tmp_path / "py", format="surface", surface={"mesh": "ply"}, progress=False)
    assert last.name == "surface_00001.ply"
    res = corpuscle("export", tmp_path / "b.cps", tmp_path / "cli", "--format", "surface", "--mesh", "ply",
                    "--cube-size", "0.75", "--iso-threshold", "0.5", "--mesh-smoothing", "3", "--decimate")
    assert res.returncode == 0, res.stderr
    assert "wrote 2 surface meshes" in res.stdout
    m = trimesh.load(tmp_path / "cli" / "surface_00000.ply", process=False)
    assert m.is_watertight
    # the options reach the reconstruction: the same mesh from the Python function
    ref = reconstruct(lattice_block((5, 5, 5)).astype(np.float32), particle_radius=DP / 2,
                      smoothing_length=2 * SMOOTHING, cube_size=0.75,
                      iso_threshold=0.5, smoothing_iters=3, decimate=True)
    assert len(m.faces) == len(ref.triangles)


@pytest.mark.parametrize("args, message", [
    (["--mesh", "stl"], "unknown --mesh 'stl'"),
    (["--cube-size", "0"], "--cube-size must be in (0.05, 16]"),
    (["--cube-size", "abc"], "--cube-size must be a number, got 'abc'"),
    (["--particle-radius", "-1"], "--particle-radius must be in (0, 1e+06]"),
    (["--smoothing-length", "nan"], "--smoothing-length must be in"),
    (["--iso-threshold", "inf"], "--iso-threshold must be in"),
    (["--mesh-smoothing", "-2"], "--mesh-smoothing must be a non-negative integer"),
    (["--frames", "5:"], "--frames '5:' selects no frames"),
])
def test_bad_options_are_one_line_errors(tmp_path, args, message):
    write_run(tmp_path / "b.cps", lattice_block((4, 4, 4)))
    res = corpuscle("export", tmp_path / "b.cps", tmp_path / "out", "--format", "surface", *args)
    assert res.returncode == 2
    assert message in res.stderr and res.stderr.count("\n") == 1 and "Traceback" not in res.stderr
    assert not list((tmp_path / "out").glob("surface_*")) if (tmp_path / "out").exists() else True


@pytest.mark.parametrize("header, message", [
    ({"scene": "wt", "kind": "wind-tunnel-3d", "dim": 3, "particle_radius": 0.01},
     "needs a fluid (SPH) run; kind 'wind-tunnel-3d' is not a fluid"),
    (fluid_header("dam-break-2d", dim=2), "needs a 3-D fluid; kind 'dam-break-2d' is 2-D"),
    ({"scene": "x", "dim": 3}, "the run header gives no particle_radius: give --particle-radius"),
])
def test_runs_that_are_not_3d_fluids_are_refused(tmp_path, header, message):
    pos = lattice_block((4, 4, 4))
    write_run(tmp_path / "r.cps", pos[:, :2] if header.get("dim") == 2 else pos, header)
    res = corpuscle("export", tmp_path / "r.cps", tmp_path / "out", "--format", "surface")
    assert res.returncode == 2 and message in res.stderr and res.stderr.count("\n") == 1


def test_surface_options_belong_to_the_surface_format(tmp_path):
    write_run(tmp_path / "b.cps", lattice_block((4, 4, 4)))
    res = corpuscle("export", tmp_path / "b.cps", tmp_path / "out", "--mesh", "ply")
    assert res.returncode == 2 and "--mesh is an option of --format surface only" in res.stderr


def test_files_of_another_kind_are_replaced_only_with_force(tmp_path):
    write_run(tmp_path / "b.cps", lattice_block((4, 4, 4)))
    out = tmp_path / "out"
    out.mkdir()
    (out / "surface_00000.obj").write_text("v 0 0 0\n")  # someone else's OBJ
    res = corpuscle("export", tmp_path / "b.cps", out, "--format", "surface")
    assert res.returncode == 2 and "surface_00000.obj: it exists and is not a .obj output" in res.stderr
    assert (out / "surface_00000.obj").read_text() == "v 0 0 0\n"
    res = corpuscle("export", tmp_path / "b.cps", out, "--format", "surface", "--force")
    assert res.returncode == 0, res.stderr
    # our own output is replaced without --force
    res = corpuscle("export", tmp_path / "b.cps", out, "--format", "surface")
    assert res.returncode == 0, res.stderr
    assert trimesh.load(out / "surface_00000.obj", process=False).is_watertight


def test_python_errors_name_the_parameter():
    with pytest.raises(SurfaceError, match=r"positions\[3\] = \[nan"):
        p = lattice_block((3, 3, 3))
        p[3, 0] = np.nan
        reconstruct(p, particle_radius=DP / 2, smoothing_length=2.0)
    with pytest.raises(SurfaceError, match="positions must be an \\(n, 3\\) array"):
        reconstruct(np.zeros((4, 2)), particle_radius=DP / 2, smoothing_length=2.0)
    with pytest.raises(SurfaceError, match="cube_size 0.06 radii .* more than 65536"):
        reconstruct(np.array([[0, 0, 0], [1e4, 0, 0]]), particle_radius=DP / 2, smoothing_length=2.0, cube_size=0.06)
    empty = reconstruct(np.zeros((0, 3)), particle_radius=DP / 2, smoothing_length=2.0)
    assert empty.vertices.shape == (0, 3) and empty.triangles.shape == (0, 3)
    with pytest.raises(ExportError, match="unknown --format 'stl': choose vtk, vtkhdf, surface"):
        export_run("x.cps", "out", format="stl")
