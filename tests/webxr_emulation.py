"""Headless Chromium with an emulated WebXR device (IWER), for tests of the real pages.

IWER (the npm package ``iwer``, Meta's Immersive Web Emulation Runtime; tests/js/package.json, installed
by ``npm ci --prefix tests/js``) implements the WebXR Device API in JavaScript: a page's own WebXR code
runs against device and controller poses the test sets. Chromium defines ``navigator.xr`` itself, so
the runtime is installed with ``forceInstall`` (measured: /work/shared/docs/notes/webxr_emulation.md).
The device is ``window.__xrDevice`` in the page; set poses with :func:`set_pose`.
"""

from __future__ import annotations

from conftest import DEADLINE_S, require_browser

# the rehearsal's browser: the same Chromium, flags, IWER file and small viewport (IWER's canvas costs CPU per pixel)
from phonepose.record.rehearse.browser import CHROMIUM_ARGS, VIEWPORT, find_iwer

INSTALL = """(() => {{
  const device = new IWER.XRDevice(IWER.{device});
  device.installRuntime({{ forceInstall: true }});
  window.__xrDevice = device;
  window.__xrConfig = IWER.{device};
}})();"""


def launch(pw):
    """Headless Chromium with WebGL (SwiftShader: an XR session needs a WebGL base layer)."""
    return pw.chromium.launch(executable_path=require_browser(), headless=True, timeout=DEADLINE_S * 1000, args=CHROMIUM_ARGS)


def new_page(browser, *, device: str | None = "metaQuest3"):
    """A page of a new context (HTTPS errors ignored: the recorder's certificate is self-signed) with IWER's
    ``device`` (an IWER export: metaQuest3, metaQuest2, ...) installed before any script; None: no emulation."""
    ctx = browser.new_context(viewport=VIEWPORT, ignore_https_errors=True)
    ctx.set_default_timeout(DEADLINE_S * 1000)
    if device is not None:
        ctx.add_init_script(path=str(find_iwer()))
        ctx.add_init_script(script=INSTALL.format(device=device))
    return ctx.new_page()


def set_pose(page, body: str, p, q_xyzw) -> None:
    """Place ``body`` ("headset", "left", "right": a controller) at position ``p`` with orientation
    ``q_xyzw``, in WebXR's axes (IWER's global space; the page's local-floor space reads the same)."""
    page.evaluate("""([body, p, q]) => {
        const d = window.__xrDevice;
        const target = body === 'headset' ? d : d.controllers[body];
        target.position.set(p[0], p[1], p[2]);
        target.quaternion.set(q[0], q[1], q[2], q[3]);
    }""", [body, [float(v) for v in p], [float(v) for v in q_xyzw]])


def set_connected(page, hand: str, connected: bool) -> None:
    """Switch a controller on or off (its input source appears in / leaves the session)."""
    page.evaluate("([hand, on]) => { window.__xrDevice.controllers[hand].connected = on; }", [hand, connected])


def grip_offset(page, hand: str):
    """The controller model's grip space in its target-ray space (IWER's 4x4, column-major), as a row-major list."""
    m = page.evaluate("(hand) => Array.from(window.__xrConfig.controllerConfig.layout[hand].gripOffsetMatrix)", hand)
    return [[m[c * 4 + r] for c in range(4)] for r in range(4)]
