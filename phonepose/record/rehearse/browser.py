"""The rehearsal's browser: headless Chromium (Playwright) with the real phone and headset pages, each
with an emulated WebXR device (IWER + driver.js), tapped as a user would.

Nothing here talks to the recorder's WebSocket: the pages do, with their own WebXR code. The Python
side only loads the pose tables into the page, tells it where sim time 0 is on its clock, and clicks.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from phonepose.errors import ConfigError
from phonepose.files import check_input
from phonepose.waiting import wait_until

DRIVER_JS = Path(__file__).with_name("driver.js")
IWER_IN_REPO = Path(__file__).resolve().parents[3] / "tests" / "js" / "node_modules" / "iwer" / "build" / "iwer.min.js"
# SwiftShader gives the pages a WebGL2 context for IWER's XRWebGLLayer (docs/notes/webxr_emulation.md)
CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
                 "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 # two pages play at once: neither may be throttled as a background page
                 "--disable-background-timer-throttling", "--disable-renderer-backgrounding",
                 "--disable-backgrounding-occluded-windows"]
CLOCK_PROBES = 25
# small pages: IWER clears its full-window canvas every XR frame, which SwiftShader does on the CPU (at 400x800
# device px x 2 and two pages, a loaded 2-core machine delivered 20 XR frames/s and 17 IMU samples/s)
VIEWPORT = {"width": 240, "height": 400}


def find_iwer(path: str | os.PathLike | None = None) -> Path:
    """iwer.min.js: the given file, else $PHONEPOSE_IWER, else the repository's tests/js/node_modules."""
    if path is not None:
        if not os.path.lexists(path):
            raise ConfigError(f"{{iwer}} {path}: no such file (expected IWER's build/iwer.min.js)", parameter="iwer",
                              value=path, expected="IWER's build/iwer.min.js")
        return check_input(path, "the file IWER's build/iwer.min.js")   # a FIFO or device: refused, never read
    for candidate in (os.environ.get("PHONEPOSE_IWER"), IWER_IN_REPO):
        if candidate and Path(candidate).is_file():
            return Path(candidate)
    raise ConfigError("IWER (the npm package iwer) is not installed: run `npm ci --prefix tests/js` in the "
                      "phonepose repository, or give {iwer} PATH/TO/iwer.min.js", parameter="iwer")


def find_chromium() -> str | None:
    """Debian's chromium when installed (tools/install-test-browser.sh), else None: Playwright's own build."""
    return shutil.which("chromium") or shutil.which("chromium-browser")


@dataclass
class PageClock:
    """The page's clock (performance.timeOrigin + now(), ms) against the recorder's, measured from Python."""

    offset_ns: int      # page - recorder
    rtt_ns: int         # the round trip of the best probe: the offset is good to half of it


class DevicePage:
    """One page (phone or headset) with its emulated device."""

    def __init__(self, page, name: str):
        self.page = page
        self.name = name
        self.clock: PageClock | None = None

    def evaluate(self, js: str, arg=None):
        return self.page.evaluate(js, arg)

    def measure_clock(self, now_ns: Callable[[], int], probes: int = CLOCK_PROBES) -> PageClock:
        """The page clock's offset from ``now_ns`` (the recorder's clock): of ``probes`` round trips the
        fastest wins (NTP's rule, as the recorder's own estimate: phonepose/record/live/clock.py)."""
        best: PageClock | None = None
        for _ in range(probes):
            t0 = now_ns()
            page_ms = self.page.evaluate("() => window.__rehearsal.nowMs()")
            t1 = now_ns()
            probe = PageClock(int(round(page_ms * 1e6)) - (t0 + t1) // 2, t1 - t0)
            if best is None or probe.rtt_ns < best.rtt_ns:
                best = probe
        assert best is not None
        self.clock = best
        return best

    def start(self, sim0_recorder_ns: int) -> None:
        """Sim time 0 is ``sim0_recorder_ns`` on the recorder's clock: tell the page where that is on its own."""
        assert self.clock is not None, "measure_clock() first"
        self.page.evaluate("t0 => window.__rehearsal.start(t0)", (sim0_recorder_ns + self.clock.offset_ns) / 1e6)

    def state(self) -> dict:
        return self.page.evaluate("() => { const s = window.__rehearsal.state; return {frames: s.frames, "
                                  "driven: s.driven, imu: s.imu, lastS: s.lastS}; }")


class RehearsalBrowser:
    """``with RehearsalBrowser(iwer) as b: phone = b.open(url, 'phone')``."""

    def __init__(self, iwer: Path, timeout_s: float):
        self.iwer = iwer
        self.timeout_s = timeout_s
        self._pw: Any = None          # playwright's objects (typed by its own stubs only when started)
        self._browser: Any = None

    def __enter__(self) -> RehearsalBrowser:
        from playwright.sync_api import sync_playwright

        self._pw = sync_playwright().start()
        try:
            self._browser = self._pw.chromium.launch(executable_path=find_chromium(), args=CHROMIUM_ARGS, headless=True,
                                                     timeout=self.timeout_s * 1000)
        except Exception as exc:   # noqa: BLE001 - no browser: one line (Playwright's own text)
            self._pw.stop()
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ConfigError(f"cannot start headless Chromium ({first[:160]}): run tools/install-test-browser.sh") from None
        return self

    def __exit__(self, *exc) -> None:
        try:
            if self._browser is not None:
                self._browser.close()
        finally:
            if self._pw is not None:
                self._pw.stop()

    def open(self, url: str, name: str) -> DevicePage:
        """A new context (its own storage, as a second device) with IWER and the driver injected, at ``url``."""
        assert self._browser is not None
        context = self._browser.new_context(viewport=VIEWPORT, device_scale_factor=1,
                                            ignore_https_errors=True)   # the recorder's self-signed certificate
        context.set_default_timeout(self.timeout_s * 1000)
        context.add_init_script(path=os.fspath(self.iwer))
        context.add_init_script(path=os.fspath(DRIVER_JS))
        page = context.new_page()
        response = page.goto(url)
        if response is None or response.status != 200:
            raise ConfigError(f"the {name} page {url.split('?')[0]} answered "
                              f"{'nothing' if response is None else f'HTTP {response.status}'}")
        return DevicePage(page, name)


def browser_failure(exc: Exception) -> ConfigError:
    """A Playwright error (a page that crashed, a click that timed out) as one line."""
    text = str(exc).strip()
    first = text.splitlines()[0] if text else type(exc).__name__
    return ConfigError(f"rehearsal: the browser failed: {first[:200]}")


def wait_for(condition: Callable[[], object], what: str, timeout_s: float) -> object:
    """Poll ``condition`` until it is truthy (:mod:`phonepose.waiting`); after ``timeout_s`` a ConfigError naming ``what``."""
    return wait_until(condition, what=what, timeout=timeout_s, show_last=False,
                      error=lambda message: ConfigError(f"rehearsal: {message}"))


def grip_offset(page: DevicePage, hand: str = "right"):
    """IWER's grip space in its controller's target-ray space (its controller model's gripOffsetMatrix)."""
    from phonepose.geometry import Pose

    m = np.asarray(page.evaluate("h => window.__rehearsal.gripOffset(h)", hand), dtype=float).reshape(4, 4).T   # column-major
    return Pose.from_matrix(m)
