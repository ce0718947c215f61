"""The live viewer's page in headless Chromium (Playwright from PyPI driving Debian's
`chromium`, or Playwright's own browser where one is installed): the page loads, draws
particles, counts frames, sends shake keys and drags into the simulation's control (no
rebuild), pauses and resumes the run, scrubs a recorded run; draws the wind tunnel's airfoil
(filled where it is, turned by its pitch), shows lift and drag, and its sliders steer the
inflow speed and the angle of attack; pans and zooms in 2-D; draws kinds it has never seen
from their headers. Skipped, with the reason, where no Chromium is available (`.ci/run`
installs Debian's)."""
from __future__ import annotations

import asyncio  # noqa: F401 - the server tests' helpers are shared
import io
import os
import shutil
import math
import subprocess
import threading
import time

import numpy as np
import pytest

pytest.importorskip("aiohttp", reason='the live viewer needs aiohttp (pip install ".[viewer]")')
playwright_api = pytest.importorskip("playwright.sync_api", reason='Playwright is not installed (pip install ".[test]")')

from cli_script import script  # noqa: E402
from test_live_server import Log, _Proc, _sim  # noqa: E402

from corpuscle.live import LiveServer, RunViewer  # noqa: E402

ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox", "--disable-gpu-sandbox"]


def _chromium() -> str | None:
    """Debian's chromium (or CORPUSCLE_CHROMIUM), else None: Playwright's own is tried next."""
    env = os.environ.get("CORPUSCLE_CHROMIUM")
    if env:
        return env
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


@pytest.fixture(scope="module")
def browser():
    pw = playwright_api.sync_playwright().start()
    exe = _chromium()
    try:
        b = pw.chromium.launch(executable_path=exe, args=ARGS) if exe else pw.chromium.launch(args=ARGS)
    except Exception as exc:  # noqa: BLE001 - no browser is a skip, with the reason
        pw.stop()
        pytest.skip(f"no headless Chromium to drive (install Debian's `chromium`): {' '.join(str(exc).split())[:200]}")
    yield b
    b.close()
    pw.stop()


@pytest.fixture
def page(browser):
    ctx = browser.new_context(viewport={"width": 800, "height": 500}, bypass_csp=True)  # wait_for_function evaluates
    pg = ctx.new_page()
    errors: list[str] = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    pg.errors = errors
    yield pg
    ctx.close()


def _stats(png: bytes) -> tuple[float, float]:
    """Share of pixels that are not the background, and the pixels' standard deviation."""
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.float64)
    bg = np.array([20, 22, 28], dtype=np.float64)
    differs = np.abs(img - bg).sum(axis=2) > 30
    return float(differs.mean()), float(img.std())


def test_page_loads_draws_particles_and_counts_frames(page, tmp_path):
    proc = _Proc("run", "magic8ball", "--backend", "serial", "--particles", "1500", "--steps", "1000000", "--every", "10",
                 "--live", "--port", "0", "--out", str(tmp_path / "live.cps"), "--no-progress")
    try:
        page.goto(proc.url)
        page.wait_for_function("window.corpuscleViewer.framesReceived >= 2", timeout=60_000)
        first = int(page.text_content("#frame-counter"))
        page.wait_for_function(f"window.corpuscleViewer.framesReceived > {first + 1}", timeout=60_000)
        assert int(page.text_content("#frame-counter")) > first  # the counter advances
        time.sleep(0.3)
        share, std = _stats(page.locator("#view").screenshot())
        assert share > 0.05 and std > 10, (share, std)  # not blank: particles, container, die
        assert "magic8ball" in page.text_content("#title") and page.text_content("#particle-count") == "1,500"
        assert page.text_content("#answer").strip()
        assert page.evaluate("window.corpuscleViewer.errors") == [] and page.errors == []
        page.evaluate("window.corpuscleViewer.setSize(0.5)")  # the size slider: smaller spheres, the die shows
        assert page.text_content("#size-value") == "0.50×"
        page.wait_for_timeout(300)
        share2, _ = _stats(page.locator("#view").screenshot())
        assert share2 < share  # less of the canvas covered
        if os.environ.get("CORPUSCLE_SCREENSHOT"):  # docs/live.png
            page.screenshot(path=os.environ["CORPUSCLE_SCREENSHOT"])
    finally:
        proc.interrupt()


def test_a_shake_key_changes_the_die_velocity(page):
    sim, twin = _sim(), _sim()
    s = LiveServer(sim.header(), port=0, controls={k: int(v) for k, v in dict(sim.core.controls()).items()},
                   log=Log()).start()
    viewer = RunViewer(s)
    try:
        viewer.publish(sim, sim.frame())
        page.goto(s.url)
        page.wait_for_function("window.corpuscleViewer.framesReceived >= 1", timeout=30_000)
        for _ in range(5):
            page.keyboard.press("d")  # +x acceleration, 2 m/s² a press
        page.keyboard.press("o")  # +z torque
        deadline = time.time() + 10
        while s.accepted < 6 and time.time() < deadline:
            time.sleep(0.02)
        viewer.between_chunks(sim)  # what the run loop does between chunks
        assert viewer.control == {"acceleration": [10.0, 0.0, 0.0], "torque": [0.0, 0.0, 0.005]}
        assert "a=(10.000, 0.000, 0.000)" in page.text_content("#control")
        sim.step(150)
        twin.step(150)
        v, v0 = np.asarray(sim.state()["die"]["velocity"]), np.asarray(twin.state()["die"]["velocity"])
        assert np.linalg.norm(v - v0) > 1e-4, (v, v0)
        page.keyboard.press(" ")  # space clears
        deadline = time.time() + 10
        while s.accepted < 7 and time.time() < deadline:
            time.sleep(0.02)
        viewer.between_chunks(sim)
        assert viewer.control == {"acceleration": [0.0, 0.0, 0.0], "torque": [0.0, 0.0, 0.0]}
        assert s.rejected == 0 and page.errors == []
    finally:
        s.stop()


def test_a_recorded_run_scrubs_to_a_chosen_frame(page, tmp_path):
    out = tmp_path / "rec.cps"
    p = subprocess.run([script(), "run", "magic8ball", "--backend", "serial", "--particles", "300", "--steps", "400",
                        "--every", "100", "--out", str(out), "--no-progress"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    proc = _Proc("view", str(out), "--port", "0")
    try:
        page.goto(proc.url)
        page.wait_for_function("window.corpuscleViewer.framesReceived >= 1", timeout=30_000)
        assert page.is_visible("#playback") and page.get_attribute("#scrub", "max") == "4"
        page.evaluate("() => { const s = document.getElementById('scrub'); s.value = 3;"
                      " s.dispatchEvent(new Event('input')); }")
        page.wait_for_function("window.corpuscleViewer.lastIndex === 3", timeout=30_000)
        assert page.text_content("#frame-index") == "4/5" and page.text_content("#sim-step") == "300"
        page.click("#play")  # plays on to the last frame and stops there
        page.wait_for_function("window.corpuscleViewer.lastIndex === 4", timeout=30_000)
        assert page.errors == []
    finally:
        assert proc.interrupt() == 0


def test_the_page_needs_the_token_off_localhost(page):
    s = LiveServer({"dim": 3, "container": None}, host="0.0.0.0", port=0, token="tok-123", log=Log()).start()
    try:
        s.publish({"index": 0, "step": 0, "time": 0.0, "positions": np.zeros((10, 3), np.float32), "fields": {},
                   "overlay": {}})
        r = page.goto(f"http://127.0.0.1:{s.port}/")
        assert r.status == 403
        page.goto(f"http://127.0.0.1:{s.port}/?token=tok-123")
        page.wait_for_function("window.corpuscleViewer.framesReceived >= 1", timeout=30_000)
        assert s.rejected == 1
    finally:
        s.stop()


# ---- steering, every kind ------------------------------------------------------------------


def _wait(cond, timeout=10.0):
    deadline = time.time() + timeout
    while not cond() and time.time() < deadline:
        time.sleep(0.02)
    return cond()


def _live(sim):
    """A live server for ``sim`` (as `run --live` starts one) with its first frame."""
    viewer = RunViewer.start(sim, sim.header(), port=0)
    viewer.server.log = Log()
    viewer.publish(sim, sim.frame())
    return viewer


def test_dragging_shakes_the_container_through_its_control_without_a_rebuild(page):
    sim, twin = _sim(), _sim()
    viewer = _live(sim)
    s = viewer.server
    try:
        page.goto(s.url)
        page.wait_for_function("window.corpuscleViewer.framesReceived >= 1", timeout=30_000)
        assert page.is_visible("#shake-help")
        box = page.locator("#view").bounding_box()
        cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        page.keyboard.down("Shift")  # shift-drag shakes; a plain drag orbits
        page.mouse.move(cx, cy)
        page.mouse.down()
        page.mouse.move(cx + 120, cy, steps=6)  # 120 px to the right: 30 m/s² along the screen's right
        assert _wait(lambda: s.accepted >= 1 and s._control is not None)
        time.sleep(0.15)  # the throttled last message of the drag
        rebuilds = sim.scalars()["rebuilds"]
        viewer.between_chunks(sim)  # what the run loop does between chunks
        a = np.asarray(sim.control["acceleration"])
        right = np.asarray(page.evaluate("(() => { const v = window.corpuscleViewer; return [0, 1, 2].map(i =>"
                                         " v.toPixel([i === 0 ? 0.1 : 0, i === 1 ? 0.1 : 0, i === 2 ? 0.1 : 0])[0]"
                                         " - v.toPixel([0, 0, 0])[0]); })()"))
        # along the drag: the acceleration points where the screen's right is (its x pixels grow)
        assert np.linalg.norm(a) == pytest.approx(30.0, rel=0.05) and float(a @ right) > 0.9 * np.linalg.norm(a) * np.linalg.norm(right)
        assert sim.scalars()["rebuilds"] == rebuilds  # setting the control rebuilds nothing
        assert sim.control["torque"] == [0.0, 0.0, 0.0]
        sim.step(150)
        twin.step(150)
        v, v0 = np.asarray(sim.state()["die"]["velocity"]), np.asarray(twin.state()["die"]["velocity"])
        assert np.linalg.norm(v - v0) > 1e-4, (v, v0)
        n = s.accepted
        page.mouse.up()  # the shake stops on release
        page.keyboard.up("Shift")
        assert _wait(lambda: s.accepted > n)
        viewer.between_chunks(sim)
        assert sim.control["acceleration"] == [0.0, 0.0, 0.0]
        # a plain drag orbits the camera and sends nothing
        n = s.accepted
        az = page.evaluate("window.corpuscleViewer.cam.az")
        page.mouse.move(cx, cy)
        page.mouse.down()
        page.mouse.move(cx + 80, cy + 10, steps=4)
        page.mouse.up()
        time.sleep(0.2)
        assert s.accepted == n and page.evaluate("window.corpuscleViewer.cam.az") != az
        assert s.rejected == 0 and page.errors == [] and page.evaluate("window.corpuscleViewer.errors") == []
    finally:
        s.stop()


def test_pause_and_resume_from_the_page(page):
    sim = _sim()
    viewer = _live(sim)
    s = viewer.server
    try:
        page.goto(s.url)
        page.wait_for_function("window.corpuscleViewer.framesReceived >= 1", timeout=30_000)
        page.click("#pause")
        assert _wait(lambda: s.paused)
        assert page.text_content("#pause") == "resume" and page.text_content("#status") == "paused"
        t = threading.Thread(target=viewer.between_chunks, args=(sim,), daemon=True)
        t.start()
        time.sleep(0.3)
        assert t.is_alive() and int(sim.steps) == 0  # the run waits, stepping nothing
        page.wait_for_function("window.corpuscleViewer.frame.meta.paused === true", timeout=10_000)
        page.keyboard.press("p")  # P resumes
        t.join(10)
        assert not t.is_alive() and not s.paused and page.text_content("#pause") == "pause"
    finally:
        s.stop()


def _wind_tunnel(particles=600, **ov):
    simulation = pytest.importorskip("corpuscle.simulation", reason="the compiled core is not built")
    from corpuscle.scene import load_scene

    return simulation.Simulation.from_scene(load_scene("wind-tunnel"), backend="serial", particles=particles,
                                            overrides={"inflow.speed": 1.0, **{k.replace("__", "."): v for k, v in ov.items()}})


def _pixel(png: bytes, xy) -> np.ndarray:
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.float64)
    x, y = int(round(xy[0])), int(round(xy[1]))
    return img[y - 1:y + 2, x - 1:x + 2].reshape(-1, 3).mean(axis=0)


def test_the_wind_tunnel_draws_its_airfoil_shows_lift_and_drag_and_its_sliders_steer_it(page):
    from corpuscle.kinds import wind_tunnel as wt

    sim = _wind_tunnel(airfoil__angle_of_attack=8.0)
    sim.step(20)
    viewer = _live(sim)
    s = viewer.server
    try:
        page.goto(s.url)
        page.wait_for_function("window.corpuscleViewer.framesReceived >= 1", timeout=30_000)
        assert "wind-tunnel" in page.text_content("#title") and "2-D" in page.text_content("#title")
        assert page.evaluate("window.corpuscleViewer.obstaclesDrawn") == 1
        # the airfoil is filled where it is: its interior's pixels are the obstacle's grey,
        # and the channel's walls are drawn
        poly = sim.info["airfoil"]
        inner = poly.mean(axis=0)  # inside the section (a thick part of it)
        assert wt.signed_distance(poly, inner[None])[0] < -0.01
        shot = page.locator("#view").screenshot()
        xy = page.evaluate(f"window.corpuscleViewer.toPixel([{inner[0]}, {inner[1]}])")
        assert np.abs(_pixel(shot, xy) - [199, 204, 214]).max() < 20, _pixel(shot, xy)
        share, std = _stats(shot)
        assert share > 0.02 and std > 5
        # this frame's lift and drag, with their units
        d = sim.diagnostics()
        assert page.text_content("#lift").endswith("N/m") and page.text_content("#drag").endswith("N/m")
        assert float(page.text_content("#lift").split()[0]) == pytest.approx(d["lift"], rel=1e-3, abs=1e-9)
        # the sliders: the angle of attack by the keyboard (four steps of 0.5 degrees), the speed set
        assert page.is_visible("#slider-pitch-0") and page.is_visible("#slider-speed_scale-0")
        page.focus("#slider-pitch-0")
        for _ in range(4):
            page.keyboard.press("ArrowRight")
        page.evaluate("() => { const e = document.getElementById('slider-speed_scale-0'); e.value = 1.5;"
                      " e.dispatchEvent(new Event('input')); }")
        assert _wait(lambda: s.accepted >= 2 and (s._current["pitch"], s._current["speed_scale"]) == ([2.0], [0.5]))
        time.sleep(0.1)
        viewer.between_chunks(sim)
        assert sim.control == {"speed_scale": [0.5], "pitch": [2.0]}
        sim.step(5)
        viewer.publish(sim, sim.frame())
        page.wait_for_function("window.corpuscleViewer.frame.meta.diagnostics.pitch === 2"
                               " && window.corpuscleViewer.drawnIndex === window.corpuscleViewer.frame.index",
                               timeout=10_000)
        # the airfoil is drawn turned by the pitch: nose up, about the quarter chord
        outline = np.asarray(page.evaluate("window.corpuscleViewer.obstacleOutline(0)")).reshape(-1, 3)[::2, :2]
        q = np.asarray(sim.params["quarter_chord"])
        t = math.radians(-2.0)
        expect = q + (poly - q) @ np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]]).T
        assert np.abs(outline - expect).max() < 1e-5
        assert page.text_content("#slider-pitch-0 + .slider-value") == "10.0 °"
        # an out-of-range control from a page is rejected and logged, the run's control stays
        page.evaluate("() => { const e = document.getElementById('slider-pitch-0'); e.max = 200; e.value = 150;"
                      " e.dispatchEvent(new Event('input')); }")
        assert _wait(lambda: s.rejected >= 1)
        assert "outside" in s.log[-1] and s._current["pitch"] == [2.0]
        assert page.errors == [] and page.evaluate("window.corpuscleViewer.errors") == []
    finally:
        s.stop()


def test_2d_pan_and_zoom_keep_the_point_under_the_cursor(page):
    sim = _wind_tunnel(particles=300)
    viewer = _live(sim)
    s = viewer.server
    try:
        page.goto(s.url)
        page.wait_for_function("window.corpuscleViewer.framesReceived >= 1", timeout=30_000)
        box = page.locator("#view").bounding_box()
        p = [-0.9, 0.0]  # near the airfoil
        at = page.evaluate(f"window.corpuscleViewer.toPixel({p})")
        page.mouse.move(box["x"] + at[0], box["y"] + at[1])
        page.mouse.wheel(0, -600)  # zoom in at the cursor
        page.wait_for_function("window.corpuscleViewer.cam.zoom > 1.5", timeout=10_000)
        after = page.evaluate(f"window.corpuscleViewer.toPixel({p})")
        assert np.allclose(after, at, atol=1.0), (at, after)
        far = page.evaluate("window.corpuscleViewer.toPixel([0.5, 0.5])")
        page.mouse.down()
        page.mouse.move(box["x"] + at[0] + 60, box["y"] + at[1] + 20, steps=3)  # drag pans
        page.mouse.up()
        moved = page.evaluate("window.corpuscleViewer.toPixel([0.5, 0.5])")
        assert np.allclose(np.subtract(moved, far), [60, 20], atol=1.0)
        page.dblclick("#view")  # fits the scene again
        page.wait_for_function("window.corpuscleViewer.cam.zoom === 1", timeout=10_000)
        assert s.accepted == 0 and page.errors == []  # a 2-D kind with no acceleration control: no shaking
    finally:
        s.stop()


# a scene kind the page has never seen: drawn from its header alone
OTHER_KINDS = [
    {"scene": "tank", "kind": "dam-break", "dim": 3, "gravity": [0, 0, -9.81],
     "container": {"type": "box", "min": [0, 0, 0], "max": [1.6, 0.6, 0.8]},
     "obstacles": [{"type": "box", "name": "step", "min": [1.0, 0.0, 0.0], "max": [1.2, 0.6, 0.1]}],
     "bodies": [{"name": "ball", "shape": "sphere", "radius": 0.05}], "particle_radius": 0.01},
    {"scene": "flat", "kind": "dam-break-2d", "dim": 2, "gravity": [0, -9.81],
     "container": {"type": "box", "min": [0, 0], "max": [4, 2]},
     "obstacles": [{"type": "box", "name": "gate", "min": [1.8, 0], "max": [2.0, 0.6]},
                   {"type": "circle", "name": "post", "center": [3, 0.5], "radius": 0.2},
                   {"type": "spline", "name": "unknown-shape"}],
     "bodies": [{"name": "crate", "shape": "box", "half_extents": [0.1, 0.1]}], "particle_radius": 0.01},
]


@pytest.mark.parametrize("header", OTHER_KINDS, ids=[h["kind"] for h in OTHER_KINDS])
def test_a_kind_the_page_does_not_know_is_drawn_from_its_header(page, header):
    dim = header["dim"]
    lo, hi = np.asarray(header["container"]["min"]), np.asarray(header["container"]["max"])
    rng = np.random.default_rng(0)
    pos = rng.uniform(lo, lo + 0.4 * (hi - lo), size=(3000, dim)).astype(np.float32)
    rigid = {b["name"]: {"position": list(0.5 * (lo + hi)) + [0.0] * (3 - dim), "orientation": [1, 0, 0, 0]}
             for b in header["bodies"]}
    s = LiveServer(dict(header), port=0, log=Log()).start()
    try:
        s.publish({"index": 0, "step": 0, "time": 0.0, "positions": pos, "fields": {"pressure": pos[:, -1]},
                   "overlay": {"rigid": rigid, "diagnostics": {"kinetic_energy": 1.5}}})
        page.goto(s.url)
        page.wait_for_function("window.corpuscleViewer.framesReceived >= 1", timeout=30_000)
        time.sleep(0.2)
        v = page.evaluate("({o: window.corpuscleViewer.obstaclesDrawn, b: window.corpuscleViewer.bodiesDrawn,"
                          " w: window.corpuscleViewer.warnings, e: window.corpuscleViewer.errors})")
        known = [o for o in header["obstacles"] if o["type"] in ("box", "circle")]
        assert v["o"] == len(known) and v["b"] == 1 and v["e"] == [] and page.errors == []
        assert any("unknown-shape" in w for w in v["w"]) == (len(known) < len(header["obstacles"]))
        share, std = _stats(page.locator("#view").screenshot())
        assert share > 0.03 and std > 5
        assert "kinetic_energy 1.500" in page.text_content("#diagnostics")
        assert page.is_hidden("#forces-line") and page.is_hidden("#shake-help")
        page.wait_for_function("window.corpuscleViewer.drawRate > 0 || window.corpuscleViewer.drawn > 0", timeout=10_000)
    finally:
        s.stop()


def test_a_recorded_wind_tunnel_run_plays_with_its_airfoil_and_forces(page, tmp_path):
    out = tmp_path / "wt.cps"
    p = subprocess.run([script(), "run", "wind-tunnel", "--backend", "serial", "--particles", "400", "--steps", "60",
                        "--every", "20", "--out", str(out), "--no-progress"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    proc = _Proc("view", str(out), "--port", "0")
    try:
        page.goto(proc.url)
        page.wait_for_function("window.corpuscleViewer.framesReceived >= 1", timeout=30_000)
        page.evaluate("window.corpuscleViewer.seek(3)")
        page.wait_for_function("window.corpuscleViewer.lastIndex === 3 && window.corpuscleViewer.drawnIndex === 3",
                               timeout=30_000)
        assert page.evaluate("window.corpuscleViewer.obstaclesDrawn") == 1 and page.is_visible("#forces-line")
        assert page.text_content("#lift").endswith("N/m") and page.is_hidden("#live-controls")
        assert page.errors == [] and page.evaluate("window.corpuscleViewer.errors") == []
    finally:
        assert proc.interrupt() == 0
