"""The HTTPS + WebSocket server the phone's page talks to (aiohttp).

Routes (the protocol, shared with the page in ``static/``; docs/recording-real-sessions.md):

- ``GET /?token=T`` the page (``static/index.html``); ``/static/...`` its assets;
  ``GET /marker.png?token=T`` the marker; ``GET /config?token=T`` ``{"marker": {"dictionary", "id"}}``.
- ``GET /ws?token=T`` the phone's WebSocket: JSON text messages ``hello``, ``marker``, ``pose``, ``imu``,
  ``anchor``, ``pong`` from the page; ``ping``, ``status``, ``error`` from us.
- ``GET /headset?token=T`` the headset page (``static/headset.html``, the ground truth: docs/phone-page.md
  "The headset page"); ``GET /ws?token=T&role=headset`` its WebSocket: ``hello``, ``xrsession``,
  ``xrframe``, ``pong`` from the page; ``ping``, ``status``, ``error`` from us.

Every route but ``/static/`` needs the recording's token (``secrets.compare_digest``); without it
the answer is 403 and nothing from that request reaches the session. One phone and one headset at a
time (:data:`ROLES`): a new connection replaces the previous one of its role (a reloaded page). A
malformed message (not JSON, unknown type, one of the other role's types, missing or non-finite fields,
a number out of range (:data:`MAX_STAMP_MS`, :data:`MAX_VALUE`), a non-unit quaternion) is counted,
logged once per kind and connection (terminal, ``/log``, an
``error`` message to the page) and ignored; the connection stays.

Stamping: each connection has its own :class:`~phonepose.record.live.clock.OffsetEstimator`
(5 pings at connect, then one a second). Samples wait until the 5 connect pings are answered, or
:data:`PENDING_TIMEOUT_S` has passed and at least one pong came: nothing is stamped without an
offset, and nothing well-formed is dropped while waiting (see :meth:`Connection.settle` for a link
that never answers). Each later pong refines the offset (the fastest exchange of the window wins).
``capture = t - offset`` goes into the message ``timestamp``; the receipt time is the MCAP log time.
"""

from __future__ import annotations

import asyncio
import inspect
import json
import logging
import math
import secrets
import statistics
from pathlib import Path
from typing import Any

from aiohttp import WSMessage, WSMsgType, web

from phonepose.geometry import QUAT_NORM_TOL
from phonepose.record.live.clock import OffsetEstimator
from phonepose.record.live.gate import ConnectionGate
from phonepose.record.live.headset import TEXT_LIMIT
from phonepose.record.live.recording import LiveRecording
from phonepose.record.live.websocket import PageSocket
from phonepose.text import printable

STATIC_DIR = Path(__file__).parent / "static"
PING_AT_CONNECT = 5
PING_AT_CONNECT_SPACING_S = 0.05
PING_PERIOD_S = 1.0
PENDING_TIMEOUT_S = 0.5
MAX_PENDING = 30_000                  # samples waiting for a first pong (~60 s of poses and IMU); then a fallback
MAX_MESSAGE_BYTES = 1 << 16            # a text message above this is ignored (logged once per kind, counted)
MAX_FRAME_BYTES = 1 << 22              # above this aiohttp closes the connection (1009): memory bound
MAX_CAPTURE_SKEW_NS = 5_000_000_000   # a sample stamped further than this from its receipt is rejected
OFFSET_LOG_CHANGE_NS = 2_000_000      # log the offset again when the estimate moves this much
DRAIN_QUIET_S = 0.1                   # at stop: the page's messages already in flight are still taken
DRAIN_MAX_S = 2.0
MAX_CONNECTIONS = 64                  # open TCP connections at a time (a phone page uses a few); see gate.py
RESERVED_FOR_TOKEN = 16               # of them, only for connections whose request carried the token
PER_ADDRESS = 16                      # connections without the token from one address (a browser opens ~6)
REQUEST_DEADLINE_S = 5.0              # TLS and a whole request head within this, or the connection is closed
LOGGED_CONNECTIONS = 20               # WebSockets whose own lines are logged; later ones' are counted (Connection.log)
KEEPALIVE_S = 15.0                    # an idle HTTP keep-alive connection is closed after this
CLOSE_TIMEOUT_S = 2.0                 # how long a close waits for the page's close frame (a vanished phone)
ROLES = ("phone", "headset")          # one connection of each at a time
MAX_XR_INPUTS = 8                     # controllers listed in one xrframe (a headset has 2; hands and trackers add some)
HANDS = ("left", "right", "none")     # XRInputSource.handedness
# A page time ``t`` (ms; performance.timeOrigin + now, ~1.8e12 today) must be within this: ~2096 as Unix ms,
# so ``t * 1e6`` ns and any difference of two such stay within int64 (9.2e18 ns), what MCAP and the
# protobuf Timestamp hold; a bigger finite ``t`` (1e305) would overflow the stamping arithmetic.
MAX_STAMP_MS = 4e12
MAX_VALUE = 1e6                       # |every other number| (m, rad/s, m/s^2, ppi): far beyond any sensor
MAX_ID = 2**31 - 1                    # a marker or ping id
# the message types each role may send (samples wait for the clock offset, see Connection.settle)
MESSAGE_TYPES = {"phone": ("hello", "marker", "pose", "imu", "anchor", "pong"),
                 "headset": ("hello", "xrsession", "xrframe", "pong")}
SAMPLE_TYPES = ("pose", "imu", "anchor", "xrframe")


class Malformed(ValueError):
    """A message that does not follow the protocol; ``kind`` groups them for the logs."""

    def __init__(self, kind: str, detail: str = ""):
        super().__init__(kind + (f": {detail}" if detail else ""))
        self.kind = kind


def _finite(v) -> bool:
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        return False
    try:
        return math.isfinite(v)
    except OverflowError:   # an int beyond float range
        return False


def _field(msg: dict, name: str):
    if name not in msg:
        raise Malformed(f"{msg['type']} without '{name}'")
    return msg[name]


def _in_range(v, bound: float) -> bool:
    return _finite(v) and -bound <= v <= bound


def _number(msg: dict, name: str, bound: float = MAX_VALUE) -> float:
    v = _field(msg, name)
    if not _finite(v):
        raise Malformed(f"{msg['type']} '{name}' is not a finite number", repr(v)[:40])
    if not -bound <= v <= bound:
        raise Malformed(f"{msg['type']} '{name}' is out of range", f"{float(v):.3g}, limit +-{bound:g}")
    return float(v)


def _stamp(msg: dict) -> float:
    """The page time ``t`` (ms), one the recorder's int64-ns arithmetic can take (:data:`MAX_STAMP_MS`)."""
    return _number(msg, "t", MAX_STAMP_MS)


def _id(msg: dict, what: str) -> int:
    i = _field(msg, "id")
    if not isinstance(i, int) or isinstance(i, bool):
        raise Malformed(f"{what} 'id' is not an integer")
    if not 0 <= i <= MAX_ID:
        raise Malformed(f"{what} 'id' is out of range", f"limit {MAX_ID}")
    return i


def _vector(msg: dict, name: str, n: int) -> list[float]:
    v = _field(msg, name)
    if not isinstance(v, list) or len(v) != n or not all(_finite(x) for x in v):
        raise Malformed(f"{msg['type']} '{name}' is not {n} finite numbers", repr(v)[:60])
    if not all(-MAX_VALUE <= x <= MAX_VALUE for x in v):
        raise Malformed(f"{msg['type']} '{name}' is out of range", f"limit +-{MAX_VALUE:g}")
    return [float(x) for x in v]


def _quaternion(msg: dict, name: str = "q") -> list[float]:
    q = _vector(msg, name, 4)
    n = math.sqrt(sum(x * x for x in q))
    if abs(n - 1.0) > QUAT_NORM_TOL:
        raise Malformed(f"{msg['type']} '{name}' is not a unit quaternion", f"|q| = {n:.6g}")
    return q


def parse_message(text: str) -> dict:
    """One client message, checked against the protocol (raises :class:`Malformed`)."""
    try:
        msg = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise Malformed("not JSON", str(exc)[:60]) from None
    if not isinstance(msg, dict) or not isinstance(msg.get("type"), str):
        raise Malformed("not a JSON object with a string 'type'")
    kind = msg["type"]
    if kind == "hello":
        return {"type": kind, "user_agent": str(msg.get("user_agent", ""))[:300],
                "webxr": bool(msg.get("webxr", False)), "message": str(msg.get("message", ""))[:300]}
    if kind == "marker":
        d, i = _field(msg, "dictionary"), _field(msg, "id")
        if not isinstance(d, str) or not isinstance(i, int) or isinstance(i, bool):
            raise Malformed("marker 'dictionary' must be a string and 'id' an integer")
        i = _id(msg, "marker")
        size = _number(msg, "size_m")
        if not 0.0 < size < 1.0:
            raise Malformed("marker 'size_m' must be in (0, 1) m", repr(size))
        return {"type": kind, "dictionary": d[:100], "id": i, "size_m": size,
                "ppi": float(msg["ppi"]) if _in_range(msg.get("ppi"), MAX_VALUE) else float("nan"),
                "device_pixel_ratio": float(msg["device_pixel_ratio"])
                if _in_range(msg.get("device_pixel_ratio"), MAX_VALUE) else float("nan")}
    if kind in ("pose", "anchor"):
        return {"type": kind, "t": _stamp(msg), "p": _vector(msg, "p", 3), "q": _quaternion(msg)}
    if kind == "imu":
        return {"type": kind, "t": _stamp(msg), "gyro": _vector(msg, "gyro", 3), "accel": _vector(msg, "accel", 3)}
    if kind == "pong":
        return {"type": kind, "id": _id(msg, "pong"), "t": _stamp(msg)}
    if kind == "xrsession":
        state, space = _field(msg, "state"), msg.get("space", "")
        if state not in ("started", "ended") or not isinstance(space, str):
            raise Malformed("xrsession 'state' must be 'started' or 'ended' and 'space' a string")
        return {"type": kind, "state": state, "space": space[:40], "message": str(msg.get("message", ""))[:300]}
    if kind == "xrframe":
        return _xrframe(msg)
    raise Malformed("unknown message type", repr(kind)[:40])


def _xr_pose(msg: dict, where: str, obj) -> tuple[list[float], list[float]] | None:
    """``{"p", "q"}`` of an xrframe entry; None when the entry has neither (no pose this frame)."""
    if not isinstance(obj, dict):
        raise Malformed(f"xrframe '{where}' is not an object")
    if "p" not in obj and "q" not in obj:
        return None
    sub = {"type": f"xrframe {where}", **obj}
    return _vector(sub, "p", 3), _quaternion(sub)


def _xrframe(msg: dict) -> dict:
    """One XR frame of the headset page: the viewer's pose (or null: not tracked) and every controller's
    grip pose (``hand`` and no ``p``/``q``: that controller is not tracked this frame); WebXR's numbers,
    converted in phonepose/record/live/webxr.py."""
    t = _stamp(msg)
    viewer = msg.get("viewer")
    controllers = _field(msg, "controllers")
    if not isinstance(controllers, list) or len(controllers) > MAX_XR_INPUTS:
        raise Malformed(f"xrframe 'controllers' is not a list of at most {MAX_XR_INPUTS}")
    out = []
    for c in controllers:
        if not isinstance(c, dict) or c.get("hand") not in HANDS:
            raise Malformed("xrframe controller 'hand' is not one of " + ", ".join(HANDS))
        out.append((c["hand"], _xr_pose(msg, "controller", c)))
    return {"type": "xrframe", "t": t, "viewer": None if viewer is None else _xr_pose(msg, "viewer", viewer),
            "controllers": out}


# aiohttp >= 3.13 can hand text over undecoded; older versions close on invalid UTF-8 (1007) themselves
_RAW_TEXT: dict[str, Any] = {"decode_text": False} if "decode_text" in inspect.signature(web.WebSocketResponse).parameters else {}


@web.middleware
async def _no_traceback(request: web.Request, handler):
    """A path the file system cannot look up (e.g. 3000 levels deep: "File name too long") is a 404,
    not a traceback on the recorder's terminal."""
    try:
        return await handler(request)
    except OSError:
        raise web.HTTPNotFound() from None


class _RequestErrors(logging.Handler):
    """aiohttp's request-handling log (bad request lines, oversized headers, handler errors) as one
    line per kind on the terminal and ``/log`` and a count, instead of a traceback per request."""

    def __init__(self, recording: LiveRecording) -> None:
        super().__init__(level=logging.WARNING)
        self.recording = recording
        self.logger = logging.getLogger(f"phonepose.live.http.{id(self)}")
        self.logger.propagate = False
        self.logger.addHandler(self)

    def emit(self, record: logging.LogRecord) -> None:
        exc = record.exc_info[1] if record.exc_info else None
        kind = type(exc).__name__ if exc is not None else printable(record.getMessage(), 60)
        self.recording.repeated(f"bad HTTP requests ({kind})", "http")


class Connection:
    """One WebSocket from the page: its clock offset, the samples waiting for it, its counters."""

    def __init__(self, server: LiveServer, sock: PageSocket, peer: str, number: int, role: str = "phone"):
        self.server = server
        self.rec = server.recording
        self.sock = sock
        self.ws = sock.ws
        self.peer = peer
        self.role = role
        self.number = number
        self.name = f"{role} #{number} ({peer})"
        self.clock = OffsetEstimator()
        self.fallback_offset_ns: int | None = None
        self.settled = False                           # stamping has started (see settle())
        self.connect_wait_over = False                 # PENDING_TIMEOUT_S has passed since the connect pings
        self.pending: list[tuple[dict, int]] = []      # (message, receipt ns) waiting for the offset
        self.malformed_kinds: set[str] = set()
        self.logged_offset_ns: int | None = None
        self.opened_ns = self.rec.clock.now_ns()
        self.received = 0
        self.hellos = 0
        self.last_receipt_ns = self.opened_ns
        self.tasks: set[asyncio.Task] = set()

    def log(self, text: str, level: str = "info", echo: bool = True) -> None:
        """A line about this connection (the terminal and /log). A page that reconnects in a loop must not flood
        either: from connection LOGGED_CONNECTIONS + 1 on, the lines are counted (closing summary)."""
        if self.number <= LOGGED_CONNECTIONS:
            self.rec.log(f"{self.name}: {text}", level=level, echo=echo)
        elif self.number == LOGGED_CONNECTIONS + 1 and text == "connected":
            self.rec.log(f"{self.name}: connected; the lines of this and later connections are only counted "
                         f"(closing summary)", level=level, echo=echo)
        else:
            self.rec.unlogged[f"lines of connections after the first {LOGGED_CONNECTIONS}"] += 1

    # ------------------------------------------------------------------ sending
    async def send(self, obj: dict) -> None:
        if self.ws.closed:
            return
        try:
            await self.ws.send_str(json.dumps(obj))
        except (ConnectionError, RuntimeError):
            pass   # the page went away; the receive loop ends on its own

    def send_soon(self, obj: dict) -> None:
        task = asyncio.ensure_future(self.send(obj))
        self.tasks.add(task)
        task.add_done_callback(self.tasks.discard)

    # ------------------------------------------------------------------ clock
    @property
    def offset_ns(self) -> int | None:
        off = self.clock.offset_ns
        return off if off is not None else self.fallback_offset_ns

    def capture_ns(self, t_ms: float) -> int:
        offset = self.offset_ns
        assert offset is not None, "stamping starts only once an offset exists (settle())"
        return int(round(t_ms * 1e6)) - offset

    def settle(self) -> None:
        """Start stamping, once an offset exists: at the first pong after the connect pings were all
        answered or :data:`PENDING_TIMEOUT_S` passed; before that every sample waits in ``pending``.

        With no pong at all (a Wi-Fi link that answers pings late or never) the samples keep waiting;
        only when :data:`MAX_PENDING` wait, or the connection ends, is an offset taken from them:
        the median of their ``t - receipt`` (zero network delay assumed; a median, so no single odd
        sample sets it), logged. A pong later replaces it.
        """
        if self.settled:
            return
        if self.clock.best() is None:
            if not self.pending:
                return
            # every waiting t is within MAX_STAMP_MS (parse_message), so this is plain int64-range arithmetic
            self.fallback_offset_ns = int(statistics.median(int(round(m["t"] * 1e6)) - r for m, r in self.pending))
            self.log(f"no answer to the clock pings; {len(self.pending)} samples stamped assuming zero network delay "
                     f"(page clock offset {self.fallback_offset_ns / 1e6:+.1f} ms) until one arrives", level="warning")
        else:
            self._log_offset(force=True)
        self.settled = True
        self.flush_pending()

    def _waiting_note(self) -> None:
        """At :data:`PENDING_TIMEOUT_S` with no pong: say once that samples wait (none is dropped)."""
        if not self.settled and self.clock.best() is None:
            self.log(f"no answer to the clock pings within {PENDING_TIMEOUT_S:g} s (Wi-Fi power saving?); samples "
                     f"wait for one, none is dropped", level="warning")

    def flush_pending(self) -> None:
        """Stamp every waiting sample; one that fails (a bug, not the page's fault) costs only itself."""
        pending, self.pending = self.pending, []
        for msg, receipt in pending:
            try:
                self.dispatch(msg, receipt)
            except Exception as exc:   # noqa: BLE001 - the samples behind it must still be written
                self.unexpected(exc)

    def _log_offset(self, force: bool = False) -> None:
        best = self.clock.best()
        if best is None:
            return
        if force or self.logged_offset_ns is None or abs(best.offset_ns - self.logged_offset_ns) >= OFFSET_LOG_CHANGE_NS:
            self.logged_offset_ns = best.offset_ns
            self.log(f"page clock offset {best.offset_ns / 1e6:+.1f} ms (best round trip {best.rtt_ns / 1e6:.1f} ms "
                     f"of {len(self.clock.exchanges)})", echo=force)

    # ------------------------------------------------------------------ receiving
    def handle_frame(self, data: bytes | str, receipt_ns: int) -> None:
        """A text message as received (bytes: aiohttp does not decode it, see LiveServer)."""
        if isinstance(data, str):
            data = data.encode("utf-8", "surrogatepass")
        if len(data) > MAX_MESSAGE_BYTES:
            self._count_received(receipt_ns)
            self.malformed(Malformed(f"text message over {MAX_MESSAGE_BYTES // 1024} KiB", f"{len(data)} bytes"))
            return
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError as exc:
            self._count_received(receipt_ns)
            self.malformed(Malformed("text message that is not valid UTF-8", f"byte {exc.start}"))
            return
        self.handle_text(text, receipt_ns)

    def _count_received(self, receipt_ns: int) -> None:
        self.received += 1
        self.last_receipt_ns = receipt_ns
        self.rec.stats["messages"] += 1

    def handle_text(self, text: str, receipt_ns: int) -> None:
        self._count_received(receipt_ns)
        try:
            msg = parse_message(text)
        except Malformed as exc:
            self.malformed(exc)
            return
        kind = msg["type"]
        if kind not in MESSAGE_TYPES[self.role]:
            self.malformed(Malformed(f"{kind} message on the {self.role}'s connection"))
            return
        if kind == "pong":
            if self.clock.pong(msg["id"], msg["t"], receipt_ns) is None:
                self.rec.stats["pongs rejected"] += 1
                return
            if self.settled:
                self._log_offset()
            elif len(self.clock.exchanges) >= PING_AT_CONNECT or self.connect_wait_over:
                self.settle()
            return
        if kind in SAMPLE_TYPES and not self.settled:
            self.pending.append((msg, receipt_ns))
            if len(self.pending) >= MAX_PENDING:
                self.settle()
            return
        self.dispatch(msg, receipt_ns)

    def malformed(self, exc: Malformed) -> None:
        if self._count_malformed(exc.kind):
            self.log(f"ignored a malformed message ({printable(str(exc), TEXT_LIMIT)}); further ones of this kind "
                     f"are only counted", level="warning")
            self.send_soon({"type": "error", "message": f"ignored malformed message: {exc}"})

    def unexpected(self, exc: Exception) -> None:
        """A message that passed the checks and still raised (a recorder bug): counted as malformed, logged
        once per exception type and connection, ignored; the connection and the messages after it go on."""
        if self._count_malformed(f"could not be handled ({type(exc).__name__})"):
            self.log(f"a message could not be handled ({type(exc).__name__}: {printable(str(exc), 80)}); ignored, "
                     f"further ones are only counted", level="error")

    def _count_malformed(self, kind: str) -> bool:
        """Count one ignored message of ``kind``; True the first time on this connection (log it then)."""
        self.rec.stats["malformed"] += 1
        self.rec.malformed_kinds[kind] += 1
        first = kind not in self.malformed_kinds
        self.malformed_kinds.add(kind)
        return first

    def dispatch(self, msg: dict, receipt_ns: int) -> None:
        kind = msg["type"]
        try:
            if kind == "hello":
                self.hellos += 1
                if self.hellos == 1:
                    (self.rec.headset.on_hello if self.role == "headset" else self.rec.on_hello)(self.name, msg)
                else:   # a page sends one per connection; more are counted, logged once
                    self.rec.repeated("hello messages after the first on a connection", self.name)
            elif kind == "marker":
                error = self.rec.on_marker(self.name, msg)
                if error:
                    self.send_soon({"type": "error", "message": error})
                self.send_soon(self.rec.status())
            elif kind == "xrsession":
                self.rec.headset.on_session(self.name, msg)
            elif kind in SAMPLE_TYPES:
                capture = self.capture_ns(msg["t"])
                if abs(capture - receipt_ns) > MAX_CAPTURE_SKEW_NS:
                    raise Malformed(f"{kind} 't' is not on the page's clock",
                                    f"{(capture - receipt_ns) / 1e9:+.1f} s from its receipt")
                if kind == "pose":
                    self.rec.on_pose(capture, receipt_ns, msg["p"], msg["q"])
                elif kind == "imu":
                    self.rec.on_imu(capture, receipt_ns, msg["gyro"], msg["accel"])
                elif kind == "xrframe":
                    self.rec.headset.on_frame(self.name, capture, msg["viewer"], msg["controllers"])
                else:
                    task = asyncio.ensure_future(self._anchor(capture, msg))
                    self.tasks.add(task)
                    task.add_done_callback(self.tasks.discard)
        except Malformed as exc:
            self.malformed(exc)

    async def _anchor(self, capture_ns: int, msg: dict) -> None:
        ok, text = await self.rec.resolve_anchor(capture_ns, msg["p"], msg["q"])
        if not ok:
            await self.send({"type": "error", "message": text})
        await self.send(self.rec.status())

    # ------------------------------------------------------------------ lifetime
    async def pinger(self) -> None:
        """5 quick pings at connect, then one (and a status) every second; the pending-samples timeout."""
        for _ in range(PING_AT_CONNECT):
            await self.send(self.clock.ping(self.rec.clock.now_ns()))
            await asyncio.sleep(PING_AT_CONNECT_SPACING_S)
        await self.send(self.rec.status())
        waited = PING_AT_CONNECT * PING_AT_CONNECT_SPACING_S
        if waited < PENDING_TIMEOUT_S and not self.settled:
            await asyncio.sleep(PENDING_TIMEOUT_S - waited)
        self.connect_wait_over = True
        if self.clock.best() is not None:
            self.settle()
        else:
            self._waiting_note()
        while not self.ws.closed:
            await asyncio.sleep(PING_PERIOD_S)
            await self.send(self.clock.ping(self.rec.clock.now_ns()))
            await self.send(self.rec.status())
            self._log_offset()

    async def finish(self) -> None:
        """The page went away: stamp what still waits, let anchors in flight finish."""
        self.settle()
        if self.tasks:
            await asyncio.gather(*list(self.tasks), return_exceptions=True)


class LiveServer:
    """The aiohttp application; :meth:`start` binds it (``port`` 0: any free port)."""

    def __init__(self, recording: LiveRecording, token: str, *, host: str = "0.0.0.0", port: int = 8443,
                 ssl_context=None, marker_png: bytes = b"", static_dir: Path = STATIC_DIR):
        self.recording = recording
        self.token = token
        self.host, self.port = host, port
        self.ssl_context = ssl_context
        self.marker_png = marker_png
        self.static_dir = Path(static_dir)
        self.current: dict[str, Connection] = {}      # role -> its connection being recorded
        self.connections = 0
        self._runner: web.AppRunner | None = None
        self._listener: asyncio.AbstractServer | None = None
        self.gate: ConnectionGate | None = None
        self.app = self._make_app()

    # ------------------------------------------------------------------ HTTP
    def _make_app(self) -> web.Application:
        app = web.Application(client_max_size=MAX_MESSAGE_BYTES, middlewares=[_no_traceback])
        app.router.add_get("/", self._index)
        app.router.add_get("/headset", self._headset)
        app.router.add_get("/marker.png", self._marker)
        app.router.add_get("/config", self._config)
        app.router.add_get("/ws", self._websocket)
        if self.static_dir.is_dir():
            app.router.add_static("/static/", self.static_dir, follow_symlinks=False)
        return app

    def _authorised(self, request: web.Request) -> bool:
        given = request.query.get("token", "")
        ok = secrets.compare_digest(given.encode("utf-8", "replace"), self.token.encode())
        if not ok:
            self.recording.refused(request.remote or "?", request.path, bool(given))
        return ok

    def _page(self, request: web.Request, name: str, what: str) -> web.StreamResponse:
        if not self._authorised(request):
            raise web.HTTPForbidden(text="phonepose: this page needs the link printed by `phonepose record live` "
                                         "(its token is new for every recording)\n")
        page = self.static_dir / name
        if not page.is_file():
            raise web.HTTPServiceUnavailable(text=f"phonepose: the {what} page is not installed (static/{name})\n")
        return web.FileResponse(page, headers={"Cache-Control": "no-store"})

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return self._page(request, "index.html", "phone")

    async def _headset(self, request: web.Request) -> web.StreamResponse:
        return self._page(request, "headset.html", "headset")

    async def _marker(self, request: web.Request) -> web.Response:
        if not self._authorised(request):
            raise web.HTTPForbidden(text="wrong token\n")
        return web.Response(body=self.marker_png, content_type="image/png", headers={"Cache-Control": "no-store"})

    async def _config(self, request: web.Request) -> web.Response:
        if not self._authorised(request):
            raise web.HTTPForbidden(text="wrong token\n")
        d, i = self.recording.marker_dictionary, self.recording.marker_id
        return web.json_response({"marker": {"dictionary": d, "id": i}, "gt_controller": self.recording.headset.gt_hand},
                                 headers={"Cache-Control": "no-store"})

    # ------------------------------------------------------------------ WebSocket
    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        if not self._authorised(request):
            raise web.HTTPForbidden(text="wrong token\n")
        # decode_text=False: text arrives as bytes, so invalid UTF-8 is ignored here (as the protocol
        # says) instead of aiohttp closing the connection with 1007
        ws = web.WebSocketResponse(max_msg_size=MAX_FRAME_BYTES, heartbeat=None, timeout=CLOSE_TIMEOUT_S,
                                   **_RAW_TEXT)
        role = request.query.get("role", "phone")
        if role not in ROLES:
            raise web.HTTPBadRequest(text=f"phonepose: role {role[:20]!r}: expected one of {', '.join(ROLES)}\n")
        await ws.prepare(request)
        self.connections += 1
        conn = Connection(self, PageSocket(ws), request.remote or "?", self.connections, role)
        previous, self.current[role] = self.current.get(role), conn
        if previous is not None and not previous.sock.closed:
            previous.log(f"replaced by {conn.name}", level="warning")
            await previous.send({"type": "error", "message": "another page connected; this one is no longer recorded"})
            previous.sock.ask_close()   # its own handler closes it; this page is served meanwhile
        conn.log("connected")
        pinger = asyncio.ensure_future(conn.pinger())
        try:
            await conn.sock.serve(lambda msg: self._on_message(conn, msg))
        finally:
            pinger.cancel()
            await asyncio.gather(pinger, return_exceptions=True)
            await conn.finish()
            why = f"closed (code {ws.close_code})" if ws.close_code is not None else "disconnected"
            conn.log(f"{why} after {conn.received} messages")
            if self.current.get(role) is conn:
                del self.current[role]
        return ws

    def _on_message(self, conn: Connection, msg: WSMessage) -> bool:
        """One message of ``conn``; False ends its connection (replaced, or a broken frame)."""
        receipt = self.recording.clock.now_ns()
        if conn is not self.current.get(conn.role):
            return False
        if msg.type == WSMsgType.TEXT:
            try:
                conn.handle_frame(msg.data, receipt)
            except Exception as exc:   # noqa: BLE001 - one odd message must not end the connection
                conn.unexpected(exc)
        elif msg.type == WSMsgType.BINARY:
            conn.received += 1
            self.recording.stats["messages"] += 1
            conn.malformed(Malformed("binary message (the protocol is JSON text)"))
        elif msg.type == WSMsgType.ERROR:
            return False
        return True

    # ------------------------------------------------------------------ lifetime
    async def _drain(self, conn: Connection) -> None:
        if conn.ws.closed:
            return
        await conn.send({"type": "status", "recording": False, "anchor": self.recording.anchor_set,
                         "marker_seen": False})
        loop = asyncio.get_running_loop()
        t_end = loop.time() + DRAIN_MAX_S
        while not conn.ws.closed and loop.time() < t_end:
            quiet = (self.recording.clock.now_ns() - conn.last_receipt_ns) / 1e9
            if quiet >= DRAIN_QUIET_S:
                break
            await asyncio.sleep(0.02)
        if conn.pending or not conn.settled:
            conn.settle()
        await conn.sock.close(message=b"recording finished")

    async def start(self) -> int:
        self._runner = web.AppRunner(self.app, handle_signals=False, access_log=None, shutdown_timeout=2.0,
                                     keepalive_timeout=KEEPALIVE_S, logger=_RequestErrors(self.recording).logger)
        await self._runner.setup()
        # aiohttp's protocol factory behind the gate (connection cap, TLS and first-request deadlines)
        assert self._runner.server is not None   # made by setup()
        self.gate = ConnectionGate(self._runner.server, self.ssl_context, token=self.token, limit=MAX_CONNECTIONS,
                                   reserved=RESERVED_FOR_TOKEN, per_address=PER_ADDRESS,
                                   deadline_s=REQUEST_DEADLINE_S)
        loop = asyncio.get_running_loop()
        self._listener = await loop.create_server(self.gate, self.host, self.port, reuse_address=True)
        sockets = list(self._listener.sockets or [])
        if sockets:
            self.port = sockets[0].getsockname()[1]
        return self.port

    async def stop(self) -> None:
        """Tell the pages, let the receive loops take what is already on its way (until each socket has been
        quiet for :data:`DRAIN_QUIET_S`, at most :data:`DRAIN_MAX_S`), then close."""
        await asyncio.gather(*(self._drain(conn) for conn in list(self.current.values())))
        if self._listener is not None:
            self._listener.close()
            self._listener = None
        if self.gate is not None and (self.gate.dropped or self.gate.refused):
            self.recording.log(f"connections without the token closed (no request within {REQUEST_DEADLINE_S:g} s, "
                               f"or room made): {self.gate.dropped}, refused (over {PER_ADDRESS} from one address, "
                               f"or every slot taken): {self.gate.refused}", level="warning")
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None
