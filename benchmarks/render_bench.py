"""Renderer timings: one 1280x720 frame of 1,000,000 random particles, and a 300-frame video.

Not a test. Run from a checkout with the package importable, e.g.

    OMP_NUM_THREADS=2 python benchmarks/render_bench.py [--run RUN.cps]

Frame: a 3-D scene (unit-cube container, particles of half the mean spacing, lit sphere splats with a depth buffer, colour by speed,
overlay and colour bar), warmed up, then the median of 7 renders. Video: 300 frames of a
3,500-particle Magic 8-Ball-like run (or the frames of --run, cycled to 300) rendered to an
H.264 .mp4 at 1280x720, wall time from opening the run to the closed file.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))

from corpuscle import _render  # noqa: E402
from corpuscle.render import FrameRenderer, render_run  # noqa: E402


def frame_bench(n: int, radius: float, size=(1280, 720), repeats: int = 7) -> dict:
    """Median time of FrameRenderer.render and of the bare splat for n random particles in a unit cube."""
    rng = np.random.default_rng(0)
    pos = (rng.random((n, 3), dtype=np.float32) - 0.5)
    vel = rng.standard_normal((n, 3)).astype(np.float32)
    header = {"scene": "bench", "dim": 3, "container": {"type": "box", "min": [-0.5] * 3, "max": [0.5] * 3},
              "particle_radius": radius}
    frame = SimpleNamespace(fields={"position": pos, "velocity": vel}, groups={}, rigid={}, time=0.0, step=0)
    r = FrameRenderer(header, size=size)
    r.render(frame)  # warm-up (and colour range)
    full = []
    for _ in range(repeats):
        t = time.perf_counter()
        r.render(frame)
        full.append(time.perf_counter() - t)
    img = r._background.copy()
    depth = np.full(size[::-1], np.inf, np.float32)
    lo, hi = r._trange
    bare = []
    for _ in range(repeats):
        depth[:] = np.inf
        t = time.perf_counter()
        _render.splat(img, depth, pos, vel, r.camera.packed(), False, radius, 0.75, r.lut, lo, hi, 0,
                      np.zeros(3, np.uint8), np.zeros(3, np.uint8), True, True)
        bare.append(time.perf_counter() - t)
    px = radius * r.camera.focal / float(np.linalg.norm(r.camera.eye - r.target))
    return {"n": n, "frame_s": statistics.median(full), "splat_s": statistics.median(bare), "radius_px": px}


def write_synthetic_run(path: Path, frames: int = 300, n: int = 3500) -> None:
    """A Magic 8-Ball-like run: fluid sloshing in the sphere, a tumbling die."""
    from corpuscle.io import FrameWriter

    rng = np.random.default_rng(1)
    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    base = d * 0.14 * rng.random((n, 1)) ** (1 / 3)
    faces = {"1": [1, 0, 0], "6": [-1, 0, 0], "2": [0, 1, 0], "5": [0, -1, 0], "3": [0, 0, 1], "4": [0, 0, -1]}
    header = {"scene": "magic8ball", "kind": "magic8ball", "dim": 3, "parameters": {"gravity": {"g": [0, 0, -9.81]}},
              "container": {"type": "sphere", "center": [0, 0, 0], "radius": 0.15},
              "bodies": [{"name": "die", "shape": "box", "half_extents": [0.032] * 3, "faces": faces}],
              "particle_radius": 0.0075, "h": 0.05}
    with FrameWriter(path, header) as w:
        for k in range(frames):
            a = 0.05 * k
            shift = 0.01 * np.array([np.sin(a), np.cos(1.3 * a), 0.0])
            pos = base + shift
            pos *= np.minimum(1.0, 0.145 / np.linalg.norm(pos, axis=1))[:, None]
            vel = rng.standard_normal((n, 3)) * 0.1
            q = np.array([np.cos(a / 2), 0.3 * np.sin(a / 2), 0.5 * np.sin(a / 2), 0.81 * np.sin(a / 2)])
            w.write_frame(10 * k, k / 30, 1e-3, {"position": pos.astype(np.float32), "velocity": vel.astype(np.float32),
                                                  "density": np.full(n, 1000, np.float32)},
                          rigid={"die": {"position": np.array([0, 0, -0.02]), "orientation": q / np.linalg.norm(q)}})


def video_bench(run: Path | None, out: Path, frames: int = 300) -> dict:
    """Wall time of rendering ``frames`` frames to .mp4 (the run's frames cycled if fewer)."""
    tmp = Path(tempfile.mkdtemp())
    if run is None:
        run = tmp / "synthetic.cps"
        write_synthetic_run(run, frames)
    import corpuscle

    r = corpuscle.open(run)
    if len(r) < frames:
        # repeat the run's frames into a longer stream so the video has `frames` frames
        from corpuscle.io import FrameWriter

        longer = tmp / "cycled.cps"
        with FrameWriter(longer, r.header) as w:
            for k in range(frames):
                f = r[k % len(r)]
                w.write_frame(k, k / 30, f.dt, dict(f.fields), groups=dict(f.groups), rigid=f.rigid)
        run = longer
    t = time.perf_counter()
    res = render_run(run, out, size=(1280, 720), fps=30, progress=False)
    return {"frames": res.frames, "video_s": time.perf_counter() - t, "particles": len(corpuscle.open(run)[0].fields["position"])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", type=Path, help="a recorded run for the video timing (default: a synthetic one)")
    ap.add_argument("--particles", type=int, default=1_000_000)
    ap.add_argument("--radius", type=float, help="particle radius in the unit cube (default: half the mean spacing)")
    args = ap.parse_args()
    radius = args.radius or 0.5 * args.particles ** (-1 / 3)
    print(f"threads: {_render.max_threads()} (OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')})")
    fb = frame_bench(args.particles, radius)
    print(f"frame: {fb['n']:,} particles at 1280x720 (radius {fb['radius_px']:.2f} px): "
          f"render {fb['frame_s'] * 1e3:.1f} ms, splat alone {fb['splat_s'] * 1e3:.1f} ms (median of 7)")
    with tempfile.TemporaryDirectory() as d:
        vb = video_bench(args.run, Path(d) / "bench.mp4")
    print(f"video: {vb['frames']} frames of {vb['particles']:,} particles at 1280x720 to .mp4: "
          f"{vb['video_s']:.1f} s ({vb['video_s'] / vb['frames'] * 1e3:.1f} ms per frame)")


if __name__ == "__main__":
    main()
