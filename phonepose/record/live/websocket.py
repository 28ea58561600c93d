"""A server-side WebSocket that other tasks can close with the full closing handshake (aiohttp).

Why this exists: aiohttp's ``WebSocketResponse.close()``, called from another task while the
handler waits in ``receive()``, sends the close frame and then closes the TCP connection at once,
without waiting for the peer's close frame (aiohttp issues #3448, #9506). A page that is still
sending (a pong, a sample) then gets a TCP reset, which can discard the close frame before the
browser has read it: the page sees code 1006 (abnormal) instead of the code sent. A phone page
told "1000: the recording finished / another page replaced you, do not reconnect" then reconnects,
and a replaced page takes the session back; on a loaded machine this happens often enough to matter.

So the close is done by the task that reads: :meth:`PageSocket.serve` reads in a child task; a
:meth:`PageSocket.close` from anywhere stops that reader (its pending read is cancelled; nothing
already received is lost, aiohttp keeps it in its queue) and then closes from ``serve`` with no
concurrent reader, where aiohttp waits (up to the response's ``timeout``) for the peer's close frame
before closing TCP: the browser has read our code by then.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

from aiohttp import WSMessage, web


class PageSocket:
    """``ws`` (already prepared) plus a close that any task may ask for."""

    def __init__(self, ws: web.WebSocketResponse) -> None:
        self.ws = ws
        loop = asyncio.get_running_loop()
        self._close_asked: asyncio.Future[tuple[int, bytes]] = loop.create_future()
        self._finished = asyncio.Event()

    @property
    def closed(self) -> bool:
        return self.ws.closed or self._close_asked.done()

    async def serve(self, handle: Callable[[WSMessage], bool]) -> None:
        """Call ``handle(msg)`` (synchronous) for each message until the peer closes, ``handle``
        returns False, or :meth:`close` is asked; in the last case close with its code here."""
        reader = asyncio.ensure_future(self._read(handle))
        try:
            waits: set[asyncio.Future[Any]] = {reader, self._close_asked}
            await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
        finally:
            if not reader.done():
                reader.cancel()
            await asyncio.gather(reader, return_exceptions=True)
            try:
                if self._close_asked.done() and not self.ws.closed:
                    code, message = self._close_asked.result()
                    await self.ws.close(code=code, message=message)
            finally:
                self._finished.set()

    async def _read(self, handle: Callable[[WSMessage], bool]) -> None:
        async for msg in self.ws:
            if not handle(msg):
                return

    def ask_close(self, code: int = 1000, message: bytes = b"") -> None:
        """Ask :meth:`serve` to close with ``code``/``message`` (the first request wins)."""
        if not self._close_asked.done():
            self._close_asked.set_result((code, message))

    async def close(self, code: int = 1000, message: bytes = b"") -> None:
        """:meth:`ask_close`, then wait until :meth:`serve` has closed (at most the response's
        ``timeout`` for the peer's close frame)."""
        self.ask_close(code, message)
        await self._finished.wait()
