"""phonepose.waiting: the one polling loop behind the tests' wait_until and record rehearse's timeouts."""

from __future__ import annotations

import asyncio
import itertools

import pytest

from phonepose.errors import ConfigError
from phonepose.waiting import wait_until, wait_until_async


def test_returns_the_first_truthy_value():
    calls = itertools.count(1)
    assert wait_until(lambda: max(0, next(calls) - 3), what="the third call", timeout=60, interval=0) == 1


def test_runs_out_with_the_error_asked_for_and_names_what():
    with pytest.raises(AssertionError, match=r"^timed out after 0 s waiting for the page \(last value: ''\)$"):
        wait_until(lambda: "", what="the page", timeout=0)
    with pytest.raises(ConfigError, match=r"^rehearsal: timed out after 0 s waiting for the page$"):
        wait_until(lambda: None, what="the page", timeout=0, show_last=False,
                   error=lambda message: ConfigError(f"rehearsal: {message}"))


def test_async_polls_while_the_loop_runs():
    async def scenario() -> str:
        done: list[str] = []
        asyncio.get_running_loop().call_soon(done.append, "set by the loop")
        return await wait_until_async(lambda: done and done[0], what="the callback", timeout=60)

    assert asyncio.run(scenario()) == "set by the loop"
