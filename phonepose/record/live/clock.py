"""The recorder's clock and the per-connection estimate of the phone page's clock offset.

The recorder clock is wall time read once at start and advanced by the monotonic clock: it
never jumps (NTP slews, manual changes) during a recording, and its values look like Unix
nanoseconds. Every live stream is stamped on it: camera frames by their capture time,
phone samples by ``t - offset``.

The offset estimate is NTP's clock filter reduced to what a LAN WebSocket needs (written here:
no library estimates an offset from our own ping/pong messages): the server sends
``{"type": "ping", "id", "server_ns"}``, the page answers at once with its clock ``t`` (ms); for
that exchange ``rtt = receive - send`` and ``offset = t - (send + receive) / 2`` (exact if the two
one-way delays are equal, else off by half their difference, at most rtt / 2). Of the last
:data:`WINDOW` exchanges the one with the smallest rtt wins: it has the least room for asymmetric
queueing delay, which is what NTP's filter does too.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

WINDOW = 16                      # exchanges kept (one ping a second: the last ~16 s)
MAX_RTT_NS = 2_000_000_000       # an exchange slower than this says nothing useful
PENDING_PING_TTL_NS = 10_000_000_000


class RecorderClock:
    """Unix-like nanoseconds that advance with the monotonic clock (never jump)."""

    def __init__(self) -> None:
        self._wall0 = time.time_ns()
        self._mono0 = time.monotonic_ns()

    def now_ns(self) -> int:
        return self._wall0 + (time.monotonic_ns() - self._mono0)

    def from_monotonic_ns(self, mono_ns: int) -> int:
        """A ``time.monotonic_ns()`` reading (e.g. a V4L2 buffer stamp) on this clock."""
        return self._wall0 + (int(mono_ns) - self._mono0)


@dataclass(frozen=True)
class Exchange:
    rtt_ns: int
    offset_ns: int        # client clock - recorder clock
    received_ns: int


class OffsetEstimator:
    """NTP-style offset of one connection's page clock (``t`` in ms) from the recorder clock."""

    def __init__(self, window: int = WINDOW) -> None:
        self._next_id = 1
        self._sent: dict[int, int] = {}
        self.exchanges: deque[Exchange] = deque(maxlen=window)
        self.rejected = 0

    def ping(self, now_ns: int) -> dict:
        """The next ping message (remembers when it was sent)."""
        pid = self._next_id
        self._next_id += 1
        self._sent[pid] = now_ns
        for old in [k for k, sent in self._sent.items() if now_ns - sent > PENDING_PING_TTL_NS]:
            del self._sent[old]
        return {"type": "ping", "id": pid, "server_ns": now_ns}

    def pong(self, pid: int, t_client_ms: float, received_ns: int) -> Exchange | None:
        """Account one pong; None (and counted as rejected) if it answers no ping of ours or is too slow.

        The send time is our own record of the ping, never the echoed ``server_ns``.
        """
        sent = self._sent.pop(pid, None)
        if sent is None:
            self.rejected += 1
            return None
        rtt = received_ns - sent
        if rtt < 0 or rtt > MAX_RTT_NS:
            self.rejected += 1
            return None
        ex = Exchange(rtt, int(round(t_client_ms * 1e6)) - (sent + received_ns) // 2, received_ns)
        self.exchanges.append(ex)
        return ex

    def best(self) -> Exchange | None:
        if not self.exchanges:
            return None
        return min(self.exchanges, key=lambda e: e.rtt_ns)

    @property
    def offset_ns(self) -> int | None:
        b = self.best()
        return None if b is None else b.offset_ns

    def to_recorder_ns(self, t_client_ms: float) -> int | None:
        """A page time (ms) on the recorder clock, or None before the first exchange."""
        off = self.offset_ns
        return None if off is None else int(round(t_client_ms * 1e6)) - off
