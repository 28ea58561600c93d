"""Shared test helpers.

Waiting: the suite runs on loaded 2-core machines (other work, CI neighbours), where a browser page
or a child process can take many times its usual time. A test never sleeps a fixed time and then
asserts: it waits for the condition itself with :func:`wait_until` (or :func:`wait_until_async` in
an asyncio script) under a deadline far beyond the normal time, so a slow machine only makes the
test slower, and a condition that never comes fails with a message naming it.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from typing import TypeVar

T = TypeVar("T")

DEADLINE_S = 120.0   # normally well under a second; generous, because a timeout only costs time when broken
POLL_S = 0.02


def _timed_out(what: str, timeout: float, last: object) -> AssertionError:
    return AssertionError(f"timed out after {timeout:g} s waiting for {what} (last value: {last!r:.200})")


def wait_until(condition: Callable[[], T], *, what: str, timeout: float = DEADLINE_S, interval: float = POLL_S) -> T:
    """Call ``condition()`` every ``interval`` s until it returns a truthy value, and return that value.

    After ``timeout`` s without one: ``AssertionError("timed out after … s waiting for <what> …")``.
    ``what`` says in words what did not happen ("the page's hello", "the recording to start").
    """
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() >= deadline:
            raise _timed_out(what, timeout, value)
        time.sleep(interval)


async def wait_until_async(condition: Callable[[], T], *, what: str, timeout: float = DEADLINE_S,
                           interval: float = POLL_S) -> T:
    """:func:`wait_until` inside an asyncio script: polls with ``asyncio.sleep`` so the loop keeps running."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() >= deadline:
            raise _timed_out(what, timeout, value)
        await asyncio.sleep(interval)


async def within(awaitable: Awaitable[T], *, what: str, timeout: float = DEADLINE_S) -> T:
    """Await ``awaitable`` under the same generous deadline, failing with a message naming ``what``."""
    try:
        return await asyncio.wait_for(awaitable, timeout)
    except TimeoutError:
        raise _timed_out(what, timeout, None) from None
