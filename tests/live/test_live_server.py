"""The live viewer's server and its run hook, through a real websocket client (no browser):
header then frames, latest-frame-wins for a slow client, the producer never waits, the token
and localhost rules, rejected messages logged without stopping anything, a control that
reaches a real CPU simulation; and `corpuscle run --live` / `corpuscle view` end to end."""
from __future__ import annotations

import asyncio
import json
import re
import signal
import socket
import subprocess
import threading
import time

import numpy as np
import pytest

aiohttp = pytest.importorskip("aiohttp", reason='the live viewer needs aiohttp (pip install ".[viewer]")')

from cli_script import script  # noqa: E402
from corpuscle.live import LiveServer, RunViewer, decode_frame  # noqa: E402

HEADER = {"scene": "t", "kind": "test", "dim": 3, "container": {"type": "sphere", "center": [0, 0, 0], "radius": 1.0}}
CONTROLS = {"acceleration": 3, "torque": 3}


def frame(i: int, n: int = 100, rng=None) -> dict:
    rng = rng or np.random.default_rng(i)
    pos = rng.uniform(-0.9, 0.9, size=(n, 3)).astype(np.float32)
    return {"index": i, "step": 10 * i, "time": 0.01 * i, "positions": pos, "fields": {"density": pos[:, 2] + 1000},
            "overlay": {"diagnostics": {"ke": float(i)}}}


class Log(list):
    def __call__(self, line):
        self.append(line)


def server(**kw) -> LiveServer:
    kw.setdefault("log", Log())
    return LiveServer(dict(HEADER), port=0, controls=CONTROLS, **kw).start()


def ws_url(s: LiveServer, token: str | None = None) -> str:
    q = f"?token={token}" if token else ""
    return f"ws://127.0.0.1:{s.port}/ws{q}"


async def receive_frame(ws, timeout=10.0) -> dict:
    msg = await ws.receive(timeout=timeout)
    assert msg.type == aiohttp.WSMsgType.BINARY, msg
    return decode_frame(msg.data)


def test_header_then_frames():
    s = server()
    try:
        s.publish(frame(0))

        async def go():
            async with aiohttp.ClientSession() as cs, cs.ws_connect(ws_url(s)) as ws:
                hello = json.loads((await ws.receive(timeout=10)).data)
                assert hello["type"] == "hello" and hello["mode"] == "live"
                assert hello["header"]["container"]["radius"] == 1.0 and hello["controls"] == CONTROLS
                assert hello["fields"] == ["density"]
                f0 = await receive_frame(ws)
                assert f0["index"] == 0 and f0["count"] == 100 and f0["meta"]["color"]["field"] == "density"
                assert np.abs(f0["positions"] - frame(0)["positions"]).max() <= 2.04 / 65535
                s.publish(frame(1))
                f1 = await receive_frame(ws)
                assert (f1["index"], f1["step"], f1["meta"]["diagnostics"]["ke"]) == (1, 10, 1.0)
                await ws.send_str('{"type": "color", "field": null}')  # the current frame again, no colour
                f1b = await receive_frame(ws)
                assert f1b["index"] == 1 and f1b["color"] is None

        asyncio.run(go())
    finally:
        s.stop()


def test_slow_client_gets_the_latest_frame_and_the_producer_never_blocks():
    s = server()
    n, count = 100_000, 60
    frames = [frame(i, n) for i in range(count)]
    try:
        s.publish(frames[0])

        async def go():
            async with aiohttp.ClientSession() as cs, cs.ws_connect(ws_url(s), max_msg_size=0) as ws:
                await ws.receive(timeout=10)  # hello
                await receive_frame(ws)
                # the client reads nothing while the producer publishes every frame
                times = []
                for f in frames[1:]:
                    t = time.perf_counter()
                    s.publish(f)
                    times.append(time.perf_counter() - t)
                    await asyncio.sleep(0)
                assert max(times) < 0.02, max(times)  # a publish only swaps a reference
                await asyncio.sleep(0.5)
                got = []
                while not got or got[-1]["index"] != count - 1:
                    got.append(await receive_frame(ws))
                return got

        got = asyncio.run(go())
        assert got[-1]["index"] == count - 1  # the latest arrives
        assert len(got) < count - 1  # ... and the ones in between were dropped, not queued
        assert [g["index"] for g in got] == sorted(g["index"] for g in got)
    finally:
        s.stop()


def test_default_bind_is_localhost_and_other_addresses_need_a_token():
    s = LiveServer(dict(HEADER))
    assert s.host == "127.0.0.1" and s.token is None
    with pytest.raises(ValueError, match="token"):
        LiveServer(dict(HEADER), host="0.0.0.0")
    from corpuscle.cli._options import live_options as _live_options  # the command line's default
    import argparse

    args = argparse.Namespace(live=True, port=None, host=None)
    _live_options(args, needs_live=True)
    assert (args.host, args.port) == ("127.0.0.1", 8765)


def test_a_connection_without_the_token_to_a_non_local_bind_is_refused():
    log = Log()
    s = LiveServer(dict(HEADER), host="0.0.0.0", port=0, token="s3cret-token", controls=CONTROLS, log=log).start()
    try:
        s.publish(frame(0))
        assert "token=s3cret-token" in s.url

        async def go():
            async with aiohttp.ClientSession() as cs:
                for bad in (None, "wrong"):
                    with pytest.raises(aiohttp.WSServerHandshakeError) as info:
                        await cs.ws_connect(ws_url(s, bad))
                    assert info.value.status == 403
                    async with cs.get(f"http://127.0.0.1:{s.port}/" + (f"?token={bad}" if bad else "")) as r:
                        assert r.status == 403
                async with cs.get(f"http://127.0.0.1:{s.port}/?token=s3cret-token") as r:
                    assert r.status == 200 and "viewer.js" in await r.text()
                async with cs.ws_connect(ws_url(s, "s3cret-token")) as ws:
                    assert json.loads((await ws.receive(timeout=10)).data)["type"] == "hello"

        asyncio.run(go())
        assert sum("token" in line for line in log) == 4 and all("\n" not in line for line in log)
    finally:
        s.stop()


def test_a_websocket_from_another_origin_is_refused():
    s = server()
    try:
        s.publish(frame(0))

        async def go():
            async with aiohttp.ClientSession() as cs:
                with pytest.raises(aiohttp.WSServerHandshakeError) as info:
                    await cs.ws_connect(ws_url(s), headers={"Origin": "http://evil.example"})
                assert info.value.status == 403
                async with cs.ws_connect(ws_url(s), headers={"Origin": f"http://127.0.0.1:{s.port}"}) as ws:
                    assert json.loads((await ws.receive(timeout=10)).data)["type"] == "hello"

        asyncio.run(go())
    finally:
        s.stop()


def test_bad_messages_are_rejected_logged_and_the_run_goes_on():
    s = server()
    bad = ["nonsense", '{"type": "control", "acceleration": [NaN, 0, 0]}', '{"type": "control", "torque": [1e9, 0, 0]}',
           '{"type": "control", "acceleration": [1, 2]}', '{"type": "warp"}', "x" * 5000]
    try:
        s.publish(frame(0))

        async def go():
            async with aiohttp.ClientSession() as cs:
                async with cs.ws_connect(ws_url(s)) as ws:
                    await ws.receive(timeout=10)
                    await receive_frame(ws)
                    for raw in bad:
                        await ws.send_str(raw)
                    await ws.send_bytes(b"\x00\x01")
                    await ws.send_str('{"type": "control", "acceleration": [1, 0, 0], "torque": [0, 0, 0.01]}')
                    s.publish(frame(1))
                    assert (await receive_frame(ws))["index"] == 1  # the connection goes on
                # a message over the transport limit closes that connection only
                async with cs.ws_connect(ws_url(s)) as ws:
                    await ws.receive(timeout=10)
                    await ws.send_str("y" * 100_000)
                    while (await ws.receive(timeout=10)).type not in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED):
                        pass
                async with cs.ws_connect(ws_url(s)) as ws:  # the server still serves
                    assert json.loads((await ws.receive(timeout=10)).data)["type"] == "hello"

        asyncio.run(go())
        time.sleep(0.2)
        assert s.take_control() == {"acceleration": [1.0, 0.0, 0.0], "torque": [0.0, 0.0, 0.01]}
        assert s.rejected == len(bad) + 2
        assert len(s.log) == len(bad) + 2 and all(line.startswith("rejected message from 127.0.0.1: ") for line in s.log)
        assert any("non-finite" in line for line in s.log) and any("at most 4096" in line for line in s.log)
    finally:
        s.stop()


def _sim(particles=300):
    simulation = pytest.importorskip("corpuscle.simulation", reason="the compiled core is not built")
    return simulation.Simulation.from_scene("magic8ball", backend="serial", particles=particles)


def test_a_control_message_reaches_set_control_of_a_real_simulation():
    sim, twin = _sim(), _sim()
    s = LiveServer(sim.header(), port=0, controls={k: int(v) for k, v in dict(sim.core.controls()).items()},
                   log=Log()).start()
    viewer = RunViewer(s)
    try:
        viewer.publish(sim, sim.frame())

        async def go():
            async with aiohttp.ClientSession() as cs, cs.ws_connect(ws_url(s)) as ws:
                hello = json.loads((await ws.receive(timeout=10)).data)
                assert hello["controls"] == {"acceleration": 3, "torque": 3}
                f = await receive_frame(ws)
                assert f["count"] == 300 and "die" in f["meta"]["rigid"] and f["meta"]["result"]["answer"]
                await ws.send_str(json.dumps({"type": "control", "acceleration": [60.0, 0.0, 0.0], "torque": [0, 0, 0.05]}))
                for _ in range(200):
                    if s.accepted:
                        break
                    await asyncio.sleep(0.01)

        asyncio.run(go())
        viewer.between_chunks(sim)
        assert viewer.control == {"acceleration": [60.0, 0.0, 0.0], "torque": [0.0, 0.0, 0.05]}
        sim.step(150)
        twin.step(150)
        v, v0 = np.asarray(sim.state()["die"]["velocity"]), np.asarray(twin.state()["die"]["velocity"])
        assert np.linalg.norm(v - v0) > 1e-3, (v, v0)
    finally:
        s.stop()


def test_pause_waits_without_stepping_until_resume():
    sim = _sim()
    s = LiveServer(sim.header(), port=0, controls=CONTROLS, log=Log()).start()
    viewer = RunViewer(s)
    try:
        viewer.publish(sim, sim.frame())

        async def go():
            # the page stays connected while the run is paused (a page that is gone lets go)
            async with aiohttp.ClientSession() as cs, cs.ws_connect(ws_url(s)) as ws:
                await ws.receive(timeout=10)

                async def send(msg):
                    await ws.send_str(json.dumps(msg))
                    for _ in range(200):
                        if s.paused == (msg["type"] == "pause"):
                            break
                        await asyncio.sleep(0.01)

                await send({"type": "pause"})
                t = threading.Thread(target=viewer.between_chunks, args=(sim,), daemon=True)
                t.start()
                await asyncio.sleep(0.4)
                assert t.is_alive() and int(sim.steps) == 0
                await send({"type": "resume"})
                await asyncio.get_running_loop().run_in_executor(None, t.join, 5)
                assert not t.is_alive()

        asyncio.run(go())
    finally:
        s.stop()


# ---- the command line -------------------------------------------------------------------


def _run(*argv, timeout=120):
    return subprocess.run([script(), *argv], capture_output=True, text=True, timeout=timeout)


def _one_line_error(p, pattern):
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr
    assert re.search(pattern, p.stderr), p.stderr


def test_bad_live_options_are_one_line_errors(tmp_path):
    _one_line_error(_run("run", "magic8ball", "--port", "9000", "--out", str(tmp_path / "a.cps")), "add --live")
    _one_line_error(_run("run", "magic8ball", "--live", "--port", "99999"), "at most 65535")
    _one_line_error(_run("run", "magic8ball", "--live", "--port", "x"), "--port must be an integer")
    _one_line_error(_run("run", "magic8ball", "--live", "--host", "no such host!"), "--host")
    _one_line_error(_run("view", str(tmp_path / "missing.cps")), "no such file")
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        out = tmp_path / "b.cps"
        p = _run("run", "magic8ball", "--backend", "serial", "--particles", "300", "--steps", "5", "--live",
                 "--port", str(port), "--out", str(out))
        _one_line_error(p, r"--live: cannot listen on 127\.0\.0\.1:\d+")
        assert not out.exists()


class _Proc:
    """A corpuscle subprocess whose first stderr line with a URL is read; the rest drained."""

    def __init__(self, *argv):
        self.p = subprocess.Popen([script(), *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.lines: list[str] = []
        deadline = time.time() + 120
        self.url = None
        while self.url is None and time.time() < deadline:
            line = self.p.stderr.readline()
            if not line:
                break
            self.lines.append(line)
            m = re.search(r"(http://\S+)", line)
            if m:
                self.url = m.group(1)
        self.drain = threading.Thread(target=lambda: self.lines.extend(self.p.stderr), daemon=True)
        self.drain.start()
        assert self.url, "".join(self.lines)
        self.port = int(re.search(r":(\d+)/", self.url).group(1))
        self.ws = f"ws://127.0.0.1:{self.port}/ws" + self.url[self.url.find("?"):] * ("?" in self.url)

    def interrupt(self, timeout=60) -> int:
        self.p.send_signal(signal.SIGINT)
        try:
            rc = self.p.wait(timeout)
        finally:
            if self.p.poll() is None:
                self.p.kill()
        self.drain.join(5)
        return rc


def test_run_live_streams_frames_and_rejects_bad_messages(tmp_path):
    out = tmp_path / "live.cps"
    proc = _Proc("run", "magic8ball", "--backend", "serial", "--particles", "300", "--steps", "1000000", "--every", "20",
                 "--live", "--port", "0", "--out", str(out), "--no-progress")
    try:
        assert re.fullmatch(rf"http://127\.0\.0\.1:{proc.port}/\?token=[\w-]+", proc.url)  # steering needs it

        async def go():
            async with aiohttp.ClientSession() as cs:
                async with cs.get(proc.url) as r:
                    assert r.status == 200 and "canvas" in await r.text()
                async with cs.ws_connect(proc.ws) as ws:
                    hello = json.loads((await ws.receive(timeout=30)).data)
                    assert hello["header"]["scene"] == "magic8ball" and hello["header"]["particles"] == 300
                    a = await receive_frame(ws, 30)
                    await ws.send_str('{"type": "control", "acceleration": [NaN, 0, 0]}')
                    await ws.send_str('{"type": "control", "acceleration": [5, 0, 0]}')
                    # frames already on their way may predate the control (the server keeps up
                    # to two ahead of the page): within a few frames every one carries it
                    want = {"acceleration": [5.0, 0.0, 0.0], "torque": [0.0, 0.0, 0.0]}
                    steps, seen = [a["step"]], None
                    for k in range(12):
                        f = await receive_frame(ws, 30)
                        steps.append(f["step"])
                        if f["meta"]["control"] == want:
                            seen = k
                            break
                    assert seen is not None and seen <= 6, steps
                    assert steps == sorted(steps) and len(set(steps)) == len(steps)  # the run went on
                    later = await receive_frame(ws, 30)
                    assert later["step"] > steps[-1] and later["meta"]["control"] == want

        asyncio.run(go())
    finally:
        rc = proc.interrupt()
    text = "".join(proc.lines)
    assert rc == 130, text
    assert "rejected message from 127.0.0.1: non-finite number NaN" in text
    assert "Traceback" not in text


def test_view_serves_a_recorded_run_and_seeks(tmp_path):
    out = tmp_path / "rec.cps"
    p = _run("run", "magic8ball", "--backend", "serial", "--particles", "300", "--steps", "300", "--every", "100",
             "--out", str(out), "--no-progress")
    assert p.returncode == 0, p.stderr
    proc = _Proc("view", str(out), "--port", "0")
    try:
        async def go():
            async with aiohttp.ClientSession() as cs, cs.ws_connect(proc.ws) as ws:
                hello = json.loads((await ws.receive(timeout=30)).data)
                assert hello["mode"] == "view" and hello["frames"] == 4 and "density" in hello["fields"]
                assert (await receive_frame(ws))["index"] == 0
                await ws.send_str('{"type": "seek", "frame": 2}')
                f = await receive_frame(ws)
                assert (f["index"], f["step"], f["count"]) == (2, 200, 300)
                await ws.send_str('{"type": "pause"}')  # a recording cannot be steered: rejected
                await ws.send_str('{"type": "seek", "frame": 3}')
                assert (await receive_frame(ws))["index"] == 3

        asyncio.run(go())
    finally:
        rc = proc.interrupt()
    text = "".join(proc.lines)
    assert rc == 0, text
    assert "viewing" in text and "4 frames" in text and "cannot be steered" in text


def test_run_live_wind_tunnel_sliders_and_frames_between_recorded_ones(tmp_path):
    out = tmp_path / "wt.cps"
    # a frame is recorded every 100000 steps: the page still sees the run move, and its
    # control is taken within a frame, not at the next recorded one
    proc = _Proc("run", "wind-tunnel", "--backend", "serial", "--particles", "500", "--steps", "100000000",
                 "--every", "100000", "--live", "--port", "0", "--out", str(out), "--no-progress")
    try:
        async def go():
            async with aiohttp.ClientSession() as cs, cs.ws_connect(proc.ws) as ws:
                hello = json.loads((await ws.receive(timeout=30)).data)
                assert hello["controls"] == {"speed_scale": 1, "pitch": 1}
                assert hello["control"] == {"speed_scale": [0.0], "pitch": [0.0]}
                assert [s["control"] for s in hello["sliders"]] == ["speed_scale", "pitch"]
                ob = hello["scene"]["obstacles"][0]
                assert ob["type"] == "polygon" and ob["turn"]["diagnostic"] == "pitch" and len(ob["points"]) > 10
                a = await receive_frame(ws, 30)
                b = await receive_frame(ws, 30)
                assert 0 < b["step"] - a["step"] < 100000 and b["step"] < 100000
                await ws.send_str('{"type": "control", "pitch": [4.5]}')
                await ws.send_str('{"type": "control", "pitch": [60]}')  # outside the slider's range: rejected
                t = time.time()
                while time.time() - t < 30:
                    f = await receive_frame(ws, 30)
                    if f["meta"]["diagnostics"].get("pitch") == 4.5:
                        break
                assert f["meta"]["control"] == {"speed_scale": [0.0], "pitch": [4.5]} and f["step"] < 100000
                assert f["meta"]["diagnostics"]["lift"] is not None and "cl" in f["meta"]["result"]

        asyncio.run(go())
    finally:
        rc = proc.interrupt()
    text = "".join(proc.lines)
    assert rc == 130, text
    assert "rejected message from 127.0.0.1: control 'pitch'[0] = 60 is outside" in text and "Traceback" not in text


def test_a_page_that_acknowledges_frames_is_sent_at_most_two_ahead():
    s = server()
    try:
        s.publish(frame(0))

        async def go():
            async with aiohttp.ClientSession() as cs, cs.ws_connect(ws_url(s)) as ws:
                await ws.receive(timeout=10)
                assert (await receive_frame(ws))["index"] == 0
                await ws.send_str('{"type": "ready"}')  # drew frame 0: flow control from here on
                got = []
                for i in range(1, 6):
                    s.publish(frame(i))
                    await asyncio.sleep(0.15)
                while True:
                    try:
                        got.append(await receive_frame(ws, timeout=0.5))
                    except asyncio.TimeoutError:
                        break
                assert [g["index"] for g in got] == [1, 2]  # two credits: no more until the page draws one
                await ws.send_str('{"type": "ready"}')
                last = await receive_frame(ws)
                assert last["index"] == 5  # the latest, the ones between dropped
                await ws.send_str('{"type": "ready", "extra": 1}')  # checked like any message

        asyncio.run(go())
        for _ in range(100):
            if s.rejected:
                break
            time.sleep(0.02)
        assert s.rejected == 1 and s.accepted == 0  # acknowledgements are not counted as requests
    finally:
        s.stop()


def test_a_flood_of_bad_messages_neither_stalls_the_producer_nor_floods_the_log():
    s = server()
    bad = ['{"type": "control", "acceleration": [1e9, 0, 0]}', "{", '{"type": "seek", "frame": 1}', "[]" * 900,
           '{"type": "control", "pitch": [1]}', '{"type": "color", "field": "nope"}']
    try:
        s.publish(frame(0))
        times = []
        stop = threading.Event()

        def produce():
            i = 1
            while not stop.is_set():
                t = time.perf_counter()
                s.publish(frame(i))
                times.append(time.perf_counter() - t)
                i += 1
                time.sleep(0.005)

        async def go():
            async with aiohttp.ClientSession() as cs, cs.ws_connect(ws_url(s)) as ws:
                await ws.receive(timeout=10)
                for k in range(3000):
                    await ws.send_str(bad[k % len(bad)])
                first = (await receive_frame(ws))["index"]
                while (f := await receive_frame(ws))["index"] <= first:
                    pass  # frames keep coming, newer ones
                return f

        t = threading.Thread(target=produce, daemon=True)
        t.start()
        try:
            asyncio.run(go())
        finally:
            stop.set()
            t.join()
        for _ in range(200):
            if s.rejected >= 3000:
                break
            time.sleep(0.02)
        assert s.rejected == 3000 and s.accepted == 0 and s.take_control() is None
        assert max(times) < 0.05, max(times)  # publishing never waited on the flood
        assert len(s.log) < 200 and all(line.startswith("rejected message from 127.0.0.1: ") for line in s.log)
    finally:
        s.stop()
