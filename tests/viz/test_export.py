"""corpuscle export: ParaView files read back with VTK reader libraries, every field compared."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

import corpuscle
from corpuscle._camera import quat_matrix
from corpuscle.export import ExportError, export_run

import viz_runs

meshio = pytest.importorskip("meshio")


def pvd_entries(path):
    """(time, part, name, file) of every data set a .pvd lists."""
    root = ET.parse(path).getroot()
    return [(float(d.get("timestep")), int(d.get("part")), d.get("name"), d.get("file"))
            for d in root.iter("DataSet")]


def check_die(points, cell_data, cells, state, half):
    """A die mesh: 6 outward quads at the recorded pose, numbered as the header says."""
    rot = quat_matrix(state["orientation"])
    local = (points - state["position"]) @ rot  # back to the body frame
    np.testing.assert_allclose(np.abs(local), half, atol=1e-9)
    faces = cell_data["face"]
    assert sorted(faces.tolist()) == [1, 2, 3, 4, 5, 6]
    for quad, number in zip(cells, faces):
        centre = local[quad].mean(axis=0) / half
        np.testing.assert_allclose(centre, viz_runs.DIE_FACES[str(int(number))], atol=1e-9)
        # outward winding: the quad's normal points away from the centre
        a, b, c = local[quad[0]], local[quad[1]], local[quad[2]]
        assert np.dot(np.cross(b - a, c - b), centre) > 0
    for key in ("position", "orientation", "velocity"):
        np.testing.assert_allclose(cell_data[key], np.repeat(np.asarray(state[key])[None], 6, axis=0).reshape(6, -1)
                                   if np.ndim(state[key]) else state[key])


def test_vtk_round_trips_every_field(tmp_path):
    viz_runs.write_magic8ball(tmp_path / "m8.cps", frames=4)
    pvd = export_run(tmp_path / "m8.cps", tmp_path / "out", format="vtk", progress=False)
    assert pvd == tmp_path / "out" / "m8.pvd"
    run = corpuscle.open(tmp_path / "m8.cps")
    entries = pvd_entries(pvd)
    assert sorted({t for t, *_ in entries}) == pytest.approx(list(run.times))
    assert {n for _, _, n, _ in entries} == {"particles", "ghost", "body_die"}
    half = viz_runs.magic8ball_header()["bodies"][0]["half_extents"][0]
    for frame in run:
        files = {n: f for t, _, n, f in entries if t == pytest.approx(frame.time)}
        # fluid particles: points and every fluid field, bit for bit
        m = meshio.read(tmp_path / "out" / files["particles"])
        np.testing.assert_array_equal(m.points, frame.fields["position"])
        assert m.cells[0].type == "vertex" and len(m.cells[0].data) == len(m.points)
        for name in ("density", "pressure", "velocity"):
            np.testing.assert_array_equal(m.point_data[name], frame.fields[name])
            assert m.point_data[name].dtype == frame.fields[name].dtype
        # the frame's time, step and diagnostics as field data
        assert m.field_data["TimeValue"][0] == frame.time and m.field_data["step"][0] == frame.step
        for name, value in frame.diagnostics.items():
            assert m.field_data[name][0] == value
        # ghost particles
        g = meshio.read(tmp_path / "out" / files["ghost"])
        np.testing.assert_array_equal(g.points, frame.fields["ghost_position"])
        # the die as a mesh with its state
        d = meshio.read(tmp_path / "out" / files["body_die"])
        assert [c.type for c in d.cells] == ["quad"]
        check_die(d.points, {k: v[0] for k, v in d.cell_data.items()}, d.cells[0].data, frame.rigid["die"], half)


def test_vtu_files_open_in_vtk_itself(tmp_path):
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import vtk_to_numpy

    viz_runs.write_magic8ball(tmp_path / "m8.cps", frames=2)
    export_run(tmp_path / "m8.cps", tmp_path / "out", frames="1:", progress=False)
    frame = corpuscle.open(tmp_path / "m8.cps")[1]
    r = vtk.vtkXMLUnstructuredGridReader()
    r.SetFileName(str(tmp_path / "out" / "particles_00001.vtu"))
    r.Update()
    ug = r.GetOutput()
    np.testing.assert_array_equal(vtk_to_numpy(ug.GetPoints().GetData()), frame.fields["position"])
    np.testing.assert_array_equal(vtk_to_numpy(ug.GetPointData().GetArray("velocity")), frame.fields["velocity"])
    assert ug.GetFieldData().GetArray("TimeValue").GetValue(0) == frame.time
    assert not (tmp_path / "out" / "particles_00000.vtu").exists()


def test_2d_export_pads_to_3d_and_writes_the_obstacle(tmp_path):
    viz_runs.write_tunnel(tmp_path / "wt.cps", frames=2)
    pvd = export_run(tmp_path / "wt.cps", tmp_path / "out", progress=False)
    run = corpuscle.open(tmp_path / "wt.cps")
    entries = pvd_entries(pvd)
    assert {n for *_, n, _ in entries} == {"particles", "obstacle_airfoil"}
    m = meshio.read(tmp_path / "out" / "particles_00001.vtu")
    f = run[1]
    np.testing.assert_array_equal(m.points[:, :2], f.fields["position"])
    assert np.all(m.points[:, 2] == 0)
    np.testing.assert_array_equal(m.point_data["velocity"][:, :2], f.fields["velocity"])
    assert np.all(m.point_data["velocity"][:, 2] == 0)
    np.testing.assert_array_equal(m.point_data["pressure"], f.fields["pressure"])
    ob = meshio.read(tmp_path / "out" / "obstacle_airfoil.vtu")
    np.testing.assert_allclose(ob.points[:, :2], viz_runs.tunnel_header()["obstacles"][0]["points"])
    assert ob.cells[0].type == "polygon"


def vtkhdf_steps(path):
    """Read a VTKHDF file with VTK's own reader: per step, block name -> unstructured grid."""
    vtk = pytest.importorskip("vtk")
    r = vtk.vtkHDFReader()
    r.SetFileName(str(path))
    r.UpdateInformation()
    info = r.GetOutputInformation(0)
    times = list(info.Get(vtk.vtkStreamingDemandDrivenPipeline.TIME_STEPS()))
    steps = []
    for k in range(r.GetNumberOfSteps()):
        r.SetStep(k)
        r.Update()
        out = r.GetOutput()
        blocks = {}
        for i in range(out.GetNumberOfPartitionedDataSets()):
            ds = vtk.vtkUnstructuredGrid()
            ds.DeepCopy(out.GetPartition(i, 0))
            blocks[out.GetMetaData(i).Get(vtk.vtkCompositeDataSet.NAME())] = ds
        steps.append(blocks)
    return times, steps


def test_vtkhdf_round_trips_every_field(tmp_path):
    pytest.importorskip("h5py")
    from vtk.util.numpy_support import vtk_to_numpy

    viz_runs.write_magic8ball(tmp_path / "m8.cps", frames=3)
    path = export_run(tmp_path / "m8.cps", tmp_path / "out", format="vtkhdf", progress=False)
    assert path == tmp_path / "out" / "m8.vtkhdf"
    run = corpuscle.open(tmp_path / "m8.cps")
    times, steps = vtkhdf_steps(path)
    assert times == pytest.approx(list(run.times))
    half = viz_runs.magic8ball_header()["bodies"][0]["half_extents"][0]
    for frame, blocks in zip(run, steps):
        assert set(blocks) == {"particles", "ghost", "body_die"}
        p = blocks["particles"]
        np.testing.assert_allclose(vtk_to_numpy(p.GetPoints().GetData()), frame.fields["position"])
        for name in ("density", "pressure", "velocity"):
            np.testing.assert_array_equal(vtk_to_numpy(p.GetPointData().GetArray(name)), frame.fields[name])
        g = blocks["ghost"]
        np.testing.assert_allclose(vtk_to_numpy(g.GetPoints().GetData()), frame.fields["ghost_position"])
        d = blocks["body_die"]
        cells = vtk_to_numpy(d.GetCells().GetConnectivityArray()).reshape(-1, 4)
        cd = {d.GetCellData().GetArrayName(k): vtk_to_numpy(d.GetCellData().GetArray(k))
              for k in range(d.GetCellData().GetNumberOfArrays())}
        check_die(vtk_to_numpy(d.GetPoints().GetData()), cd, cells, frame.rigid["die"], half)


def test_vtkhdf_field_data_and_static_obstacle(tmp_path):
    h5py = pytest.importorskip("h5py")
    viz_runs.write_tunnel(tmp_path / "wt.cps", frames=3)
    path = export_run(tmp_path / "wt.cps", tmp_path / "out", format="vtkhdf", progress=False)
    run = corpuscle.open(tmp_path / "wt.cps")
    times, steps = vtkhdf_steps(path)
    assert times == pytest.approx(list(run.times))
    for blocks in steps:
        assert blocks["obstacle_airfoil"].GetNumberOfPoints() == 40
        assert blocks["particles"].GetNumberOfPoints() == 3000
    # per-step field data, laid out as the VTKHDF spec says (VTK 9.7's reader skips field
    # data inside composite files, so read it with h5py)
    with h5py.File(path) as f:
        g = f["VTKHDF/particles"]
        for name in ("lift", "drag", "cl", "cd", "TimeValue"):
            offs = g[f"Steps/FieldDataOffsets/{name}"][:]
            want = run.times if name == "TimeValue" else run.series(name)
            np.testing.assert_allclose(g[f"FieldData/{name}"][:][offs], want)


# the command line's bad input is tested through the console script: test_viz_console.py


def test_missing_h5py_names_the_pip_install(tmp_path, monkeypatch):
    import sys

    viz_runs.write_magic8ball(tmp_path / "m8.cps", frames=1)
    monkeypatch.setitem(sys.modules, "h5py", None)
    with pytest.raises(ExportError, match="pip install h5py"):
        export_run(tmp_path / "m8.cps", tmp_path / "out", format="vtkhdf")


def test_2d_body_with_an_angle_becomes_a_rotated_quad(tmp_path):
    from corpuscle.io import FrameWriter

    hdr = viz_runs.tunnel_header() | {"bodies": [{"name": "plate", "shape": "box", "half_extents": [0.2, 0.02]}]}
    with FrameWriter(tmp_path / "p.cps", hdr) as w:
        w.write_frame(0, 0.0, 1e-3, {"position": np.zeros((3, 2), np.float32)},
                      rigid={"plate": {"position": np.array([1.5, 0.5]), "orientation": np.array([np.pi / 2])}})
    export_run(tmp_path / "p.cps", tmp_path / "out", progress=False)
    m = meshio.read(tmp_path / "out" / "body_plate_00000.vtu")
    assert [c.type for c in m.cells] == ["quad"] and len(m.points) == 4
    lo, hi = m.points.min(axis=0), m.points.max(axis=0)
    np.testing.assert_allclose(lo[:2], [1.48, 0.3], atol=1e-9)
    np.testing.assert_allclose(hi[:2], [1.52, 0.7], atol=1e-9)
    np.testing.assert_allclose(m.cell_data["orientation"][0], np.pi / 2)


def test_sphere_body_becomes_a_closed_sphere_mesh(tmp_path):
    from corpuscle.io import FrameWriter

    hdr = viz_runs.magic8ball_header() | {"bodies": [{"name": "ball", "shape": "sphere", "radius": 0.02}]}
    with FrameWriter(tmp_path / "b.cps", hdr) as w:
        w.write_frame(0, 0.0, 1e-3, {"position": np.zeros((2, 3), np.float32)},
                      rigid={"ball": {"position": np.array([0.01, 0.0, -0.03]), "orientation": np.array([1.0, 0, 0, 0])}})
    export_run(tmp_path / "b.cps", tmp_path / "out", progress=False)
    m = meshio.read(tmp_path / "out" / "body_ball_00000.vtu")
    np.testing.assert_allclose(np.linalg.norm(m.points - [0.01, 0.0, -0.03], axis=1), 0.02)
    # every edge is shared by exactly two faces: a closed surface
    edges = {}
    for block in m.cells:
        for cell in block.data:
            for a, b in zip(cell, np.roll(cell, -1)):
                key = (min(a, b), max(a, b))
                edges[key] = edges.get(key, 0) + 1
    assert set(edges.values()) == {2}


# ---- failed exports leave no partial output ------------------------------------------------------


def test_vtk_export_failing_part_way_leaves_no_file_and_no_new_folder(tmp_path):
    from cli_script import corrupt_frame, listing
    from corpuscle.io import FrameStreamError

    viz_runs.write_magic8ball(tmp_path / "m8.cps", frames=5)
    corrupt_frame(tmp_path / "m8.cps", 3)
    # frames 0-2 are converted (9 .vtu files), then frame 3 raises
    with pytest.raises(FrameStreamError, match="frame 3 is corrupted"):
        export_run(tmp_path / "m8.cps", tmp_path / "new" / "out", progress=False)
    assert listing(tmp_path) == {"m8.cps"}
    # into an existing folder: what was there stays, nothing is added
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "notes.txt").write_text("mine")
    with pytest.raises(FrameStreamError, match="frame 3 is corrupted"):
        export_run(tmp_path / "m8.cps", tmp_path / "out", progress=False)
    assert listing(tmp_path / "out") == {"notes.txt"}
    # the frames before it export fine, and only then do their files appear
    export_run(tmp_path / "m8.cps", tmp_path / "out", frames=":3", progress=False)
    assert listing(tmp_path / "out") == {"notes.txt", "m8.pvd"} | {f"{p}_{k:05d}.vtu" for p in ("particles", "ghost", "body_die")
                                                                 for k in range(3)}


def test_vtkhdf_export_failing_part_way_leaves_no_file(tmp_path, monkeypatch):
    pytest.importorskip("h5py")
    from cli_script import listing
    from corpuscle import export

    viz_runs.write_magic8ball(tmp_path / "m8.cps", frames=4)
    real, calls = export._HdfBlock.add, []

    def fill_the_disk(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 5:  # in the second time step
            raise OSError(28, "No space left on device")
        return real(self, *args, **kwargs)

    monkeypatch.setattr(export._HdfBlock, "add", fill_the_disk)
    with pytest.raises(ExportError, match="cannot write into .*out: No space left on device"):
        export_run(tmp_path / "m8.cps", tmp_path / "out", format="vtkhdf", progress=False)
    assert len(calls) == 5 and listing(tmp_path) == {"m8.cps"}
