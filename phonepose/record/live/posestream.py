"""The pose stream: live trackers' estimates as JSON lines over a WebSocket, for applications.

``ws://127.0.0.1:PORT/poses`` by default (loopback: no token needed). Opened to the network (a host other than
loopback, as ``record live --pose-host``), it is ``wss://`` with the recording's certificate and wants the phone
page's token (``?token=...``), like the phone page. Each text message is one line (docs/recording-real-sessions.md,
"Live tracking"; ``examples/pose_client.py`` reads it). A slow client never delays tracking: each client has a
bounded queue, and what does not fit is dropped and counted.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import secrets
import threading
from collections.abc import Callable

from aiohttp import WSMsgType, web

CLIENT_QUEUE_MAX = 256     # lines waiting for one client (~2.5 s of 5 trackers at 20 Hz)
PATH = "/poses"
CLOSE_WAIT_S = 2.0         # at the end, how long queued lines may take to go out before the stream closes


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class PoseStreamServer:
    """The WebSocket server in its own thread and asyncio loop; :meth:`send` from any thread, never blocking."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, *, token: str = "", ssl_context=None,
                 warn: Callable[[str], None] = lambda text: None, queue_max: int = CLIENT_QUEUE_MAX):
        self.host = host
        self.port = port
        self.open = not is_loopback(host)          # opened to the network: token and TLS
        self.token = token
        self.ssl_context = ssl_context if self.open else None
        self.warn = warn
        self.queue_max = queue_max
        self.clients: set[asyncio.Queue] = set()
        self.dropped = 0
        self.refused = 0
        self.served = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._runner: web.AppRunner | None = None
        self._sockets: set[web.WebSocketResponse] = set()

    @property
    def url(self) -> str:
        shown = self.host if self.host not in ("0.0.0.0", "::", "") else "localhost"
        query = f"?token={self.token}" if self.open else ""
        return f"{'wss' if self.open else 'ws'}://{shown}:{self.port}{PATH}{query}"

    def start(self) -> int:
        """Bind (OSError if the port is taken); returns the port."""
        loop = self._loop = asyncio.new_event_loop()
        ready = threading.Event()

        def run() -> None:
            asyncio.set_event_loop(loop)
            loop.call_soon(ready.set)
            loop.run_forever()
            loop.close()

        self._thread = threading.Thread(target=run, name="phonepose-pose-stream", daemon=True)
        self._thread.start()
        ready.wait()
        try:
            self.port = asyncio.run_coroutine_threadsafe(self._start(), loop).result(timeout=10)
        except BaseException:
            self._stop_loop()
            raise
        return self.port

    async def _start(self) -> int:
        app = web.Application()
        app.router.add_get(PATH, self._handle)
        self._runner = web.AppRunner(app, access_log=None, shutdown_timeout=2.0)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port, ssl_context=self.ssl_context)
        await site.start()
        return int(self._runner.addresses[0][1])

    async def _handle(self, request: web.Request) -> web.StreamResponse:
        if self.open and not secrets.compare_digest(request.query.get("token", ""), self.token):
            self.refused += 1
            return web.Response(status=403, text="wrong or missing token\n")
        ws = web.WebSocketResponse(heartbeat=20.0)
        await ws.prepare(request)
        q: asyncio.Queue = asyncio.Queue(maxsize=self.queue_max)
        self.clients.add(q)
        self._sockets.add(ws)
        self.served += 1

        async def pump() -> None:
            while True:
                line = await q.get()
                await ws.send_str(line)
                q.task_done()

        sender = asyncio.ensure_future(pump())
        try:
            async for msg in ws:   # the client says nothing; this ends when it goes
                if msg.type == WSMsgType.ERROR:
                    break
        finally:
            self.clients.discard(q)
            self._sockets.discard(ws)
            sender.cancel()
        return ws

    def send(self, lines: list[str]) -> None:
        """Queue ``lines`` for every client (any thread)."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        try:
            loop.call_soon_threadsafe(self._fan_out, lines)
        except RuntimeError:    # the loop closed meanwhile (stopping)
            pass

    def _fan_out(self, lines: list[str]) -> None:
        for q in list(self.clients):
            for line in lines:
                try:
                    q.put_nowait(line)
                except asyncio.QueueFull:
                    self.dropped += 1

    def stop(self) -> None:
        if self._loop is None or self._thread is None or not self._thread.is_alive():
            return
        if self._runner is not None:
            try:
                asyncio.run_coroutine_threadsafe(self._close(), self._loop).result(timeout=10)
            except Exception:  # noqa: BLE001 - stopping: the clients are gone either way
                pass
        self._stop_loop()

    async def _close(self) -> None:
        # what is queued goes out first (a client keeping up gets every line), for at most CLOSE_WAIT_S
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(asyncio.gather(*(q.join() for q in list(self.clients))), CLOSE_WAIT_S)
        for ws in list(self._sockets):   # the clients see the stream end (close code 1001: going away)
            await ws.close(code=1001, message=b"recording stopped")
        assert self._runner is not None
        await self._runner.cleanup()

    def _stop_loop(self) -> None:
        if self._loop is not None and self._thread is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=10)

    def summary(self) -> list[str]:
        out = [f"pose stream: {self.served} client(s) served"]
        if self.dropped:
            out[0] += f", {self.dropped} line(s) dropped for slow clients"
        if self.refused:
            out[0] += f", {self.refused} request(s) refused without the right token"
        return out
