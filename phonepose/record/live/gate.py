"""The listening socket's gate: bounded connections, a request within a deadline, room for the token.

The recorder listens on 0.0.0.0 for one phone (and one headset); anyone on the network can open
connections, and aiohttp has no connection limit, so this protocol factory sits in front of
aiohttp's own (``AppRunner.server``). A connection is *trusted* once its first request line carries
the recording's token; until then it is *untrusted*, and:

- it must finish TLS and send a whole request head (up to the blank line) within ``deadline_s``,
  or it is closed (TLS is started here with that handshake deadline);
- one address holds at most ``per_address`` untrusted connections: a newer one is refused, so one
  host churning or trickling connections only ever takes its own slots;
- all untrusted connections together hold at most ``limit - reserved``: when full, or when every
  slot is taken, the oldest untrusted connection of the address holding the most is closed for
  the newcomer; the ``reserved`` slots are only ever taken by connections that showed the token.

aiohttp's request handler is made only once TLS is done; bytes are read only by TLS until then.
"""

from __future__ import annotations

import asyncio
import secrets
import ssl
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import cast
from urllib.parse import parse_qs, urlsplit

MAX_HEAD_BYTES = 1 << 16      # a request head longer than this is never "sent" (aiohttp refuses it anyway)


def request_token(line: bytes) -> str:
    """The ``token`` query parameter of an HTTP request line (``GET /ws?token=T HTTP/1.1``), "" if none."""
    parts = line.split(b" ")
    if len(parts) != 3:
        return ""
    try:
        query = urlsplit(parts[1].decode("ascii")).query
    except (UnicodeDecodeError, ValueError):
        return ""
    return parse_qs(query).get("token", [""])[0]


class ConnectionGate:
    """Protocol factory for ``loop.create_server``; ``handlers`` makes aiohttp's protocol."""

    def __init__(self, handlers: Callable[[], asyncio.BaseProtocol], ssl_context: ssl.SSLContext | None, *,
                 token: str, limit: int, reserved: int, per_address: int, deadline_s: float) -> None:
        self.handlers = handlers
        self.ssl_context = ssl_context
        self.token = token.encode()
        self.limit = limit
        self.reserved = reserved
        self.per_address = per_address
        self.deadline_s = deadline_s
        self.open = 0
        self.dropped = 0                  # untrusted connections closed: no request in time, or room made
        self.refused = 0                  # new connections refused (their address's share or every slot taken)
        self.untrusted: dict[str, OrderedDict[int, _Gated]] = {}   # per address, oldest first

    def __call__(self) -> asyncio.Protocol:
        return _Gated(self)

    @property
    def untrusted_count(self) -> int:
        return sum(len(q) for q in self.untrusted.values())

    def admit(self, conn: _Gated) -> bool:
        mine = self.untrusted.get(conn.address)
        if mine is not None and len(mine) >= self.per_address:
            self.refused += 1
            return False
        while self.open >= self.limit or self.untrusted_count >= self.limit - self.reserved:
            if not self._drop_one():
                self.refused += 1
                return False
        self.open += 1
        self.untrusted.setdefault(conn.address, OrderedDict())[id(conn)] = conn
        return True

    def _drop_one(self) -> bool:
        """Close the oldest untrusted connection of the address holding the most; False if there is none."""
        if not self.untrusted:
            return False
        address = max(self.untrusted, key=lambda a: (len(self.untrusted[a]),
                                                      -next(iter(self.untrusted[a].values())).opened))
        _, oldest = self.untrusted[address].popitem(last=False)
        if not self.untrusted[address]:
            del self.untrusted[address]
        self.dropped += 1
        oldest.close()   # its slot is free now, not only when asyncio reports the loss
        return True

    def trust(self, conn: _Gated) -> None:
        self._forget(conn)

    def matches(self, token: str) -> bool:
        return secrets.compare_digest(token.encode("utf-8", "replace"), self.token)

    def release(self, conn: _Gated) -> None:
        self._forget(conn)
        self.open -= 1

    def _forget(self, conn: _Gated) -> None:
        mine = self.untrusted.get(conn.address)
        if mine is not None:
            mine.pop(id(conn), None)
            if not mine:
                del self.untrusted[conn.address]


class _Gated(asyncio.Protocol):
    """One accepted connection: TLS first, then aiohttp's handler, which then sees every event."""

    def __init__(self, gate: ConnectionGate) -> None:
        self.gate = gate
        self.raw: asyncio.Transport | None = None
        self.handler: asyncio.Protocol | None = None
        self.counted = False
        self.address = "?"
        self.opened = time.monotonic()
        self.head = b""                     # the first request head so far (until its blank line)
        self.head_done = False
        self._early: list[bytes] = []       # decrypted bytes that came before the handler existed
        self._timer: asyncio.TimerHandle | None = None

    # ------------------------------------------------------------------ raw connection
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.raw = raw = cast(asyncio.Transport, transport)   # a TCP server's transports are Transports
        peer = raw.get_extra_info("peername")
        self.address = str(peer[0]) if isinstance(peer, tuple) and peer else "?"
        if not self.gate.admit(self):
            raw.abort()
            return
        self.counted = True
        loop = asyncio.get_running_loop()
        self._timer = loop.call_later(self.gate.deadline_s, self._no_request_in_time)
        if self.gate.ssl_context is None:
            self._attach(raw)
        else:
            raw.pause_reading()   # a ClientHello already here is for TLS (start_tls resumes), not for aiohttp
            asyncio.ensure_future(self._start_tls(raw))

    async def _start_tls(self, raw: asyncio.Transport) -> None:
        loop = asyncio.get_running_loop()
        assert self.gate.ssl_context is not None
        if raw.is_closing():
            # dropped before this task ran: a TLS start on it now would arm a handshake timer that
            # keeps the protocol and its 256 KiB buffer alive for the whole timeout
            self.connection_lost(None)
            return
        try:
            tls = await loop.start_tls(raw, self, self.gate.ssl_context, server_side=True,
                                       ssl_handshake_timeout=self.gate.deadline_s)
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

    def _no_request_in_time(self) -> None:
        if not self.head_done:
            self.gate.dropped += 1
            self.close()

    def _read_head(self, data: bytes) -> None:
        """Follow the first request head: its request line may carry the token (trusted from then on), its
        blank line ends the deadline."""
        before = self.head
        self.head = (before + data)[:MAX_HEAD_BYTES]
        if b"\r\n" in self.head and b"\r\n" not in before:
            if self.gate.matches(request_token(self.head.split(b"\r\n", 1)[0])):
                self.gate.trust(self)
        if b"\r\n\r\n" in self.head:
            self.head_done = True
            self.head = b""
            if self._timer is not None:
                self._timer.cancel()

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
        if not self.head_done:
            self._read_head(data)
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
