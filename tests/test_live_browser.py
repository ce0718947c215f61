"""The live viewer's page in headless Chromium (Playwright from PyPI driving Debian's
`chromium`, or Playwright's own browser where one is installed): the page loads, draws
particles, counts frames, sends shake keys into the simulation and scrubs a recorded run.
Skipped, with the reason, where no Chromium is available (`.ci/run` installs Debian's)."""
from __future__ import annotations

import asyncio  # noqa: F401 - the server tests' helpers are shared
import io
import os
import shutil
import subprocess
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
