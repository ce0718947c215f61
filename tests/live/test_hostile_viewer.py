"""A viewer client that misbehaves, or a web page that is not the viewer's: each case held or
steered a run before its fix.

- a page that pauses the run and goes away must not hold it (the pause is released when the
  last page steering the run is gone);
- a request that names this server by another site's name (DNS rebinding) or another port
  is refused, page and websocket alike, and a live run's page and controls need the token in
  its URL unless the user opted out (``--no-token``).
"""
from __future__ import annotations

import asyncio
import json
import re
import threading
import time

import numpy as np
import pytest

aiohttp = pytest.importorskip("aiohttp", reason='the live viewer needs aiohttp (pip install ".[viewer]")')

from corpuscle.live import LiveServer, RunViewer  # noqa: E402

HEADER = {"scene": "t", "kind": "test", "dim": 3, "container": {"type": "sphere", "center": [0, 0, 0], "radius": 1.0}}
CONTROLS = {"acceleration": 3, "torque": 3}


class Log(list):
    def __call__(self, line):
        self.append(line)


def _frame(i: int = 0) -> dict:
    pos = np.random.default_rng(i).uniform(-0.9, 0.9, size=(50, 3)).astype(np.float32)
    return {"index": i, "step": i, "time": 0.0, "positions": pos, "fields": {}, "overlay": {}}


def _server(**kw) -> LiveServer:
    s = LiveServer(dict(HEADER), port=0, controls=CONTROLS, log=kw.pop("log", Log()), **kw).start()
    s.publish(_frame())
    return s


def _wait(cond, timeout=5.0) -> bool:
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        time.sleep(0.02)
    return cond()


async def _connect(cs, s, token=None):
    ws = await cs.ws_connect(f"ws://127.0.0.1:{s.port}/ws" + (f"?token={token}" if token else ""))
    assert json.loads((await ws.receive(timeout=10)).data)["type"] == "hello"
    return ws


# --- a page that is gone never holds the run ------------------------------------------------

@pytest.mark.parametrize("others", ["alone", "a page that only watches", "after a resume and a pause"])
def test_a_page_that_pauses_and_goes_away_lets_the_run_go(others):
    log = Log()
    s = _server(log=log)
    try:
        async def go():
            async with aiohttp.ClientSession() as cs:
                watcher = await _connect(cs, s) if others == "a page that only watches" else None
                ws = await _connect(cs, s)
                if others == "after a resume and a pause":
                    for kind in ("pause", "resume"):
                        await ws.send_str(json.dumps({"type": kind}))
                await ws.send_str('{"type": "pause"}')
                assert await asyncio.get_running_loop().run_in_executor(None, _wait, lambda: s.paused)
                await ws.close()  # the page is closed (or its tab, or its browser)
                released = await asyncio.get_running_loop().run_in_executor(None, _wait, lambda: not s.paused)
                if watcher is not None:
                    assert not watcher.closed
                    await watcher.close()
                return released

        assert asyncio.run(go()), "the run stayed paused by a page that is gone"
        assert any("pause released" in line for line in log), log
    finally:
        s.stop()


def test_a_pause_holds_while_another_page_steering_the_run_is_there():
    s = _server()
    try:
        async def go():
            async with aiohttp.ClientSession() as cs:
                a, b = await _connect(cs, s), await _connect(cs, s)
                await b.send_str('{"type": "control", "acceleration": [1, 0, 0]}')
                await a.send_str('{"type": "pause"}')
                loop = asyncio.get_running_loop()
                assert await loop.run_in_executor(None, _wait, lambda: s.paused)
                await a.close()
                await asyncio.sleep(0.3)
                held = s.paused  # b steers the run too, and may resume it
                await b.close()
                return held, await loop.run_in_executor(None, _wait, lambda: not s.paused)

        assert asyncio.run(go()) == (True, True)
    finally:
        s.stop()


def test_a_run_paused_by_a_page_that_is_gone_goes_on_stepping():
    corpuscle = pytest.importorskip("corpuscle")
    pytest.importorskip("corpuscle._core")
    sim = corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=300)
    viewer = RunViewer.start(sim, sim.header(), port=0)
    viewer.server.log = Log()
    viewer.publish(sim, sim.frame())
    token = re.search(r"token=([\w-]+)", viewer.url).group(1)
    try:
        async def pause_and_leave():
            async with aiohttp.ClientSession() as cs:
                ws = await _connect(cs, viewer.server, token)
                await ws.send_str('{"type": "pause"}')
                assert await asyncio.get_running_loop().run_in_executor(None, _wait, lambda: viewer.server.paused)

        asyncio.run(pause_and_leave())
        t = threading.Thread(target=viewer.between_chunks, args=(sim,), daemon=True)
        t.start()
        t.join(5)
        assert not t.is_alive(), "the run waits for a page that is gone"
    finally:
        viewer.close()


# --- another site cannot reach or steer the run --------------------------------------------

HOSTILE_HOSTS = [  # Host header (and the Origin a rebinding page sends with it)
    "evil.example:{port}",            # another site's name, rebound to 127.0.0.1
    "127.0.0.1.nip.io:{port}",        # a public name for the loopback address
    "localhost.evil.example:{port}",
    "127.0.0.1:1",                    # another port: another server's page
    "[::1]:1",
    "",
]


@pytest.mark.parametrize("host", HOSTILE_HOSTS)
def test_a_request_for_another_name_or_port_is_refused(host):
    log = Log()
    s = _server(log=log)
    try:
        host = host.format(port=s.port)
        headers = {"Host": host, "Origin": f"http://{host}"}

        async def go():
            async with aiohttp.ClientSession() as cs:
                for path in ("/", "/static/viewer.js"):
                    async with cs.get(f"http://127.0.0.1:{s.port}{path}", headers=headers) as r:
                        assert r.status == 403, (path, r.status)
                with pytest.raises(aiohttp.WSServerHandshakeError) as info:
                    await cs.ws_connect(f"ws://127.0.0.1:{s.port}/ws", headers=headers)
                assert info.value.status == 403
                # this server's own names still work, with their own origin
                for own in (f"127.0.0.1:{s.port}", f"localhost:{s.port}", f"[::1]:{s.port}"):
                    async with cs.get(f"http://127.0.0.1:{s.port}/", headers={"Host": own}) as r:
                        assert r.status == 200, own
                    ws = await cs.ws_connect(f"ws://127.0.0.1:{s.port}/ws",
                                             headers={"Host": own, "Origin": f"http://{own}"})
                    await ws.close()
                # ... but not from a page of another port or site, nor one without an origin of its own
                for origin in (f"http://127.0.0.1:{s.port + 1}", "http://evil.example", "null",
                               f"http://127.0.0.1:{s.port}/x", f"file://127.0.0.1:{s.port}"):
                    with pytest.raises(aiohttp.WSServerHandshakeError) as info:
                        await cs.ws_connect(f"ws://127.0.0.1:{s.port}/ws",
                                            headers={"Host": f"127.0.0.1:{s.port}", "Origin": origin})
                    assert info.value.status == 403, origin

        asyncio.run(go())
        assert s.accepted == 0 and all("\n" not in line for line in log) and len(log) >= 3
    finally:
        s.stop()


def test_a_live_run_needs_its_token_to_be_steered_unless_the_user_opted_out():
    corpuscle = pytest.importorskip("corpuscle")
    pytest.importorskip("corpuscle._core")
    sim = corpuscle.Simulation.from_scene("magic8ball", backend="serial", particles=300)
    viewer = RunViewer.start(sim, sim.header(), port=0)
    viewer.server.log = Log()
    try:
        viewer.publish(sim, sim.frame())
        m = re.fullmatch(r"http://127\.0\.0\.1:\d+/\?token=([\w-]{16,})", viewer.url)
        assert m, viewer.url  # the token is in the URL printed for the user

        async def go():
            async with aiohttp.ClientSession() as cs:
                for bad in (None, "guess"):
                    with pytest.raises(aiohttp.WSServerHandshakeError) as info:
                        await _connect(cs, viewer.server, bad)
                    assert info.value.status == 403
                ws = await _connect(cs, viewer.server, m.group(1))
                await ws.send_str('{"type": "control", "acceleration": [1, 0, 0]}')
                await ws.close()

        asyncio.run(go())
        assert _wait(lambda: viewer.server.accepted == 1)
    finally:
        viewer.close()
    opted_out = RunViewer.start(sim, sim.header(), port=0, require_token=False)
    try:
        assert opted_out.server.token is None and "token" not in opted_out.url
    finally:
        opted_out.close()


@pytest.mark.parametrize("argv,words", [
    (("--no-token",), "--no-token is an option of the live view: add --live"),
    (("--live", "--no-token", "--host", "0.0.0.0"), "--no-token: only on this machine's own address"),
])
def test_opting_out_of_the_token_is_for_a_local_live_run_only(tmp_path, argv, words):
    from cli_script import assert_one_line_error, corpuscle as run_cli

    p = run_cli("run", "magic8ball", "--steps", "1", "--out", tmp_path / "o.cps", *argv)
    assert_one_line_error(p, words)
    assert not (tmp_path / "o.cps").exists()
