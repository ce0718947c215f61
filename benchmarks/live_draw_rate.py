"""Frames per second the live viewer's page draws in a browser, over localhost: a producer
thread publishes fresh synthetic frames (no simulation) as fast as the server takes them, the
server quantises and sends the latest, headless Chromium (Playwright) receives, uploads and
draws them; the page's own counters (performance.now()) give the rates.

Three figures per size: "end to end" (frames received and drawn per second while the producer
runs; the page acknowledges each frame it draws and the server sends at most two ahead),
"transfer only" (the same with the particles' draw call skipped: sending, receiving, decoding
and uploading) and "draw only" (the page redraws its last frame on every animation frame, no
transfer).
The WebGL renderer is printed: in headless Chromium without a GPU it is SwiftShader, a CPU
software rasteriser, so the figures are CPU figures (they share this machine's cores with the
server and the producer).

    python benchmarks/live_draw_rate.py [N ...] [--seconds S] [--dim 2|3] [--size WxH]
        [--chromium PATH] [--gpu]      # --gpu: leave Chromium's own GL choice (no SwiftShader flags)
"""
from __future__ import annotations

import argparse
import os
import shutil
import threading
import time

import numpy as np

from corpuscle.live import LiveServer

SWIFTSHADER = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox", "--disable-gpu-sandbox"]
HEADERS = {
    3: {"scene": "bench", "kind": "bench", "dim": 3, "container": {"type": "sphere", "center": [0, 0, 0], "radius": 0.15},
        "particle_radius": 0.0015},
    2: {"scene": "bench", "kind": "bench", "dim": 2, "container": {"type": "box", "min": [-1.78, -1.0], "max": [1.78, 1.0]},
        "particle_radius": 0.0015},
}

MEASURE = """async (seconds) => {
  const v = window.corpuscleViewer, t0 = performance.now(), r0 = v.framesReceived, d0 = v.drawn, w0 = v.redraws;
  await new Promise((ok) => setTimeout(ok, seconds * 1000));
  const dt = (performance.now() - t0) / 1000;
  return {received: (v.framesReceived - r0) / dt, drawn: (v.drawn - d0) / dt, redraws: (v.redraws - w0) / dt};
}"""


def frames(n: int, dim: int, k: int = 4):
    rng = np.random.default_rng(0)
    h = HEADERS[dim]["container"]
    if dim == 3:
        pos = [rng.uniform(-0.14, 0.14, size=(n, 3)).astype(np.float32) for _ in range(k)]
    else:
        pos = [rng.uniform(h["min"], h["max"], size=(n, 2)).astype(np.float32) for _ in range(k)]
    col = [rng.uniform(900, 1100, size=n).astype(np.float32) for _ in range(k)]
    return pos, col


def measure(page, n: int, dim: int, seconds: float) -> dict:
    pos, col = frames(n, dim)
    s = LiveServer(dict(HEADERS[dim]), port=0, log=lambda line: None).start()
    stop = threading.Event()

    def produce():
        i = 0
        while not stop.is_set():
            s.publish({"index": i, "step": i, "time": i * 1e-3, "positions": pos[i % 4],
                       "fields": {"density": col[i % 4]}, "overlay": {}})
            i += 1
            time.sleep(0.002)

    s.publish({"index": 0, "step": 0, "time": 0.0, "positions": pos[0], "fields": {"density": col[0]}, "overlay": {}})
    t = threading.Thread(target=produce, daemon=True)
    try:
        page.goto(s.url)
        page.wait_for_function("window.corpuscleViewer.framesReceived >= 1", timeout=120_000)
        t.start()
        page.wait_for_timeout(2000)  # warm-up
        e2e = page.evaluate(MEASURE, seconds)
        page.evaluate("window.corpuscleViewer.skipParticles = true")
        page.wait_for_timeout(1000)
        transfer = page.evaluate(MEASURE, seconds)
        page.evaluate("window.corpuscleViewer.skipParticles = false")
        stop.set()
        t.join()
        page.evaluate("window.corpuscleViewer.redraw = true")
        page.wait_for_timeout(1000)
        only = page.evaluate(MEASURE, seconds)
        page.evaluate("window.corpuscleViewer.redraw = false")
        renderer = page.evaluate("window.corpuscleViewer.renderer")
    finally:
        stop.set()
        if t.is_alive():
            t.join()
        s.stop()
    return {"particles": n, "dim": dim, "received": e2e["received"], "drawn": e2e["drawn"],
            "transfer": transfer["received"],
            "draw_only": only["redraws"], "renderer": renderer, "published": s.published}


def main() -> None:
    from playwright.sync_api import sync_playwright

    ap = argparse.ArgumentParser()
    ap.add_argument("n", nargs="*", type=int, default=[100_000, 1_000_000])
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--dim", type=int, choices=(2, 3), default=3)
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--chromium", default=os.environ.get("CORPUSCLE_CHROMIUM") or shutil.which("chromium"))
    ap.add_argument("--gpu", action="store_true", help="no SwiftShader flags: Chromium picks its GL (a GPU if it may)")
    ap.add_argument("--chromium-arg", action="append", default=[], help="a further Chromium flag (repeatable)")
    ap.add_argument("--radius", type=float, default=None, help="particle radius (m; default 0.0015, the 8-ball's scale)")
    args = ap.parse_args()
    w, h = (int(x) for x in args.size.split("x"))
    if args.radius is not None:
        for hd in HEADERS.values():
            hd["particle_radius"] = args.radius
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=args.chromium, args=(["--ignore-gpu-blocklist"] if args.gpu else SWIFTSHADER) + args.chromium_arg)
        page = browser.new_context(viewport={"width": w, "height": h}, bypass_csp=True).new_page()  # wait_for_function evaluates
        try:
            for n in args.n:
                r = measure(page, n, args.dim, args.seconds)
                print(f"{r['particles']:>10,} particles ({r['dim']}-D, {w}x{h}): end to end {r['received']:6.1f} frames/s "
                      f"received, {r['drawn']:6.1f} drawn; transfer only {r['transfer']:6.1f}; draw only {r['draw_only']:6.1f} "
                      "frames/s", flush=True)
        finally:
            browser.close()
    print(f"renderer: {r['renderer']}; load average {load:.2f} on {os.cpu_count()} CPUs")


if __name__ == "__main__":
    main()
