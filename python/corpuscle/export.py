"""``corpuscle export``: recorded runs as ParaView-readable files.

``--format vtk`` writes one VTK XML unstructured grid (``.vtu``, raw appended binary) per
frame and part plus a ``.pvd`` collection that ParaView opens as one time series;
``--format vtkhdf`` writes a single VTKHDF file (HDF5; a temporal
PartitionedDataSetCollection, VTKHDF 2.2, needs ``h5py``).

Parts of a frame: ``particles`` (the fluid group: points at ``position``, every other fluid
field as point data), one part per other particle group (``ghost``: points at
``ghost_position``), one mesh per rigid body (a box as 6 quads with the die's face numbers
as cell data ``face`` and its recorded state -- position, orientation, velocities -- as cell
data), and the scene's obstacles (e.g. the airfoil polygon). Each per-frame part carries the
frame's time, step, dt and diagnostics as field data. 2-D points and 2-component vectors
are padded with z = 0 so ParaView treats them as 3-D vectors.

Python API::

    export_run("run.cps", "out/", format="vtk")      # -> out/run.pvd
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from ._camera import quat_matrix
from ._errors import write_failure
from ._viz_common import (AtomicOutputs, cli_warnings, missing_dirs, open_run, os_reason, parse_frames, prepare_dir,
                          remove_dirs, require, run_stem, scene_info)


class ExportError(ValueError):
    """Bad input to ``corpuscle export`` (one-line message)."""


FORMATS = ("vtk", "vtkhdf")

# VTK cell type ids (vtkCellType.h)
VTK_VERTEX, VTK_TRIANGLE, VTK_POLYGON, VTK_QUAD = 1, 5, 7, 9

# NumPy dtype -> VTK XML type name
_VTK_TYPES = {
    "f4": "Float32", "f8": "Float64", "i1": "Int8", "i2": "Int16", "i4": "Int32", "i8": "Int64",
    "u1": "UInt8", "u2": "UInt16", "u4": "UInt32", "u8": "UInt64",
}


@dataclass
class Part:
    """One piece of geometry of a frame: points, cells and the arrays on them."""

    name: str
    points: np.ndarray  # (n, 3)
    connectivity: np.ndarray  # int64
    offsets: np.ndarray  # int64, (cells,): where each cell's point ids end in connectivity
    types: np.ndarray  # uint8 (cells,)
    point_data: dict = field(default_factory=dict)
    cell_data: dict = field(default_factory=dict)
    field_data: dict = field(default_factory=dict)


# ---- frames -> parts ------------------------------------------------------------------------


def _pad3(a: np.ndarray) -> np.ndarray:
    """(n, 2) -> (n, 3) with zero z; (n, 3) unchanged."""
    if a.ndim == 2 and a.shape[1] == 2:
        return np.hstack([a, np.zeros((len(a), 1), a.dtype)])
    return a


def _array(a) -> np.ndarray:
    """A recorded array in a type VTK stores (bool -> uint8, others kept)."""
    a = np.asarray(a)
    if a.dtype == np.bool_:
        a = a.astype(np.uint8)
    elif a.dtype.str[1:] not in _VTK_TYPES:
        a = a.astype(np.float64)
    if a.dtype.byteorder == ">":
        a = a.astype(a.dtype.newbyteorder("<"))
    return np.ascontiguousarray(a)


def _vertex_part(name: str, points: np.ndarray, data: dict, dim: int) -> Part:
    """A point cloud as one vertex cell per point."""
    n = len(points)
    pd = {}
    for k, v in data.items():
        v = _array(v)
        pd[k] = _pad3(v) if dim == 2 and v.ndim == 2 and v.shape[1] == 2 else v
    return Part(name, _pad3(_array(points)), np.arange(n, dtype=np.int64), np.arange(1, n + 1, dtype=np.int64),
                np.full(n, VTK_VERTEX, np.uint8), pd)


def _body_part(name: str, spec: dict, state: dict, dim: int) -> Part:
    """A rigid body's surface in world coordinates, its state as cell data."""
    pos = np.zeros(3)
    p = np.asarray(state.get("position", [0, 0, 0]), float).reshape(-1)[:3]
    pos[: len(p)] = p
    rot = quat_matrix(state.get("orientation", [1, 0, 0, 0]))
    shape = spec.get("shape", "box" if "half_extents" in spec else None)
    faces_spec = spec.get("faces") or {}
    if shape == "box" and "half_extents" in spec and dim == 2:
        # a rectangle in the plane: one quad
        hx, hy = np.asarray(spec["half_extents"], float).reshape(-1)[:2]
        corners = np.array([[-hx, -hy, 0.0], [hx, -hy, 0.0], [hx, hy, 0.0], [-hx, hy, 0.0]])
        part = Part(name, pos + corners @ rot.T, np.arange(4, dtype=np.int64), np.array([4], np.int64),
                    np.array([VTK_QUAD], np.uint8))
    elif shape == "box" and "half_extents" in spec:
        he = np.zeros(3)
        h = np.asarray(spec["half_extents"], float).reshape(-1)[:3]
        he[: len(h)] = h
        corners = np.array([[(1 if (k >> a) & 1 else -1) * he[a] for a in range(3)] for k in range(8)])
        quads, numbers = [], []
        for a in range(3):
            for s in (0, 1):
                b, c = (a + 1) % 3, (a + 2) % 3
                ring = []
                for sb, sc in ((0, 0), (1, 0), (1, 1), (0, 1)):
                    ring.append((s << a) | (sb << b) | (sc << c))
                if s == 0:
                    ring = ring[::-1]  # outward winding on the negative face
                quads.append(ring)
                normal = np.zeros(3)
                normal[a] = 1.0 if s else -1.0
                numbers.append(next((int(lbl) for lbl, nrm in faces_spec.items()
                                     if np.allclose(np.asarray(nrm, float) / max(np.linalg.norm(nrm), 1e-300), normal)), 0))
        pts = pos + corners @ rot.T
        conn = np.array(quads, np.int64).reshape(-1)
        part = Part(name, pts, conn, np.arange(4, 4 * len(quads) + 1, 4, dtype=np.int64),
                    np.full(len(quads), VTK_QUAD, np.uint8), cell_data={"face": np.array(numbers, np.int32)})
    elif shape == "sphere" and spec.get("radius"):
        r = float(spec["radius"])
        nu, nv = 16, 8
        th = np.linspace(0, np.pi, nv + 1)[1:-1]
        ph = np.linspace(0, 2 * np.pi, nu + 1)[:-1]
        ring = np.array([[np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)] for t in th for f in ph])
        pts = np.vstack([[0, 0, 1], ring, [0, 0, -1]]) * r @ rot.T + pos
        conn, offs, types = [], [], []
        south = len(pts) - 1
        for j in range(nu):
            conn += [0, 1 + j, 1 + (j + 1) % nu]
            types.append(VTK_TRIANGLE)
            offs.append(len(conn))
        for i in range(nv - 2):
            for j in range(nu):
                a, b = 1 + i * nu + j, 1 + i * nu + (j + 1) % nu
                conn += [a, a + nu, b + nu, b]
                types.append(VTK_QUAD)
                offs.append(len(conn))
        for j in range(nu):
            base = 1 + (nv - 2) * nu
            conn += [base + j, south, base + (j + 1) % nu]
            types.append(VTK_TRIANGLE)
            offs.append(len(conn))
        part = Part(name, pts, np.array(conn, np.int64), np.array(offs, np.int64), np.array(types, np.uint8))
    else:
        part = Part(name, pos[None], np.zeros(1, np.int64), np.ones(1, np.int64), np.full(1, VTK_VERTEX, np.uint8))
    ncells = len(part.types)
    for k, v in state.items():
        v = _array(v).reshape(-1)
        part.cell_data[k] = np.ascontiguousarray(np.repeat(v[None], ncells, axis=0) if len(v) > 1 else np.repeat(v, ncells))
    return part


def _obstacle_part(ob: dict, k: int) -> Part | None:
    """A fixed obstacle: a polygon as one polygon cell (an extruded one as its two caps and
    its sides), a 3-D box as its 6 faces."""
    if ob.get("type") == "box" and len(ob.get("min", ())) == 3:
        lo, hi = np.asarray(ob["min"], float), np.asarray(ob["max"], float)
        part = _body_part(f"obstacle_{ob.get('name', k)}", {"shape": "box", "half_extents": 0.5 * (hi - lo)},
                          {"position": 0.5 * (lo + hi)}, 3)
        part.cell_data = {}
        return part
    if ob.get("type") == "mesh":
        v = np.asarray(ob["vertices"], float)
        f = np.asarray(ob["faces"], np.int64).reshape(-1, 3)
        return Part(f"obstacle_{ob.get('name', k)}", v, f.reshape(-1), np.arange(3, 3 * len(f) + 1, 3, dtype=np.int64),
                    np.full(len(f), VTK_TRIANGLE, np.uint8))
    pts = ob.get("points")
    if pts is None or len(pts) < 3:
        return None
    ext = ob.get("extrude")
    if isinstance(ext, (list, tuple)) and len(ext) == 2:
        # an x-y section swept along z from ext[0] to ext[1] (wind-tunnel-3d's airfoil): its two
        # end caps (polygons) and one quad per edge
        xy = np.asarray(pts, float)[:, :2]
        n = len(xy)
        p = np.vstack([np.column_stack([xy, np.full(n, float(ext[0]))]), np.column_stack([xy, np.full(n, float(ext[1]))])])
        conn = list(range(n)) + list(range(2 * n - 1, n - 1, -1))
        offs, types = [n, 2 * n], [VTK_POLYGON, VTK_POLYGON]
        for i in range(n):
            j = (i + 1) % n
            conn += [i, j, n + j, n + i]
            offs.append(len(conn))
            types.append(VTK_QUAD)
        return Part(f"obstacle_{ob.get('name', k)}", p, np.array(conn, np.int64), np.array(offs, np.int64),
                    np.array(types, np.uint8))
    p = _pad3(np.asarray(pts, float)[:, :3])
    n = len(p)
    return Part(f"obstacle_{ob.get('name', k)}", p, np.arange(n, dtype=np.int64), np.array([n], np.int64),
                np.array([VTK_POLYGON], np.uint8))


def _group_position(fields: dict, groups: dict, group: str) -> str | None:
    """The field holding a particle group's positions."""
    for cand in (f"{group}_position", "position" if group == "fluid" else None):
        if cand and cand in fields and groups.get(cand, "fluid") == group:
            return cand
    return next((k for k in fields if groups.get(k, "fluid") == group and k.endswith("position")), None)


def frame_parts(frame, header: dict) -> list[Part]:
    """Split one frame into parts (particles, other groups, rigid bodies)."""
    fields = frame.fields
    groups = dict(getattr(frame, "groups", None) or {})
    info = scene_info(header)
    dim = int(info["dim"] or (fields["position"].shape[1] if "position" in fields else 3))
    fd = {"TimeValue": np.array([float(frame.time)]), "step": np.array([int(frame.step)], np.int64),
          "dt": np.array([float(getattr(frame, "dt", np.nan))])}
    for k, v in (getattr(frame, "diagnostics", None) or {}).items():
        fd[k] = np.array([float(v)])
    parts = []
    names = sorted({groups.get(k, "fluid") for k in fields}, key=lambda g: (g != "fluid", g))
    for g in names:
        pkey = _group_position(fields, groups, g)
        if pkey is None:
            raise ExportError(f"particle group '{g}' has no position field: cannot place its points")
        members = {k: v for k, v in fields.items() if groups.get(k, "fluid") == g and k != pkey}
        n = len(fields[pkey])
        bad = [k for k, v in members.items() if len(v) != n]
        if bad:
            raise ExportError(f"field '{bad[0]}' has {len(members[bad[0]])} rows, its group '{g}' has {n} particles")
        part = _vertex_part("particles" if g == "fluid" else g, fields[pkey], members, dim)
        part.field_data = fd
        parts.append(part)
    specs = {b.get("name"): b for b in info["bodies"]}
    for name, state in (getattr(frame, "rigid", None) or {}).items():
        part = _body_part(f"body_{name}", specs.get(name, {}), state, dim)
        part.field_data = fd
        parts.append(part)
    return parts


def static_parts(header: dict) -> list[Part]:
    """Parts that do not change over the run (obstacles)."""
    return [p for k, ob in enumerate(scene_info(header)["obstacles"]) if (p := _obstacle_part(ob, k)) is not None]


# ---- VTK XML (.vtu + .pvd) ------------------------------------------------------------------


def _data_array(a: np.ndarray, name: str | None, offset: int, tuples: bool = False) -> str:
    comps = 1 if a.ndim == 1 else int(np.prod(a.shape[1:]))
    attrs = f'type="{_VTK_TYPES[a.dtype.str[1:]]}"'
    if name is not None:
        attrs += f" Name={quoteattr(name)}"
    if comps > 1:
        attrs += f' NumberOfComponents="{comps}"'
    if tuples:
        attrs += f' NumberOfTuples="{len(a)}"'
    return f'<DataArray {attrs} format="appended" offset="{offset}"/>'


def write_vtu(path: Path, part: Part) -> None:
    """One part as a VTK XML UnstructuredGrid with raw appended binary data.

    The binary blocks are stored in the reverse of the order the XML lists them: VTK seeks to
    each offset and does not mind, and meshio's raw-data reader (which relabels offsets one
    block at a time) then never mistakes a relabelled offset for a pending one.
    """
    arrays: list[tuple[np.ndarray, str | None, bool]] = []
    lines = ['<?xml version="1.0"?>',
             '<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64">',
             "<UnstructuredGrid>"]

    def add(a: np.ndarray, name: str | None, tuples: bool = False) -> str:
        arrays.append((_array(a), name, tuples))
        return f"\0{len(arrays) - 1}\0"

    if part.field_data:
        lines.append("<FieldData>")
        lines += [add(v, k, tuples=True) for k, v in part.field_data.items()]
        lines.append("</FieldData>")
    lines.append(f'<Piece NumberOfPoints="{len(part.points)}" NumberOfCells="{len(part.types)}">')
    lines.append("<PointData>")
    lines += [add(v, k) for k, v in part.point_data.items()]
    lines.append("</PointData>")
    lines.append("<CellData>")
    lines += [add(v, k) for k, v in part.cell_data.items()]
    lines.append("</CellData>")
    lines += ["<Points>", add(part.points, "Points"), "</Points>"]
    lines += ["<Cells>", add(part.connectivity, "connectivity"), add(part.offsets, "offsets"), add(part.types, "types"),
              "</Cells>", "</Piece>", "</UnstructuredGrid>", '<AppendedData encoding="raw">']
    # offsets: the last-listed array's block comes first
    offsets, pos = [0] * len(arrays), 0
    for k in reversed(range(len(arrays))):
        offsets[k] = pos
        pos += 8 + arrays[k][0].nbytes
    xml = [(_data_array(arrays[int(ln[1:-1])][0], arrays[int(ln[1:-1])][1], offsets[int(ln[1:-1])], arrays[int(ln[1:-1])][2])
            if ln.startswith("\0") else ln) for ln in lines]
    with open(path, "wb") as f:
        f.write(("\n".join(xml) + "\n_").encode())
        for a, _, _ in reversed(arrays):
            f.write(np.uint64(a.nbytes).tobytes())
            f.write(a.tobytes())
        f.write(b"\n</AppendedData>\n</VTKFile>\n")


def _export_vtk(run, indices, out: Path, stem: str, bar, files: AtomicOutputs) -> Path:
    """Every .vtu and the .pvd, written to temporary names in ``files`` (the caller commits)."""
    entries = []
    header = run.header or {}
    statics = static_parts(header)
    for part in statics:
        write_vtu(files.path(out / f"{part.name}.vtu"), part)
    for i in indices:
        frame = run[i]
        parts = frame_parts(frame, header)
        names = [p.name for p in parts] + [p.name for p in statics]
        for p in parts:
            fname = f"{p.name}_{i:05d}.vtu"
            write_vtu(files.path(out / fname), p)
            entries.append((frame.time, names.index(p.name), p.name, fname))
        for p in statics:
            entries.append((frame.time, names.index(p.name), p.name, f"{p.name}.vtu"))
        bar.update(1)
    # the collection last: it is moved into place after every file it lists
    pvd = out / f"{stem}.pvd"
    rows = [f'<DataSet timestep="{t!r}" part="{k}" name={quoteattr(n)} file={quoteattr(f)}/>' for t, k, n, f in entries]
    files.path(pvd).write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="1.0" byte_order="LittleEndian">\n'
                               "<Collection>\n" + "\n".join(rows) + "\n</Collection>\n</VTKFile>\n")
    return pvd


# ---- VTKHDF (.vtkhdf) -----------------------------------------------------------------------


def _hdf_name(name: str) -> str:
    """VTKHDF array names cannot hold '/' or '.'."""
    return name.replace("/", "_").replace(".", "_")


class _HdfBlock:
    """One temporal UnstructuredGrid block of a VTKHDF PartitionedDataSetCollection."""

    def __init__(self, root, name: str, index: int, schema: dict):
        import h5py

        self.g = root.create_group(name, track_order=True)
        self.g.attrs["Version"] = np.array([2, 2], np.int64)
        self.g.attrs.create("Type", np.bytes_("UnstructuredGrid"), dtype=h5py.string_dtype("ascii", len("UnstructuredGrid")))
        self.g.attrs["Index"] = np.int64(index)
        self.schema = schema
        self.steps = self.g.create_group("Steps", track_order=True)
        self.counters = {"points": 0, "cells": 0, "conn": 0, "parts": 0}
        self.nsteps = 0

    def _append(self, path: str, a: np.ndarray) -> int:
        """Append rows to a growable dataset; returns the row where they start."""
        if path not in self.g:
            self.g.create_dataset(path, data=a, maxshape=(None,) + a.shape[1:], chunks=True)
            return 0
        d = self.g[path]
        start = d.shape[0]
        d.resize(start + len(a), axis=0)
        d[start:] = a
        return start

    def add(self, time: float, part: Part | None, reuse: bool) -> None:
        """Add one time step (``part`` None: an empty step; ``reuse``: point at the first step's data)."""
        c = self.counters
        steps = {"Values": [time]}
        if reuse and self.nsteps > 0:
            steps.update(PartOffsets=[0], NumberOfParts=[1], PointOffsets=[0], CellOffsets=[[0]], ConnectivityIdOffsets=[[0]])
            for grp in ("PointData", "CellData", "FieldData"):
                for k in self.schema[grp]:
                    self._append(f"Steps/{grp}Offsets/{k}", np.array([0], np.int64))
        else:
            if part is None:
                part = Part("", np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.uint8))
            n, m, k = len(part.points), len(part.types), len(part.connectivity)
            steps.update(PartOffsets=[c["parts"]], NumberOfParts=[1], PointOffsets=[c["points"]],
                         CellOffsets=[[c["cells"]]], ConnectivityIdOffsets=[[c["conn"]]])
            self._append("NumberOfPoints", np.array([n], np.int64))
            self._append("NumberOfCells", np.array([m], np.int64))
            self._append("NumberOfConnectivityIds", np.array([k], np.int64))
            self._append("Points", np.asarray(part.points, np.float64).reshape(-1, 3) if n else np.zeros((0, 3)))
            self._append("Connectivity", part.connectivity.astype(np.int64))
            self._append("Offsets", np.concatenate([[0], part.offsets]).astype(np.int64))
            self._append("Types", part.types.astype(np.uint8))
            for grp, rows, data in (("PointData", n, part.point_data), ("CellData", m, part.cell_data)):
                for name, (dtype, shape) in self.schema[grp].items():
                    a = data.get(name)
                    if a is None:
                        a = np.full((rows,) + shape, np.nan if np.issubdtype(dtype, np.floating) else 0, dtype)
                    start = self._append(f"{grp}/{_hdf_name(name)}", np.asarray(a, dtype).reshape((rows,) + shape))
                    self._append(f"Steps/{grp}Offsets/{_hdf_name(name)}", np.array([start], np.int64))
            for name, (dtype, shape) in self.schema["FieldData"].items():
                a = part.field_data.get(name)
                a = np.full(1, np.nan if np.issubdtype(dtype, np.floating) else 0, dtype) if a is None else np.asarray(a, dtype)
                start = self._append(f"FieldData/{_hdf_name(name)}", a.reshape(-1))
                self._append(f"Steps/FieldDataOffsets/{_hdf_name(name)}", np.array([start], np.int64))
                self._append(f"Steps/FieldDataSizes/{_hdf_name(name)}", np.array([[1, len(a.reshape(-1))]], np.int64))
            c["points"] += n
            c["cells"] += m
            c["conn"] += k
            c["parts"] += 1
        for key, val in steps.items():
            self._append(f"Steps/{key}", np.asarray(val, np.float64 if key == "Values" else np.int64))
        self.nsteps += 1
        self.steps.attrs["NSteps"] = np.int64(self.nsteps)


def _schema(parts: list[Part]) -> dict:
    """Arrays (dtype, per-row shape) of a block over all its frames."""
    s = {"PointData": {}, "CellData": {}, "FieldData": {}}
    for p in parts:
        for grp, data in (("PointData", p.point_data), ("CellData", p.cell_data), ("FieldData", p.field_data)):
            for k, v in data.items():
                s[grp].setdefault(k, (v.dtype, v.shape[1:] if grp != "FieldData" else ()))
    return s


def _export_vtkhdf(run, indices, out: Path, stem: str, bar, files: AtomicOutputs) -> Path:
    h5py = require("h5py", "h5py", "--format vtkhdf", ExportError)
    header = run.header or {}
    # pass 1: which blocks exist and which arrays each carries (reads shapes, not data)
    order, schemas = [], {}
    for i in indices:
        for p in frame_parts(run[i], header):
            if p.name not in schemas:
                order.append(p.name)
                schemas[p.name] = []
            schemas[p.name].append(Part(p.name, p.points[:0], p.connectivity[:0], p.offsets[:0], p.types[:0],
                                        {k: v[:0] for k, v in p.point_data.items()},
                                        {k: v[:0] for k, v in p.cell_data.items()}, p.field_data))
    statics = static_parts(header)
    path = out / f"{stem}.vtkhdf"
    with open(files.path(path), "w+b", buffering=0) as raw:  # unbuffered: seek never writes
        sink = _WriteErrorLatch(raw)
        _write_vtkhdf(h5py, sink, run, indices, header, order, schemas, statics, bar)
        if sink.error is not None:
            raise sink.error
    return path


class _WriteErrorLatch:
    """The file object h5py writes the .vtkhdf through: the first failed write (a full
    disk) is kept and later writes are dropped, so HDF5 never sees a failure.

    HDF5 writing a file itself on a full disk failed inside h5py's close: a traceback
    printed for every open object, then a segmentation fault, and the partial file left
    behind. Here the export stops after the frame that failed and raises the kept OSError
    once h5py has closed cleanly (the partial file is then discarded)."""

    def __init__(self, raw):
        self.raw, self.error = raw, None

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        n = len(view)
        if self.error is None:
            try:
                while view:  # a raw write may take fewer bytes than offered
                    view = view[self.raw.write(view):]
            except OSError as exc:
                self.error = exc
        if view:  # dropped: move on as if written
            self.raw.seek(len(view), 1)
        return n

    def read(self, n: int = -1) -> bytes:
        return self.raw.read(n)

    def readinto(self, b) -> int:
        return self.raw.readinto(b)

    def seek(self, offset: int, whence: int = 0) -> int:
        return self.raw.seek(offset, whence)

    def tell(self) -> int:
        return self.raw.tell()

    def truncate(self, size: int | None = None) -> int:
        if self.error is None:
            try:
                return self.raw.truncate(size)
            except OSError as exc:
                self.error = exc
        return self.raw.tell() if size is None else size

    def flush(self) -> None:
        if self.error is None:
            try:
                self.raw.flush()
            except OSError as exc:
                self.error = exc


def _write_vtkhdf(h5py, sink, run, indices, header, order, schemas, statics, bar) -> None:
    with h5py.File(sink, "w", track_order=True) as f:
        root = f.create_group("VTKHDF", track_order=True)
        root.attrs["Version"] = np.array([2, 2], np.int64)
        root.attrs.create("Type", np.bytes_("PartitionedDataSetCollection"),
                          dtype=h5py.string_dtype("ascii", len("PartitionedDataSetCollection")))
        assembly = root.create_group("Assembly", track_order=True)
        blocks = {}
        for k, name in enumerate(order + [p.name for p in statics]):
            sch = _schema(schemas[name]) if name in schemas else _schema([p for p in statics if p.name == name])
            blocks[name] = _HdfBlock(root, name, k, sch)
            assembly[name] = h5py.SoftLink(f"/VTKHDF/{name}")
        # pass 2: the data, one time step at a time
        for i in indices:
            frame = run[i]
            parts = {p.name: p for p in frame_parts(frame, header)}
            for name in order:
                blocks[name].add(float(frame.time), parts.get(name), reuse=False)
            for p in statics:
                blocks[p.name].add(float(frame.time), p, reuse=True)
            bar.update(1)
            if sink.error is not None:
                break  # the disk is full: no point in encoding the rest


# ---- entry points ---------------------------------------------------------------------------


def export_run(run, out_dir, *, format: str = "vtk", frames=None, progress: bool | None = None) -> Path:
    """Export a recorded run (path or opened Run) into folder ``out_dir``.

    ``format``: ``"vtk"`` (``.vtu`` per frame and part plus ``<run>.pvd``) or ``"vtkhdf"``
    (one ``<run>.vtkhdf``). ``frames``: ``"a:b[:step]"`` or a slice (default all). Returns the
    file to open in ParaView. Raises :class:`ExportError` for bad input.
    """
    if format not in FORMATS:
        raise ExportError(f"unknown --format '{format}': choose {' or '.join(FORMATS)}")
    run = open_run(run, ExportError)
    indices = parse_frames(frames, len(run), ExportError)
    created = missing_dirs(out_dir)
    out = prepare_dir(out_dir, ExportError)
    stem = run_stem(run)
    from tqdm import tqdm

    # every file is written under a temporary name and moved into place only when the whole
    # export succeeded; a failure part-way (a corrupted frame, a full disk, Ctrl-C) leaves none
    files = AtomicOutputs()
    try:
        with tqdm(total=len(indices), unit="frame", desc="export", leave=False,
                  disable=None if progress is None else not progress) as bar:
            writer = _export_vtk if format == "vtk" else _export_vtkhdf
            result = writer(run, indices, out, stem, bar, files)
        files.commit()
    except BaseException as exc:
        files.discard()
        remove_dirs(created)  # the folders this export made, if empty again
        if isinstance(exc, OSError):
            raise write_failure(ExportError, f"cannot write into {out}: {os_reason(exc)}", exc) from None
        raise
    return result


def run_command(args: argparse.Namespace) -> int:
    """Run ``corpuscle export`` from parsed arguments; returns the exit code."""
    with cli_warnings():
        return _run_command(args)


def _run_command(args: argparse.Namespace) -> int:
    path = export_run(args.run, args.output, format=args.format, frames=args.frames,
                      progress=False if args.quiet else None)
    if not args.quiet:
        print(f"wrote {path}")
    return 0


# one-line help and description of the subcommand (for a command table such as corpuscle.cli's)
HELP = "export a recorded run for ParaView (VTK or VTKHDF)"
DESCRIPTION = ("Export a recorded run as ParaView-readable files: a .vtu per frame and "
               "part plus a .pvd series (vtk), or one .vtkhdf file (vtkhdf).")


def configure_parser(p: argparse.ArgumentParser) -> None:
    """Add ``corpuscle export``'s arguments to a (sub)parser."""
    p.add_argument("run", metavar="RUN", help="recorded run (frame stream file)")
    p.add_argument("output", metavar="DIR", help="output folder (created if missing)")
    p.add_argument("--format", default="vtk", metavar="vtk|vtkhdf", help="vtk (default) or vtkhdf")
    p.add_argument("--frames", metavar="A:B[:STEP]", help="frames to export (Python slice; default all)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``corpuscle export`` on an argparse subparsers object (handler in ``func``)."""
    p = subparsers.add_parser("export", help=HELP, description=DESCRIPTION)
    configure_parser(p)
    p.set_defaults(func=run_command)
    return p
