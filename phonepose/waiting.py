"""Waiting for a condition under a deadline: the one polling loop of the tests and of ``record rehearse``.

On a loaded 2-core machine a browser page or a child process can take many times its usual time, so
nothing sleeps a fixed time and then checks: it polls the condition itself until a generous deadline,
and a condition that never comes fails with a message naming it. The tests raise ``AssertionError``
(tests/conftest.py); ``record rehearse`` raises the one-line :class:`~phonepose.errors.ConfigError`.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

POLL_S = 0.02


def timed_out(what: str, timeout: float, last: object, *, show_last: bool) -> str:
    """The message of a wait that ran out: what did not happen, after how long, and (for tests) the last value."""
    message = f"timed out after {timeout:g} s waiting for {what}"
    return f"{message} (last value: {last!r:.200})" if show_last else message


class _Deadline:
    """The clock of one wait: :meth:`check` raises ``error(message)`` once ``timeout`` s have passed."""

    def __init__(self, what: str, timeout: float, error: Callable[[str], Exception], show_last: bool):
        self.end = time.monotonic() + timeout
        self.what, self.timeout, self.error, self.show_last = what, timeout, error, show_last

    def check(self, last: object) -> None:
        if time.monotonic() >= self.end:
            raise self.error(timed_out(self.what, self.timeout, last, show_last=self.show_last))


def wait_until(condition: Callable[[], T], *, what: str, timeout: float, interval: float = POLL_S,
               error: Callable[[str], Exception] = AssertionError, show_last: bool = True) -> T:
    """Call ``condition()`` every ``interval`` s until it returns a truthy value, and return that value.

    After ``timeout`` s without one, raise ``error(message)``; ``what`` says in words what did not
    happen ("the page's hello", "the recording to start").
    """
    deadline = _Deadline(what, timeout, error, show_last)
    while not (value := condition()):
        deadline.check(value)
        time.sleep(interval)
    return value


async def wait_until_async(condition: Callable[[], T], *, what: str, timeout: float, interval: float = POLL_S,
                           error: Callable[[str], Exception] = AssertionError, show_last: bool = True) -> T:
    """:func:`wait_until` inside an asyncio script: polls with ``asyncio.sleep`` so the loop keeps running."""
    deadline = _Deadline(what, timeout, error, show_last)
    while not (value := condition()):
        deadline.check(value)
        await asyncio.sleep(interval)
    return value
