"""Frames per second the live viewer's server pushes to one websocket client on localhost,
with synthetic frames (no simulation): a producer thread publishes fresh frames as fast as it
can, the server quantises (uint16 positions + a uint8 colour field) and sends the latest,
the client (aiohttp, in this process) counts what arrives.

    python benchmarks/live_bandwidth.py [N ...] [--seconds S]
"""
from __future__ import annotations

import argparse
import asyncio
import threading
import time

import aiohttp
import numpy as np

from corpuscle.live import LiveServer

HEADER = {"dim": 3, "container": {"type": "sphere", "center": [0, 0, 0], "radius": 0.15}}


def measure(n: int, seconds: float) -> dict:
    rng = np.random.default_rng(0)
    pool = [rng.uniform(-0.14, 0.14, size=(n, 3)).astype(np.float32) for _ in range(4)]
    dens = [rng.uniform(900, 1100, size=n).astype(np.float32) for _ in range(4)]
    s = LiveServer(dict(HEADER), port=0, log=lambda line: None).start()
    stop = threading.Event()

    def produce():
        i = 0
        while not stop.is_set():
            s.publish({"index": i, "step": i, "time": i * 1e-3, "positions": pool[i % 4],
                       "fields": {"density": dens[i % 4]}, "overlay": {}})
            i += 1
            time.sleep(0.001)

    s.publish({"index": 0, "step": 0, "time": 0.0, "positions": pool[0], "fields": {"density": dens[0]}, "overlay": {}})
    t = threading.Thread(target=produce, daemon=True)
    t.start()

    async def client():
        async with aiohttp.ClientSession() as cs, cs.ws_connect(f"ws://127.0.0.1:{s.port}/ws", max_msg_size=0) as ws:
            await ws.receive()  # hello
            await ws.receive()  # the first frame (warm-up)
            count, nbytes, t0 = 0, 0, time.perf_counter()
            while time.perf_counter() - t0 < seconds:
                msg = await ws.receive()
                count += 1
                nbytes += len(msg.data)
            dt = time.perf_counter() - t0
            return count / dt, nbytes / dt

    try:
        fps, bps = asyncio.run(client())
    finally:
        stop.set()
        t.join()
        s.stop()
    return {"particles": n, "frames_per_second": fps, "MB_per_second": bps / 1e6, "published": s.published}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("n", nargs="*", type=int, default=[100_000, 1_000_000])
    ap.add_argument("--seconds", type=float, default=5.0)
    args = ap.parse_args()
    for n in args.n:
        r = measure(n, args.seconds)
        print(f"{r['particles']:>10,} particles: {r['frames_per_second']:7.1f} frames/s, "
              f"{r['MB_per_second']:7.1f} MB/s ({r['published']} frames published)")


if __name__ == "__main__":
    main()
