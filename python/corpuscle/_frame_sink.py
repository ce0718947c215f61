"""Frames written on a background thread: a run's next chunk of steps runs (with the GIL
released in the core) while the frame before it is encoded, checksummed and written.

Frames are written in the order they are put. A write that fails (disk full ...) is kept
and raised in the caller's thread by the next :meth:`FrameSink.put` or by :meth:`close`;
frames put after it are dropped, so the file holds exactly the frames before it (the writer
cuts a partial frame back).
"""
from __future__ import annotations

import queue
import threading


class FrameSink:
    def __init__(self, writer, depth: int = 2):
        self.writer = writer
        self.written = 0          # frames written so far
        self.last_step = None     # step of the last frame written
        self._error: BaseException | None = None
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._thread = threading.Thread(target=self._loop, name="corpuscle-frames", daemon=True)
        self._thread.start()

    def put(self, step: int, time: float, dt: float, record: dict, kind: str = "frame") -> None:
        self._raise()
        self._queue.put((step, time, dt, record, kind))

    def close(self) -> None:
        """Write what is queued, stop the thread, raise a write error if there was one."""
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
        self._raise()

    def _raise(self) -> None:
        if self._error is not None:
            err, self._error = self._error, None
            raise err

    def _loop(self) -> None:
        failed = False
        while True:
            item = self._queue.get()
            if item is None:
                return
            if failed:
                continue
            step, time, dt, record, kind = item
            try:
                self.writer.write_frame(step, time, dt, **record, kind=kind)
            except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
                self._error = exc
                failed = True
                continue
            self.written += 1
            self.last_step = step
