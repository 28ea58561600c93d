"""Shared test helpers.

Waiting: the suite runs on loaded 2-core machines (other work, CI neighbours), where a browser page
or a child process can take many times its usual time. A test never sleeps a fixed time and then
asserts: it waits for the condition itself with :func:`wait_until` (or :func:`wait_until_async` in
an asyncio script) under a deadline far beyond the normal time, so a slow machine only makes the
test slower, and a condition that never comes fails with a message naming it.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import signal
from collections.abc import Awaitable, Callable, Iterator
from pathlib import Path
from typing import NamedTuple, TypeVar

import pytest
from hypothesis import settings

from phonepose import waiting
from phonepose.waiting import POLL_S

T = TypeVar("T")

# hypothesis's per-example deadline measures the machine's load, not the code: no deadline
settings.register_profile("phonepose", deadline=None)
settings.load_profile("phonepose")

DEADLINE_S = 120.0   # normally well under a second; generous, because a timeout only costs time when broken


def wait_until(condition: Callable[[], T], *, what: str, timeout: float = DEADLINE_S, interval: float = POLL_S) -> T:
    """:func:`phonepose.waiting.wait_until` under the suite's deadline, failing with ``AssertionError``.

    After ``timeout`` s without a truthy value: ``AssertionError("timed out after … s waiting for <what> …")``.
    """
    return waiting.wait_until(condition, what=what, timeout=timeout, interval=interval)


async def wait_until_async(condition: Callable[[], T], *, what: str, timeout: float = DEADLINE_S,
                           interval: float = POLL_S) -> T:
    """:func:`wait_until` inside an asyncio script: polls with ``asyncio.sleep`` so the loop keeps running."""
    return await waiting.wait_until_async(condition, what=what, timeout=timeout, interval=interval)


async def within(awaitable: Awaitable[T], *, what: str, timeout: float = DEADLINE_S) -> T:
    """Await ``awaitable`` under the same generous deadline, failing with a message naming ``what``."""
    try:
        return await asyncio.wait_for(awaitable, timeout)
    except TimeoutError:
        raise AssertionError(waiting.timed_out(what, timeout, None, show_last=True)) from None


@functools.cache
def _browser_missing() -> str | None:
    """Why no headless Chromium can be started here, or None: Debian's (tools/install-test-browser.sh) or
    Playwright's own build, whichever exists."""
    from phonepose.record.rehearse.browser import find_chromium
    if find_chromium():
        return None
    from playwright.sync_api import sync_playwright
    with sync_playwright() as pw:
        if Path(pw.chromium.executable_path).is_file():
            return None
    return "no headless Chromium: tools/install-test-browser.sh could not install one (apt or Playwright)"


def require_browser() -> str | None:
    """The Chromium executable to launch (None: Playwright's own build), or skip the test with the reason:
    the test command runs every other test when no browser could be installed."""
    reason = _browser_missing()
    if reason:
        pytest.skip(reason)
    from phonepose.record.rehearse.browser import find_chromium
    return find_chromium()


@contextlib.contextmanager
def deadline(seconds: int) -> Iterator[None]:
    """A call that blocks (a FIFO opened by mistake) fails the test with TimeoutError instead of hanging it
    (SIGALRM: POSIX only, as the FIFO cases are)."""
    def expired(signum, frame):
        raise TimeoutError(f"no answer within {seconds} s")
    old = signal.signal(signal.SIGALRM, expired)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def pytest_collection_modifyitems(config, items) -> None:
    """The tests marked ``long`` first, the rest in their order: pytest-xdist hands tests to its workers in
    collection order, so a long test collected near the end runs alone while the other worker idles. Not the
    browser rehearsal: it streams in real time, and started first beside exp2's worker processes its page falls
    behind and misses its goals."""
    items.sort(key=lambda item: item.get_closest_marker("long") is None)


@pytest.fixture
def short_exp1(monkeypatch) -> list[tuple[float, float, float]]:
    """``experiment exp1`` with 4 of its 16 targets: one inside and one outside the view at each depth (a ~27 s
    session instead of 112 s), for tests of what exp1 does with its session, not of its numbers (CI checks those
    on the whole session: ``tools/docs_results.py check --run``). In-process runs only."""
    from phonepose.record.sim import scenarios
    targets = [scenarios._exp1_targets_cam()[i] for i in (0, 4, 8, 12)]
    monkeypatch.setattr(scenarios, "_exp1_targets_cam", lambda: list(targets))
    return targets


class CliResult(NamedTuple):      # as subprocess.CompletedProcess names them; unpacks as (code, out, err)
    returncode: int
    stdout: str
    stderr: str


@pytest.fixture
def cli(capsys, monkeypatch) -> Callable[..., CliResult]:
    """``phonepose ARGS`` run in this process, through the console script's own entry point
    (``phonepose.cli.main``: the same one-line errors and exit codes), with ``env`` set for the call.

    A spawned interpreter spends most of a second importing numpy, scipy and the CLI before the command starts,
    and most tests only check what a command prints or refuses. The tests that need
    a real process (signals, a killed command, logging's warnings, the entry point's own wiring:
    test_evaluation's ``test_cli_error_in_a_real_process``) still spawn one."""
    from phonepose.cli import main

    def run(*args, env: dict[str, str] | None = None) -> CliResult:
        for key, value in (env or {}).items():
            monkeypatch.setenv(key, value)
        capsys.readouterr()
        try:
            main([str(a) for a in args])
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        out = capsys.readouterr()
        return CliResult(code, out.out, out.err)

    return run
