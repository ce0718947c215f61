"""The live viewer's server: aiohttp on a background thread with its own event loop.

The simulation thread calls :meth:`LiveServer.publish` with each frame; that stores it as
the latest (replacing one not yet sent) and wakes the senders, and never waits for a
client. Each client has a sender that encodes and sends the latest frame whenever its
previous send is done, so a slow page gets fewer frames, never a backlog. Messages from the
page are checked (:func:`protocol.parse_message`); rejected ones are logged, one line each
on stderr, and the connection goes on (a message over the transport limit closes it).
"""
from __future__ import annotations

import asyncio
import hmac
import importlib.resources
import ipaddress
import logging
import re
import socket
import sys
import threading
import time
from typing import Any, Callable

import numpy as np

from . import protocol
from .._viz_common import render_hint

STATIC_FILES = {"index.html": "text/html", "viewer.js": "text/javascript", "viewer.css": "text/css"}
CSP = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
       "connect-src 'self'; frame-ancestors 'none'")
LOCAL_NAMES = {"localhost", "127.0.0.1", "::1"}
TRANSPORT_LIMIT = 64 * 1024  # a websocket message over this closes the connection
CREDITS = 2  # frames in flight to a page that acknowledges them (one drawn, one on its way)
HEARTBEAT = 20.0  # s between pings to a page; one that does not answer is closed


class ServerError(OSError):
    """The server could not start (port in use, an address it cannot bind)."""


def is_local(host: str) -> bool:
    """Whether binding to ``host`` exposes the server to this machine only."""
    if host in LOCAL_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _import_aiohttp():
    try:
        from aiohttp import WSMsgType, web  # noqa: F401
    except ImportError:
        raise ImportError('the live viewer needs aiohttp: pip install "corpuscle[viewer]" '
                          '(or ".[viewer]" from a checkout)') from None
    return web, WSMsgType


class _Client:
    def __init__(self, ws, peer: str, color: str | None):
        self.ws = ws
        self.peer = peer
        self.color = color
        self.event = asyncio.Event()
        self.sent_seq = -1
        self.dirty = True
        self.want: int | None = None
        self.sent = 0
        # flow control: a page that says "ready" after drawing a frame is sent at most
        # CREDITS frames it has not drawn yet (None: a client that never says it; the
        # socket's own back-pressure only)
        self.credits: int | None = None
        # it sent a control, pause or resume: the run is held by it (a pause it set is
        # released when the last such client is gone)
        self.controlling = False


class _OneLineLogger(logging.Logger):
    """aiohttp's server logger for one LiveServer: each record (a bad request, a client that
    went away mid-request) as one rate-limited line of the server's log, never a traceback."""

    def __init__(self, server: "LiveServer"):
        super().__init__("corpuscle.live.http", logging.WARNING)
        self.propagate = False
        self._server = server

    def handle(self, record: logging.LogRecord) -> None:
        text = record.getMessage()
        exc = record.exc_info[1] if record.exc_info else None
        if exc is not None:
            why = " ".join(str(getattr(exc, "message", "") or exc).split())
            why = re.sub(r"^\d{3}, message: ", "", why)
            text = f"{text}: {type(exc).__name__}: {why[:80]}{'...' if len(why) > 80 else ''}"
        self._server._log_limited(" ".join(text.split()))


class LiveServer:
    """Serves the page and one websocket (``/ws``).

    ``mode`` "live": frames come from :meth:`publish`; controls and pause go to
    :meth:`take_control` / :attr:`paused`. ``mode`` "view": ``source(i)`` returns frame i of a
    recorded run (``frames`` of them) when the page seeks it.

    A frame (for publish, and what ``source`` returns) is a dict: ``index``, ``step``,
    ``time``, ``positions`` (n x dim), ``fields`` (name -> per-particle array, colourable),
    ``overlay`` (JSON-able: diagnostics, result, rigid poses ...).
    """

    def __init__(self, header: dict[str, Any], *, mode: str = "live", host: str = "127.0.0.1", port: int = 8765,
                 token: str | None = None, controls: dict[str, int] | None = None,
                 source: Callable[[int], dict] | None = None, frames: int | None = None,
                 log: Callable[[str], None] | None = None, control: dict[str, list[float]] | None = None,
                 sliders: list[dict[str, Any]] | None = None):
        if not is_local(host) and not token:
            raise ValueError(f"a server on {host} (not this machine only) needs a token")
        self.header = header
        self.mode = mode
        self.host = host
        self.port = int(port)
        self.token = token
        self.controls = dict(controls or {})
        # the control the run takes (a control message changes the controls it names)
        self._current = {k: [float(x) for x in (control or {}).get(k, [0.0] * n)] for k, n in self.controls.items()}
        self.sliders = [dict(sl) for sl in (sliders or []) if sl.get("control") in self.controls]
        self.ranges = protocol.slider_ranges(self.sliders)
        self.source = source
        self.frames = frames
        self.log = log if log is not None else (lambda line: print(f"corpuscle: live: {line}", file=sys.stderr, flush=True))
        self.scene = _scene_geometry(header, self.log)
        self.rejected = 0           # messages rejected (tests read it)
        self.accepted = 0
        self.published = 0
        self._lock = threading.Lock()
        self._latest: tuple[int, dict] | None = None
        self._control: dict[str, Any] | None = None
        self._paused = threading.Event()
        self._clients: set[_Client] = set()
        self._cache: dict[tuple, bytes] = {}
        self._cache_lock = threading.Lock()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._runner = None
        self._first_frame: asyncio.Event | None = None
        self._log_times: list[float] = []
        self._log_suppressed = 0

    # ---- lifecycle ---------------------------------------------------------------------
    def start(self) -> "LiveServer":
        """Bind and serve on a background thread; raises :class:`ServerError` if it cannot."""
        _import_aiohttp()
        self._thread = threading.Thread(target=self._main, name="corpuscle-live", daemon=True)
        self._thread.start()
        self._ready.wait()
        if self._error is not None:
            err = self._error
            self._thread.join(5)
            raise ServerError(f"cannot listen on {self.host}:{self.port}: {_reason(err)}") from None
        return self

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        query = f"?token={self.token}" if self.token else ""
        return f"http://{host}:{self.port}/{query}"

    def stop(self) -> None:
        loop = self._loop
        if loop is None or self._thread is None:
            return
        try:
            asyncio.run_coroutine_threadsafe(self._shutdown(), loop).result(5)
        except Exception:  # noqa: BLE001 - stopping is best effort
            pass
        try:
            loop.call_soon_threadsafe(loop.stop)
        except RuntimeError:
            pass
        self._thread.join(5)
        self._loop = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    # ---- the simulation's side ----------------------------------------------------------
    def publish(self, frame: dict[str, Any]) -> None:
        """Make ``frame`` the latest; never waits for a client."""
        with self._lock:
            seq = self._latest[0] + 1 if self._latest else 0
            self._latest = (seq, frame)
            self.published += 1
        loop = self._loop
        if loop is not None:
            try:
                loop.call_soon_threadsafe(self._wake_all)
            except RuntimeError:  # the loop is closing
                pass

    def take_control(self) -> dict[str, Any] | None:
        """The latest control message not yet taken (None: none came)."""
        with self._lock:
            ctl, self._control = self._control, None
        return ctl

    @property
    def paused(self) -> bool:
        return self._paused.is_set()

    @property
    def clients(self) -> int:
        return len(self._clients)

    # ---- internals ------------------------------------------------------------------------
    def _main(self) -> None:
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._start())
        except BaseException as exc:  # noqa: BLE001 - reported by start()
            self._loop = None
            self._error = exc
            self._ready.set()
            loop.close()
            return
        self._ready.set()
        try:
            loop.run_forever()
        finally:
            try:
                loop.run_until_complete(loop.shutdown_asyncgens())
            finally:
                loop.close()

    async def _start(self) -> None:
        web, _ = _import_aiohttp()
        self._loop = asyncio.get_running_loop()  # publish() wakes the senders from here on
        self._first_frame = asyncio.Event()
        if self._latest is not None or self.mode != "live":
            self._first_frame.set()
        app = web.Application(client_max_size=TRANSPORT_LIMIT, middlewares=[self._host_check(web)])
        app.router.add_get("/", self._page)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/static/{name}", self._static)
        app.router.add_get("/favicon.ico", self._no_content)
        # aiohttp logs a request it cannot parse (an oversized header or URL, bytes that are
        # not HTTP) with its traceback; the client already has its 400: one line here
        self._runner = web.AppRunner(app, access_log=None, handle_signals=False, logger=_OneLineLogger(self))
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port, reuse_address=False)
        try:
            await site.start()
        except BaseException:
            await self._runner.cleanup()
            raise
        sockets = getattr(site._server, "sockets", None) or []  # noqa: SLF001 - the port picked for 0
        if sockets:
            self.port = int(sockets[0].getsockname()[1])

    async def _shutdown(self) -> None:
        for client in list(self._clients):
            try:
                await client.ws.close()
            except Exception:  # noqa: BLE001
                pass
        if self._runner is not None:
            await self._runner.cleanup()

    def _wake_all(self) -> None:
        if self._first_frame is not None:
            self._first_frame.set()
        for client in self._clients:
            client.event.set()

    def _reject(self, peer: str, reason: str) -> None:
        self.rejected += 1
        self._log_limited(f"rejected message from {peer}: {reason}")

    def _log_limited(self, line: str) -> None:
        """One line through ``self.log``; past 20 a second they are counted, not echoed."""
        now = time.monotonic()
        self._log_times = [t for t in self._log_times if now - t < 1.0]
        if len(self._log_times) >= 20:  # a flood is summarised, not echoed line by line
            self._log_suppressed += 1
            return
        self._log_times.append(now)
        more = f" ({self._log_suppressed} more suppressed)" if self._log_suppressed else ""
        self._log_suppressed = 0
        self.log(f"{line}{more}")

    def _authorised(self, request) -> bool:
        if self.token is None:
            return True
        given = request.query.get("token", "")
        return hmac.compare_digest(given.encode(), self.token.encode())

    def _host_names(self) -> set[str]:
        """The names a request may call this server by: the address it was started for, and
        this machine's names where that address is local (or every address, 0.0.0.0 / ::)."""
        names = {self.host.strip("[]").lower()}
        if is_local(self.host) or _wildcard(self.host):
            names |= {"localhost", "127.0.0.1", "::1", "localhost.localdomain"}
        if _wildcard(self.host):
            try:
                names |= {socket.gethostname().lower(), socket.getfqdn().lower()}
            except OSError:
                pass
        return names

    def _allowed(self, authority: str | None) -> bool:
        """Whether a Host (``name[:port]``) or an Origin's authority names this server: one of
        :meth:`_host_names` (or, bound to every address, any IP address) and its port. A
        name that only resolves here (DNS rebinding: another site's name) is refused."""
        parts = _split_authority(authority or "")
        if parts is None:
            return False
        name, port = parts
        if (port or "80") != str(self.port):  # a browser leaves out http's own port, 80
            return False
        name = name.lower().rstrip(".")
        if name in self._host_names():
            return True
        if _wildcard(self.host):
            try:
                ipaddress.ip_address(name)
                return True
            except ValueError:
                return False
        return False

    def _host_check(self, web):
        """Middleware: every request must name this server in its Host header."""
        @web.middleware
        async def check(request, handler):
            if not self._allowed(request.headers.get("Host")):
                self._reject(_peer(request), f"request for host {request.headers.get('Host', '')[:60]!r} "
                                             "(not an address this server was started for)")
                return web.Response(status=403, text="403: not this server's address\n")
            return await handler(request)
        return check

    def _same_origin(self, request) -> bool:
        """A browser's websocket must come from this server's own page (not another site):
        its Origin names one of this server's addresses and port."""
        origin = request.headers.get("Origin")
        if origin is None:
            return True  # not a browser
        scheme, sep, authority = origin.partition("://")
        return bool(sep) and scheme in ("http", "https") and "/" not in authority and self._allowed(authority)

    async def _page(self, request):
        web, _ = _import_aiohttp()
        if not self._authorised(request):
            self._reject(_peer(request), "page request without the right token")
            return web.Response(status=403, text="403: this viewer needs the token printed with its URL\n")
        return web.Response(body=_static_bytes("index.html"), content_type="text/html",
                            headers={"Content-Security-Policy": CSP, "Cache-Control": "no-store"})

    async def _no_content(self, request):
        web, _ = _import_aiohttp()
        return web.Response(status=204)

    async def _static(self, request):
        web, _ = _import_aiohttp()
        name = request.match_info["name"]
        if name not in STATIC_FILES or name == "index.html":
            return web.Response(status=404, text="404\n")
        return web.Response(body=_static_bytes(name), content_type=STATIC_FILES[name],
                            headers={"Content-Security-Policy": CSP, "Cache-Control": "no-store"})

    def _fields(self) -> list[str]:
        if self.mode == "view":
            return list(self.header.get("_fields", []))
        with self._lock:
            latest = self._latest
        return list(latest[1].get("fields", {})) if latest else []

    async def _websocket(self, request):
        web, WSMsgType = _import_aiohttp()
        peer = _peer(request)
        if not self._authorised(request):
            self._reject(peer, "websocket without the right token")
            return web.Response(status=403, text="403: token required\n")
        if not self._same_origin(request):
            self._reject(peer, f"websocket from another origin ({request.headers.get('Origin', '')[:60]})")
            return web.Response(status=403, text="403: cross-origin websocket\n")
        # pings every HEARTBEAT s: a page that vanished without closing (a sleeping laptop, a
        # dropped network) is noticed and let go like one that closed
        ws = web.WebSocketResponse(max_msg_size=TRANSPORT_LIMIT, heartbeat=HEARTBEAT, compress=False)
        await ws.prepare(request)
        if self.mode == "live":
            await self._first_frame.wait()
        fields = self._fields()
        client = _Client(ws, peer, default_color(self.header, fields))
        with self._lock:
            current = {k: list(v) for k, v in self._current.items()}
        hello = {"type": "hello", "mode": self.mode, "header": self.header, "scene": self.scene, "fields": fields,
                 "color": client.color,
                 "controls": self.controls, "limits": {k: protocol.LIMITS.get(k, protocol.DEFAULT_LIMIT)
                                                        for k in self.controls},
                 "control": current, "sliders": self.sliders,
                 "frames": self.frames, "paused": self.paused, "max_message": protocol.MAX_MESSAGE}
        await ws.send_str(protocol.dumps(hello))
        self._clients.add(client)
        if self.mode == "view":
            client.want = 0
        client.event.set()
        sender = asyncio.ensure_future(self._sender(client))
        try:
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    self._handle(client, msg.data)
                elif msg.type == WSMsgType.BINARY:
                    self._reject(peer, "binary message (only JSON text is accepted)")
                elif msg.type == WSMsgType.ERROR:
                    self._reject(peer, f"connection closed: {_reason(ws.exception())}")
        finally:
            self._clients.discard(client)
            sender.cancel()
            self._let_go(client)
        return ws

    def _let_go(self, client: _Client) -> None:
        """A client is gone: when it steered the run and no other steering client is left, a
        pause is released (a run is never held by a page that is gone)."""
        if not client.controlling or any(c.controlling for c in self._clients):
            return
        if self._paused.is_set():
            self._paused.clear()
            self.log(f"pause released: {client.peer}, the last page steering the run, is gone")

    def _handle(self, client: _Client, data: str) -> None:
        try:
            msg = protocol.parse_message(data, self.controls, fields=self._fields(),
                                         frames=self.frames if self.mode == "view" else None, ranges=self.ranges)
            if self.mode == "view" and msg["type"] in ("control", "pause", "resume"):
                raise protocol.MessageError(f"{msg['type']}: a recorded run cannot be steered")
        except protocol.MessageError as exc:
            self._reject(client.peer, str(exc))
            return
        kind = msg["type"]
        if kind in ("control", "pause", "resume"):
            client.controlling = True
        if kind != "ready":  # (flow control is not counted: tests count what the page asked for)
            self.accepted += 1
        if kind == "control":
            with self._lock:
                self._current.update({k: v for k, v in msg.items() if k != "type"})
                self._control = {k: list(v) for k, v in self._current.items()}
        elif kind == "pause":
            self._paused.set()
        elif kind == "resume":
            self._paused.clear()
        elif kind == "color":
            client.color = msg["field"]
            client.dirty = True
            client.event.set()
        elif kind == "seek":
            client.want = msg["frame"]
            client.event.set()
        elif kind == "ready":  # the page drew a frame: it may have another
            client.credits = min(CREDITS, (client.credits if client.credits is not None else CREDITS - 1) + 1)
            client.event.set()

    async def _sender(self, client: _Client) -> None:
        loop = asyncio.get_running_loop()
        last_view: tuple[int, dict] | None = None
        try:
            while not client.ws.closed:
                await client.event.wait()
                client.event.clear()
                if client.credits is not None and client.credits <= 0:
                    continue  # the page has not drawn what it was sent: the next "ready" wakes this
                if self.mode == "live":
                    with self._lock:
                        latest = self._latest
                    if latest is None or (latest[0] == client.sent_seq and not client.dirty):
                        continue
                    seq, frame = latest
                else:
                    if client.want is None:
                        if not client.dirty or last_view is None:
                            continue
                        seq, frame = last_view
                    else:
                        seq, client.want = client.want, None
                        frame = await loop.run_in_executor(None, self.source, seq)
                        last_view = (seq, frame)
                client.dirty = False
                data = await loop.run_in_executor(None, self._encoded, seq, frame, client.color)
                await client.ws.send_bytes(data)  # waits while this client's socket is full
                client.sent_seq = seq
                client.sent += 1
                if client.credits is not None:
                    client.credits -= 1
        except (asyncio.CancelledError, ConnectionError):
            pass
        except Exception as exc:  # noqa: BLE001 - one client's failure never reaches the run
            self.log(f"stopped sending to {client.peer}: {_reason(exc)}")

    def _encoded(self, seq: int, frame: dict, color: str | None) -> bytes:
        key = (self.mode, seq, color)
        with self._cache_lock:
            data = self._cache.get(key)
        if data is not None:
            return data
        data = encode(frame, self.header, color)
        with self._cache_lock:
            self._cache = {k: v for k, v in self._cache.items() if k[1] == seq}
            self._cache[key] = data
        return data


def default_color(header: dict, fields: list[str]) -> str | None:
    """The field a new page colours by: the kind's choice (the header's ``render`` entry) when
    the frames carry it, else density, else the first field."""
    hinted = render_hint(header).get("color")
    if hinted in fields:
        return hinted
    return "density" if "density" in fields else (fields[0] if fields else None)


def encode(frame: dict, header: dict, color: str | None) -> bytes:
    """A frame dict (see :class:`LiveServer`) as one binary message."""
    pos = np.asarray(frame["positions"])
    lo, hi = protocol.domain_box(header, pos)
    overlay = dict(frame.get("overlay") or {})
    col = None
    values = (frame.get("fields") or {}).get(color) if color else None
    if values is not None and len(values) == len(pos):
        hint = render_hint(header)
        col, vrange = protocol.color_bytes(values, hint.get("range") if hint.get("color") == color else None)
        overlay["color"] = {"field": color, "range": vrange,
                            "unit": (header.get("units") or {}).get(color, "")}
    return protocol.encode_frame(frame.get("index", 0), frame.get("step", 0), frame.get("time", 0.0), pos,
                                 lo, hi, overlay, col)


def _scene_geometry(header: dict, log: Callable[[str], None]) -> dict | None:
    """The header's scene description checked and normalised for the page (render's
    ``scene_info``: numbers where numbers belong, a 2-D box obstacle's corners), or None
    (logged) where it is malformed: the page then draws the particles only."""
    from .._viz_common import HeaderError, scene_info

    try:
        return scene_info(header)
    except HeaderError as exc:
        log(f"the run header's scene is not drawn: {exc}")
        return None


def _static_bytes(name: str) -> bytes:
    return (importlib.resources.files("corpuscle.live") / "static" / name).read_bytes()


def _split_authority(authority: str) -> tuple[str, str] | None:
    """``name[:port]`` or ``[v6]:port`` as (name, port), port "" when absent; None if malformed."""
    if authority.startswith("["):
        end = authority.find("]")
        rest = authority[end + 1:] if end > 0 else "x"
        if end < 0 or (rest and not rest.startswith(":")):
            return None
        return authority[1:end], rest[1:]
    if authority.count(":") > 1 or not authority:
        return None
    name, _, port = authority.partition(":")
    return (name, port) if name else None


def _wildcard(host: str) -> bool:
    """Whether ``host`` binds every address of this machine (0.0.0.0, ::, empty)."""
    return host.strip("[]") in ("", "0.0.0.0", "::")


def _peer(request) -> str:
    return str(request.remote or "?")


def _reason(exc: BaseException | None) -> str:
    if exc is None:
        return "unknown"
    text = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
    return " ".join(str(text).split())
