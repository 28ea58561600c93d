"""The listening socket's gate: a bounded number of connections, TLS within a deadline.

The recorder listens on 0.0.0.0 for one phone (and one headset); anyone on the network can open
connections. Measured before this gate: 2000 idle TCP connections that never start TLS took the
recorder from 136 MB to 726 MB, since asyncio gives each one a TLS state and aiohttp a request
handler, and keeps them for 60 s. aiohttp has no connection limit, so this protocol factory sits
in front of aiohttp's own (``AppRunner.server``):

- at most ``limit`` connections at a time; when full, the oldest connection that has not yet sent
  a byte of HTTP (no TLS handshake done, or silent after it) is dropped for the new one, so idle
  connections cannot lock out the real phone; if every connection is busy, the new one is refused;
- TLS is started here (``loop.start_tls``) with ``handshake_timeout_s``, and a connection that sends
  no request within ``first_request_s`` is closed; aiohttp's request handler is made only then.
"""

from __future__ import annotations

import asyncio
import ssl
from collections import OrderedDict
from collections.abc import Callable
from typing import cast


class ConnectionGate:
    """Protocol factory for ``loop.create_server``; ``handlers`` makes aiohttp's protocol."""

    def __init__(self, handlers: Callable[[], asyncio.BaseProtocol], ssl_context: ssl.SSLContext | None, *,
                 limit: int, handshake_timeout_s: float, first_request_s: float) -> None:
        self.handlers = handlers
        self.ssl_context = ssl_context
        self.limit = limit
        self.handshake_timeout_s = handshake_timeout_s
        self.first_request_s = first_request_s
        self.open = 0
        self.dropped = 0                  # idle connections closed for a newer one, or for silence
        self.refused = 0                  # new connections refused (every slot busy)
        self._silent: OrderedDict[int, _Gated] = OrderedDict()   # counted, no request byte yet

    def __call__(self) -> asyncio.Protocol:
        return _Gated(self)

    def admit(self, conn: _Gated) -> bool:
        if self.open >= self.limit and self._silent:
            _, oldest = self._silent.popitem(last=False)
            self.dropped += 1
            oldest.close()   # its slot is free now, not only when asyncio reports the loss
        if self.open >= self.limit:
            self.refused += 1
            return False
        self.open += 1
        self._silent[id(conn)] = conn
        return True

    def spoke(self, conn: _Gated) -> None:
        self._silent.pop(id(conn), None)

    def release(self, conn: _Gated) -> None:
        self._silent.pop(id(conn), None)
        self.open -= 1


class _Gated(asyncio.Protocol):
    """One accepted connection: TLS first, then aiohttp's handler, which then sees every event."""

    def __init__(self, gate: ConnectionGate) -> None:
        self.gate = gate
        self.raw: asyncio.Transport | None = None
        self.handler: asyncio.Protocol | None = None
        self.counted = False
        self.spoke = False
        self._early: list[bytes] = []       # decrypted bytes that came before the handler existed
        self._timer: asyncio.TimerHandle | None = None

    # ------------------------------------------------------------------ raw connection
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.raw = raw = cast(asyncio.Transport, transport)   # a TCP server's transports are Transports
        if not self.gate.admit(self):
            raw.abort()
            return
        self.counted = True
        loop = asyncio.get_running_loop()
        self._timer = loop.call_later(self.gate.first_request_s, self._silent_too_long)
        if self.gate.ssl_context is None:
            self._attach(raw)
        else:
            asyncio.ensure_future(self._start_tls(raw))

    async def _start_tls(self, raw: asyncio.Transport) -> None:
        loop = asyncio.get_running_loop()
        assert self.gate.ssl_context is not None
        if raw.is_closing():
            # dropped before this task ran: a TLS start on it now would arm a handshake timer that
            # keeps the protocol and its 256 KiB buffer alive for the whole timeout (measured: 300 of
            # 2000 dropped connections still held 2 s later)
            self.connection_lost(None)
            return
        try:
            tls = await loop.start_tls(raw, self, self.gate.ssl_context, server_side=True,
                                       ssl_handshake_timeout=self.gate.handshake_timeout_s)
        except (TimeoutError, OSError, ssl.SSLError, ConnectionError, RuntimeError):
            tls = None
        if tls is None or raw.is_closing():   # start_tls returns None when the peer left mid-handshake
            raw.abort()   # asyncio tells the app protocol nothing of a failed handshake: release here
            self.connection_lost(None)
            return
        self._attach(tls)

    def _attach(self, transport: asyncio.BaseTransport) -> None:
        self.handler = cast(asyncio.Protocol, self.gate.handlers())   # aiohttp's RequestHandler
        self.handler.connection_made(transport)
        early, self._early = self._early, []
        for data in early:
            self.handler.data_received(data)

    def _silent_too_long(self) -> None:
        if not self.spoke:
            self.gate.dropped += 1
            self.close()

    def close(self) -> None:
        if self._timer is not None:
            self._timer.cancel()   # the timer holds this object (and its TLS buffers) alive
        if self.counted:
            self.counted = False
            self.gate.release(self)
        if self.raw is not None and not self.raw.is_closing():
            self.raw.abort()

    # ------------------------------------------------------------------ forwarded to aiohttp
    def data_received(self, data: bytes) -> None:
        if not self.spoke:
            self.spoke = True
            self.gate.spoke(self)
        if self.handler is None:
            self._early.append(data)
        else:
            self.handler.data_received(data)

    def eof_received(self) -> bool | None:
        return self.handler.eof_received() if self.handler is not None else None

    def pause_writing(self) -> None:
        if self.handler is not None:
            self.handler.pause_writing()

    def resume_writing(self) -> None:
        if self.handler is not None:
            self.handler.resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        if self._timer is not None:
            self._timer.cancel()
        if self.counted:
            self.counted = False
            self.gate.release(self)
        if self.handler is not None:
            self.handler.connection_lost(exc)
        self.handler = None
        self.raw = None
