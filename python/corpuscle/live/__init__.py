"""The live viewer: a local web page that draws a running simulation (``corpuscle run SCENE
--live``) or a recorded run (``corpuscle view RUN.cps``), and steers a running one.

It needs the optional extra ``viewer`` (aiohttp), imported only when a server starts. The
page is static files in ``static/`` (WebGL2, no CDN, no build step); the wire format is in
:mod:`corpuscle.live.protocol`; the server in :mod:`corpuscle.live.server`.
"""
from __future__ import annotations

import math
import secrets
import time
from typing import Any

import numpy as np

from .protocol import MessageError, decode_frame, encode_frame, parse_message  # noqa: F401
from .server import LiveServer, ServerError, is_local  # noqa: F401

__all__ = ["LiveServer", "RunViewer", "ServerError", "is_local", "make_token", "serve_recording",
           "frame_from_record", "parse_message", "encode_frame", "decode_frame", "MessageError"]

_SKIP_FIELDS = {"position", "id"}


def make_token() -> str:
    return secrets.token_urlsafe(18)


def colour_fields(fields: dict[str, Any], groups: dict[str, str]) -> dict[str, Any]:
    """The per-particle fields of the positions' group a page can colour by."""
    pos = fields.get("position")
    if pos is None:
        return {}
    group = groups.get("position")
    n = len(pos)
    return {name: arr for name, arr in fields.items()
            if name not in _SKIP_FIELDS and not name.startswith("state.") and groups.get(name) == group
            and getattr(arr, "shape", (None,))[0] == n and np.asarray(arr).dtype.kind in "fiu"}


def _rigid(rigid: dict[str, Any]) -> dict[str, Any]:
    return {body: {k: np.asarray(v, dtype=np.float64).tolist() for k, v in pose.items()}
            for body, pose in (rigid or {}).items()}


def frame_from_record(rec: dict[str, Any], index: int, step: int, time_: float,
                      overlay: dict[str, Any] | None = None) -> dict[str, Any]:
    """A server frame from ``Simulation.frame()``'s record (or a recorded Frame's parts)."""
    fields, groups = rec.get("fields") or {}, rec.get("groups") or {}
    out_overlay = {"diagnostics": dict(rec.get("diagnostics") or {}), "rigid": _rigid(rec.get("rigid"))}
    out_overlay.update(overlay or {})
    return {"index": int(index), "step": int(step), "time": float(time_), "positions": fields["position"],
            "fields": colour_fields(fields, groups), "overlay": out_overlay}


class RunViewer:
    """What ``corpuscle run --live`` adds to its loop: :meth:`publish` each recorded frame,
    :meth:`between_chunks` to apply the page's control and wait while it paused the run."""

    #: the page is sent a frame at most this often between recorded frames (s)
    FRAME_INTERVAL = 1.0 / 30.0

    def __init__(self, server: LiveServer):
        self.server = server
        self.control: dict[str, list[float]] | None = None
        self._frames = 0
        self._rate_at: tuple[int, float] | None = None
        self._rate = math.nan
        self._published_at = -math.inf
        self._chunk_at: tuple[int, float] | None = None
        self._step_seconds = math.nan  # the run's wall time per step, measured between chunks

    @classmethod
    def start(cls, sim, header: dict[str, Any], host: str = "127.0.0.1", port: int = 8765,
              token: str | None = None, require_token: bool = True) -> "RunViewer":
        """Serve the run; the page and its controls need a random token (in :attr:`url`)
        unless ``require_token`` is False on this machine's own address."""
        controls = {str(k): int(v) for k, v in dict(sim.core.controls()).items()} if hasattr(sim, "core") else {}
        if token is None and (require_token or not is_local(host)):
            token = make_token()  # a page of another site (DNS rebinding, a guessed port) cannot steer
        server = LiveServer(header, mode="live", host=host, port=port, token=token, controls=controls,
                            control=getattr(sim, "control", None), sliders=live_sliders(sim))
        return cls(server.start())

    @property
    def url(self) -> str:
        return self.server.url

    def publish(self, sim, rec: dict[str, Any]) -> None:
        step, now = int(sim.steps), time.perf_counter()
        if self._rate_at is not None and now > self._rate_at[1] and step > self._rate_at[0]:
            self._rate = (step - self._rate_at[0]) / (now - self._rate_at[1])
        self._rate_at = (step, now)
        try:
            result = dict(sim.result() or {})
        except Exception:  # noqa: BLE001 - the overlay never stops a run
            result = {}
        overlay = {"result": result, "steps_per_second": self._rate, "particles": int(sim.n_particles),
                   "control": getattr(sim, "control", self.control), "paused": self.server.paused}
        self.server.publish(frame_from_record(rec, self._frames, step, float(sim.time), overlay))
        self._frames += 1
        self._published_at = now

    def chunk(self, steps: int) -> int:
        """How many of the next ``steps`` to take before the page's control is looked at
        again: about :attr:`FRAME_INTERVAL` of wall time (at least one step), so a control
        or a pause is taken within a frame and the page sees the run move between recorded
        frames."""
        if not math.isfinite(self._step_seconds) or self._step_seconds <= 0:
            return max(1, min(int(steps), 1))
        return max(1, min(int(steps), int(self.FRAME_INTERVAL / self._step_seconds)))

    def stepped(self, sim, recorded: bool = False) -> None:
        """After each chunk: measure the step rate and, where the chunk recorded no frame
        (``recorded``: it did, and published it), a page is connected and a frame interval
        has passed, publish the current state (not recorded)."""
        now, step = time.perf_counter(), int(sim.steps)
        if self._chunk_at is not None and step > self._chunk_at[0] and now > self._chunk_at[1]:
            self._step_seconds = (now - self._chunk_at[1]) / (step - self._chunk_at[0])
        self._chunk_at = (step, now)
        if not recorded and self.server.clients and now - self._published_at >= self.FRAME_INTERVAL:
            self.publish(sim, sim.frame())

    def apply(self, sim) -> bool:
        """Apply the page's latest control, if one came; True if one did."""
        ctl = self.server.take_control()
        if ctl is None:
            return False
        try:
            sim.set_control(**ctl)
        except (TypeError, ValueError) as exc:
            self.server._reject("page", f"control refused by the simulation: {' '.join(str(exc).split())}")
            return False
        self.control = ctl
        return True

    def between_chunks(self, sim, poll: float = 0.05) -> None:
        """Apply a control; while paused, wait (Ctrl-C interrupts) without stepping."""
        self.apply(sim)
        announced = False
        while self.server.paused:
            if not announced:
                self.publish(sim, sim.frame())  # the overlay shows the pause
                announced = True
            time.sleep(poll)
            self.apply(sim)

    def close(self) -> None:
        self.server.stop()


def live_sliders(sim) -> list[dict[str, Any]]:
    """The kind's sliders for the page (``Kind.live_controls``; none if it has none): each
    ``{"control", "index", "label", "unit", "min", "max", "step", "value", "scale",
    "offset"}``, the control component being ``scale * value + offset``."""
    kind = getattr(sim, "kind", None)
    fn = getattr(kind, "live_controls", None)
    if fn is None:
        return []
    out = []
    for sl in fn(sim) or []:
        sl = dict(sl)
        sl.setdefault("index", 0)
        sl.setdefault("scale", 1.0)
        sl.setdefault("offset", 0.0)
        sl.setdefault("label", sl["control"])
        sl.setdefault("unit", "")
        sl.setdefault("step", (float(sl["max"]) - float(sl["min"])) / 100.0)
        out.append(sl)
    return out


def serve_recording(path, host: str = "127.0.0.1", port: int = 8765, token: str | None = None) -> tuple[LiveServer, Any]:
    """A started server for the recorded run at ``path`` (``corpuscle.open``), and the run."""
    from .. import io

    run = io.open(path)
    header = dict(run.header)
    n = len(run)
    if n == 0:
        run.close()
        raise ValueError(f"{path}: the run has no frames")
    first = run[0]
    header["_fields"] = list(colour_fields(first.fields, first.groups))

    def source(i: int) -> dict[str, Any]:
        frame = run[i]
        rec = {"fields": frame.fields, "groups": frame.groups, "rigid": frame.rigid,
               "diagnostics": frame.diagnostics}
        return frame_from_record(rec, frame.index, frame.step, frame.time,
                                 {"particles": int(len(frame.fields["position"])), "frames": n})

    if token is None and not is_local(host):
        token = make_token()
    server = LiveServer(header, mode="view", host=host, port=port, token=token, source=source, frames=n)
    try:
        server.start()
    except BaseException:
        run.close()
        raise
    return server, run
