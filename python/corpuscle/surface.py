"""Fluid free surfaces of recorded SPH runs, as triangle meshes for Blender, ParaView and other DCC tools.

The surface is reconstructed with splashsurf (Löschner, Böttcher, Jeske & Bender 2023, through
its Python package ``pysplashsurf``, the optional ``surface`` extra): an SPH "colour field"
(each particle's volume m / rho times the cubic-spline kernel, rho from the particles
themselves) sampled on a sparse marching-cubes grid, its iso-surface at a threshold (0.6 by
default: the surface then lies a fraction of a spacing outside the outermost particle centres),
then optionally smoothed (weighted Laplacian smoothing of the vertices) and cleaned of
"barnacles" (decimation). Parameters follow splashsurf's command line: the particle radius in
metres, the smoothing length and the cube (voxel) size in multiples of the radius.

Defaults come from the run header (``Simulation.header()``): the radius is the header's
``particle_radius`` (half the lattice spacing of the SPH kinds), the smoothing length is half
the run's kernel support ``h`` (splashsurf's kernel support is twice its smoothing length, so
the colour field is smoothed over the same support as the run's own density), the cube size one
radius (splashsurf recommends 0.5 to 1 radius; at the SPH kinds' support of 3.46 spacings, about
1.7 times splashsurf's usual one, one radius still puts two cells in a spacing, and costs about
a fifth of half a radius: docs/rendering.md has the timings).

One mesh per chosen frame, named with the frame's number: ``surface_00012.obj`` (Wavefront
OBJ, text), ``.ply`` (binary little-endian PLY) or ``.vtu`` (VTK XML, plus ``<run>_surface.pvd``,
the series ParaView opens with its times). Vertex normals (``normals=True``) go into each.

Python API::

    from corpuscle.surface import export_surfaces, reconstruct
    export_surfaces("run.cps", "out/", mesh="ply", frames="-1:")
    mesh = reconstruct(positions, particle_radius=0.005, smoothing_length=3.46)
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._errors import write_failure
from ._viz_common import (AtomicOutputs, check_file_output, missing_dirs, open_run, os_reason, parse_frames,
                          prepare_dir, remove_dirs, run_stem)

MESH_FORMATS = {"obj": ".obj", "ply": ".ply", "vtk": ".vtu"}

# what a parameter may be (splashsurf's conventions: lengths but the radius in radii)
LIMITS = {
    "particle_radius": (0.0, 1e6, "m"),
    "smoothing_length": (0.25, 32.0, "particle radii"),
    "cube_size": (0.05, 16.0, "particle radii"),
    "iso_threshold": (0.0, 10.0, ""),
}
DEFAULT_CUBE = 1.0  # radii (splashsurf: 0.5 to 1; 1 at the SPH kinds' wide support: see docs/rendering.md)
DEFAULT_ISO = 0.6  # splashsurf's default threshold of the colour field
MAX_SMOOTHING_ITERS = 10000
# a frame whose surface would need more marching-cubes cells along one axis than this is refused
# (a cube size far below the particle spacing over a large domain: memory, not a surface)
MAX_CELLS_PER_AXIS = 1 << 16


class SurfaceError(ValueError):
    """Bad input to the surface reconstruction or ``corpuscle export --format surface`` (one line)."""


@dataclass
class SurfaceMesh:
    """A triangle mesh: vertices (n, 3) float64, triangles (m, 3) int64 (outward by the
    right-hand rule), vertex normals (n, 3) or None."""

    vertices: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray | None = None

    def volume(self) -> float:
        """The enclosed volume (divergence theorem; exact for a closed, consistently wound mesh)."""
        a, b, c = (self.vertices[self.triangles[:, k]] for k in range(3))
        return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)

    def area(self) -> float:
        """The total area of the triangles."""
        a, b, c = (self.vertices[self.triangles[:, k]] for k in range(3))
        return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())


def _splashsurf(error: type[ValueError] = SurfaceError):
    try:
        import pysplashsurf
    except ImportError:
        raise error("surface reconstruction needs the 'pysplashsurf' package: pip install pysplashsurf  "
                    "(or pip install 'corpuscle[surface]')") from None
    return pysplashsurf


def _number(name: str, value, error: type[ValueError], option: str | None = None) -> float:
    """A parameter checked against LIMITS (exclusive low end, inclusive high end)."""
    lo, hi, unit = LIMITS[name]
    label = option or name
    if isinstance(value, bool):
        raise error(f"{label} must be a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise error(f"{label} must be a number, got {value!r}") from None
    if not (math.isfinite(v) and lo < v <= hi):
        raise error(f"{label} must be in ({lo:g}, {hi:g}]{' ' + unit if unit else ''}, got {value!r}")
    return v


def _iterations(value, error: type[ValueError], label: str = "smoothing_iters") -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) and not (
            isinstance(value, str) and value.strip().lstrip("+").isdigit()):
        raise error(f"{label} must be a non-negative integer, got {value!r}")
    v = int(value)
    if not 0 <= v <= MAX_SMOOTHING_ITERS:
        raise error(f"{label} must be between 0 and {MAX_SMOOTHING_ITERS}, got {value!r}")
    return v


def reconstruct(positions, *, particle_radius: float, smoothing_length: float, cube_size: float = DEFAULT_CUBE,
                iso_threshold: float = DEFAULT_ISO, smoothing_iters: int = 0, decimate: bool = False,
                normals: bool = False, error: type[ValueError] = SurfaceError) -> SurfaceMesh:
    """The free surface of a set of fluid particles (positions (n, 3) in metres).

    ``particle_radius`` in metres; ``smoothing_length`` and ``cube_size`` in multiples of the
    radius (splashsurf's kernel support is twice the smoothing length); ``iso_threshold`` the
    colour-field value of the surface; ``smoothing_iters`` weighted Laplacian smoothing
    iterations of the vertices (0: none); ``decimate``: barnacle decimation; ``normals``:
    vertex normals from the colour field's gradient. An empty set gives an empty mesh.
    """
    r = _number("particle_radius", particle_radius, error)
    hl = _number("smoothing_length", smoothing_length, error)
    cube = _number("cube_size", cube_size, error)
    iso = _number("iso_threshold", iso_threshold, error)
    iters = _iterations(smoothing_iters, error)
    pos = np.asarray(positions)
    if pos.ndim != 2 or pos.shape[1] != 3 or not np.issubdtype(pos.dtype, np.number):
        raise error(f"positions must be an (n, 3) array of numbers, got shape {pos.shape} of {pos.dtype}")
    pos = np.ascontiguousarray(pos, np.float64)
    if len(pos) == 0:
        return SurfaceMesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 3)) if normals else None)
    bad = np.flatnonzero(~np.isfinite(pos).all(axis=1))
    if bad.size:
        raise error(f"positions[{int(bad[0])}] = {pos[int(bad[0])].tolist()} is not finite ({bad.size} particles)")
    extent = float((pos.max(axis=0) - pos.min(axis=0)).max()) + 4.0 * hl * r
    if extent / (cube * r) > MAX_CELLS_PER_AXIS:
        raise error(f"cube_size {cube:g} radii ({cube * r:.3g} m) needs {extent / (cube * r):.3g} cells across the "
                    f"fluid's {extent:.3g} m, more than {MAX_CELLS_PER_AXIS}: choose a larger cube size")
    ps = _splashsurf(error)
    try:
        result = ps.reconstruction_pipeline(
            pos, particle_radius=r, smoothing_length=hl, cube_size=cube, iso_surface_threshold=iso,
            mesh_smoothing_iters=iters or None, mesh_smoothing_weights=True, decimate_barnacles=bool(decimate),
            compute_normals=bool(normals), sph_normals=bool(normals), mesh_cleanup=bool(decimate))
    except (KeyboardInterrupt, SystemExit):
        raise
    except BaseException as exc:  # splashsurf's refusals, and a Rust panic (pyo3's PanicException is a BaseException)
        raise error(f"surface reconstruction failed: {' '.join(str(exc).split()) or type(exc).__name__}") from None
    data = result[0] if isinstance(result, tuple) else result
    tri = data.mesh
    v = np.array(tri.vertices, np.float64).reshape(-1, 3)
    t = np.array(tri.triangles, np.int64).reshape(-1, 3)
    n = None
    if normals:
        attrs = data.point_attributes
        n = np.array(attrs["normals"], np.float64).reshape(-1, 3) if "normals" in attrs else np.zeros_like(v)
    return SurfaceMesh(v, t, n)


# ---- mesh files -------------------------------------------------------------------------------


def write_obj(path: str | os.PathLike, mesh: SurfaceMesh) -> None:
    """Wavefront OBJ (text): ``v`` lines, ``vn`` lines when there are normals, 1-based faces."""
    with open(path, "w", encoding="ascii") as f:
        f.write(f"# corpuscle surface mesh: {len(mesh.vertices)} vertices, {len(mesh.triangles)} triangles\n")
        np.savetxt(f, mesh.vertices, fmt="v %.9g %.9g %.9g")
        t = mesh.triangles + 1
        if mesh.normals is not None:
            np.savetxt(f, mesh.normals, fmt="vn %.6g %.6g %.6g")
            np.savetxt(f, np.repeat(t, 2, axis=1), fmt="f %d//%d %d//%d %d//%d")
        else:
            np.savetxt(f, t, fmt="f %d %d %d")


def write_ply(path: str | os.PathLike, mesh: SurfaceMesh) -> None:
    """Binary little-endian PLY: float vertices (and normals), uchar-counted int faces."""
    nv, nt = len(mesh.vertices), len(mesh.triangles)
    names = ["x", "y", "z"] + (["nx", "ny", "nz"] if mesh.normals is not None else [])
    header = ["ply", "format binary_little_endian 1.0", "comment corpuscle surface mesh", f"element vertex {nv}"]
    header += [f"property float {k}" for k in names]
    header += [f"element face {nt}", "property list uchar int vertex_indices", "end_header"]
    vert = np.zeros(nv, [(k, "<f4") for k in names])
    for k, name in enumerate(names[:3]):
        vert[name] = mesh.vertices[:, k]
    if mesh.normals is not None:
        for k, name in enumerate(names[3:]):
            vert[name] = mesh.normals[:, k]
    face = np.zeros(nt, [("n", "u1"), ("i", "<i4", (3,))])
    face["n"] = 3
    face["i"] = mesh.triangles
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(vert.tobytes())
        f.write(face.tobytes())


def write_vtu(path: str | os.PathLike, mesh: SurfaceMesh, field_data: dict | None = None) -> None:
    """VTK XML unstructured grid of triangles (the VTK export's writer), normals as point data ``Normals``."""
    from .export import VTK_TRIANGLE, Part, write_vtu as _write

    nt = len(mesh.triangles)
    part = Part("surface", mesh.vertices, mesh.triangles.reshape(-1).astype(np.int64),
                np.arange(3, 3 * nt + 1, 3, dtype=np.int64), np.full(nt, VTK_TRIANGLE, np.uint8),
                {"Normals": mesh.normals} if mesh.normals is not None else {}, {}, field_data or {})
    _write(Path(path), part)


WRITERS = {"obj": write_obj, "ply": write_ply}


# ---- recorded runs ----------------------------------------------------------------------------


def surface_defaults(header: dict | None, error: type[ValueError] = SurfaceError) -> dict:
    """The reconstruction's defaults for a run (particle radius, smoothing length and cube size
    in radii, threshold), after checking that the run is a 3-D fluid."""
    h = header if isinstance(header, dict) else {}
    kind_name = h.get("kind")
    from . import kinds as _kinds

    kind = _kinds.find(kind_name) if isinstance(kind_name, str) else None
    if kind is not None and not getattr(kind, "fluid", False):
        raise error(f"--format surface needs a fluid (SPH) run; kind '{kind_name}' is not a fluid")
    dim = h.get("dim", kind.dim if kind is not None else None)
    if dim is not None and dim != 3:
        raise error(f"--format surface needs a 3-D fluid; kind '{kind_name}' is {dim}-D")
    out = {"particle_radius": None, "smoothing_length": None, "cube_size": DEFAULT_CUBE, "iso_threshold": DEFAULT_ISO}
    r, support = h.get("particle_radius"), h.get("h")
    if isinstance(r, (int, float)) and not isinstance(r, bool) and math.isfinite(r) and r > 0:
        out["particle_radius"] = float(r)
        if isinstance(support, (int, float)) and not isinstance(support, bool) and math.isfinite(support) and support > 0:
            # splashsurf's support is twice its smoothing length: the run's support h -> h / 2
            out["smoothing_length"] = 0.5 * float(support) / float(r)
    return out


def export_surfaces(run, out_dir, *, mesh: str = "obj", frames=None, particle_radius: float | None = None,
                    smoothing_length: float | None = None, cube_size: float | None = None,
                    iso_threshold: float | None = None, smoothing_iters: int = 0, decimate: bool = False,
                    normals: bool = False, progress: bool | None = None, force: bool | None = None,
                    error: type[ValueError] = SurfaceError, format: str = "surface") -> list[Path]:
    """Reconstruct the fluid surface of each chosen frame of a recorded run into ``out_dir``.

    ``mesh``: ``"obj"``, ``"ply"`` or ``"vtk"`` (``.vtu`` per frame plus ``<run>_surface.pvd``);
    ``frames``: ``"a:b[:step]"`` or a slice (default all); the parameters as :func:`reconstruct`'s
    (``smoothing_iters``: ``--mesh-smoothing``),
    None for the run's defaults (:func:`surface_defaults`). An existing file of another kind is
    replaced only with ``force``. Returns the files written (the .pvd last).
    """
    if format != "surface":  # export_run(format=..., surface={...}): the options of another format
        raise error(f"surface options are for format 'surface', not '{format}'")
    if mesh not in MESH_FORMATS:
        raise error(f"unknown --mesh '{mesh}': choose {', '.join(MESH_FORMATS)}")
    run = open_run(run, error)
    header = run.header or {}
    d = surface_defaults(header, error)
    given = {"particle_radius": particle_radius, "smoothing_length": smoothing_length, "cube_size": cube_size,
             "iso_threshold": iso_threshold}
    par = {}
    for key, value in given.items():
        option = "--" + key.replace("_", "-")
        if value is None:
            value = d[key]
            if value is None:
                raise error(f"the run header gives no {'particle_radius' if key == 'particle_radius' else 'h'}: "
                            f"give {option}")
        par[key] = _number(key, value, error, option)
    iters = _iterations(smoothing_iters, error, "--mesh-smoothing")
    indices = parse_frames(frames, len(run), error)
    ext = MESH_FORMATS[mesh]
    finals = [Path(out_dir) / f"surface_{i:05d}{ext}" for i in indices]
    stem = run_stem(run)
    pvd = Path(out_dir) / f"{stem}_surface.pvd" if mesh == "vtk" else None
    created = missing_dirs(out_dir)
    out = prepare_dir(out_dir, error)
    for p in finals + ([pvd] if pvd else []):
        check_file_output(p, error, force)
    _splashsurf(error)  # before any work: the missing package as a one-line error
    from tqdm import tqdm

    from .export import _group_position

    files = AtomicOutputs()
    written, rows = [], []
    try:
        with tqdm(total=len(indices), unit="frame", desc="surface", leave=False,
                  disable=None if progress is None else not progress) as bar:
            for i, final in zip(indices, finals):
                frame = run[i]
                fields = frame.fields
                groups = dict(getattr(frame, "groups", None) or {})
                key = _group_position(fields, groups, "fluid")
                if key is None:
                    raise error(f"frame {i} has no fluid positions: cannot reconstruct its surface")
                m = reconstruct(fields[key], particle_radius=par["particle_radius"],
                                smoothing_length=par["smoothing_length"], cube_size=par["cube_size"],
                                iso_threshold=par["iso_threshold"], smoothing_iters=iters, decimate=decimate,
                                normals=normals, error=_frame_error(error, i))
                if mesh == "vtk":
                    write_vtu(files.path(final), m, {"TimeValue": np.array([float(frame.time)]),
                                                      "step": np.array([int(frame.step)], np.int64)})
                    rows.append((float(frame.time), final.name))
                else:
                    WRITERS[mesh](files.path(final), m)
                written.append(final)
                bar.update(1)
            if pvd is not None:
                from xml.sax.saxutils import quoteattr

                body = "\n".join(f'<DataSet timestep="{t!r}" part="0" name="surface" file={quoteattr(f)}/>'
                                 for t, f in rows)
                files.path(pvd).write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="1.0" '
                                           'byte_order="LittleEndian">\n<Collection>\n' + body +
                                           "\n</Collection>\n</VTKFile>\n")
                written.append(pvd)
        files.commit()
    except BaseException as exc:
        files.discard()
        remove_dirs(created)
        if isinstance(exc, OSError):
            raise write_failure(error, f"cannot write into {out}: {os_reason(exc)}", exc) from None
        raise
    return written


def _frame_error(error: type[ValueError], index: int) -> type[ValueError]:
    """``error`` whose messages start with the frame they are about."""

    class FrameError(error):  # type: ignore[misc, valid-type]
        def __init__(self, message: str):
            super().__init__(f"frame {index}: {message}")

    FrameError.__name__ = error.__name__
    return FrameError


# ---- the options of `corpuscle export --format surface` ---------------------------------------

# (attribute of the parsed options = the keyword of export_surfaces)
SURFACE_OPTIONS = ("mesh", "particle_radius", "smoothing_length", "cube_size", "iso_threshold", "smoothing_iters",
                   "decimate", "normals")


def configure_surface_options(p) -> None:
    """Add the surface options to ``corpuscle export``'s parser."""
    s = p.add_argument_group("surface (--format surface; splashsurf's parameters, defaults from the run)")
    s.add_argument("--mesh", metavar="obj|ply|vtk", help="mesh file format (default obj; vtk: .vtu per frame and a .pvd)")
    s.add_argument("--particle-radius", metavar="M", help="particle radius in metres (default: the run's, half the spacing)")
    s.add_argument("--smoothing-length", metavar="RADII",
                   help="kernel smoothing length in particle radii; the support is twice it (default: the run's h / 2)")
    s.add_argument("--cube-size", metavar="RADII", help="marching-cubes cell size in particle radii (default 1)")
    s.add_argument("--iso-threshold", metavar="X", help="colour-field value of the surface (default 0.6)")
    s.add_argument("--mesh-smoothing", dest="smoothing_iters", metavar="N",
                   help="weighted Laplacian smoothing iterations of the mesh (default 0)")
    s.add_argument("--decimate", action="store_true", help="remove marching-cubes barnacles (decimation)")
    s.add_argument("--normals", action="store_true", help="write vertex normals (from the colour field's gradient)")


def _option_name(key: str) -> str:
    return "--mesh-smoothing" if key == "smoothing_iters" else "--" + key.replace("_", "-")


def run_surface_command(args, error: type[ValueError]) -> int | None:
    """``corpuscle export --format surface``: the meshes and one summary line unless quiet (the
    exit code); None for another format, which refuses the surface options."""
    surface = {k: getattr(args, k) for k in SURFACE_OPTIONS if getattr(args, k, None) not in (None, False)}
    if args.format != "surface":
        if surface:
            raise error(f"{_option_name(next(iter(surface)))} is an option of --format surface only")
        return None
    paths = export_surfaces(args.run, args.output, frames=args.frames, progress=False if args.quiet else None,
                            error=error, **surface)
    if not args.quiet:
        meshes = [p for p in paths if p.suffix != ".pvd"]
        print(f"wrote {len(meshes)} surface mesh{'es' if len(meshes) != 1 else ''} into {args.output}"
              + (f" ({paths[-1].name} opens them as a series)" if paths[-1].suffix == ".pvd" else ""))
    return 0
