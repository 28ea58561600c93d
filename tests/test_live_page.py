"""The phone page of `phonepose record live` (phonepose/record/live/static/) in headless Chromium.

A small aiohttp server started here plays the laptop's side of the protocol in docs/phone-page.md
(page, /marker.png, /config, /ws with pings), on plain http://127.0.0.1, which Chromium treats as a
secure context like https, so DeviceMotion and navigator.xr behave as on the phone. Chromium
(Debian's, installed by tools/install-test-browser.sh, else Playwright's build) is driven with playwright. Headless
Chromium has no AR device, so the page must report WebXR as unavailable and
stream IMU only; the WebXR path itself needs a real ARCore phone and is not covered here.
"""

from __future__ import annotations

import asyncio
import importlib.resources
import json
import math
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from aiohttp import WSMsgType, web
from conftest import DEADLINE_S, require_browser, wait_until
from playwright.sync_api import sync_playwright

from phonepose.record.live.websocket import PageSocket

CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
TOKEN = "s3cret-t0ken"
DICTIONARY = "DICT_4X4_50"
MARKER_ID = 7
DPR = 2  # device_scale_factor of the browser context: W * DPR is then exact in CSS layout units
PPI = 320.5  # with DPR 2 and a 400 CSS px wide viewport: a 63 mm wide screen, as on phones
NOT_AVAILABLE = "WebXR immersive-ar is not available in this browser"
STATIC = Path(str(importlib.resources.files("phonepose.record").joinpath("live", "static")))


def _marker_png() -> bytes:
    """The marker PNG with a white quiet zone, as the real server serves it."""
    try:
        from phonepose.calibration.marker_image import marker_png  # written for issue 10

        return marker_png(DICTIONARY, MARKER_ID)
    except (ImportError, TypeError):
        dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
        img = cv2.aruco.generateImageMarker(dictionary, MARKER_ID, 240)
        img = cv2.copyMakeBorder(img, 40, 40, 40, 40, cv2.BORDER_CONSTANT, value=255)
        ok, buf = cv2.imencode(".png", img)
        assert ok
        return buf.tobytes()


class LaptopSide:
    """The server's half of the protocol, in a thread with its own event loop."""

    def __init__(self) -> None:
        self.messages: list[dict] = []  # every page->server message, in arrival order
        self.connections: list[list[dict]] = []  # the messages of each WebSocket, in the order they opened
        self.pings: dict[int, int] = {}  # id -> server_ns sent
        self.sockets: list[PageSocket] = []
        self.rejected_ws = 0
        self.loop = asyncio.new_event_loop()
        self.png = _marker_png()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    # -- handlers
    def _authorised(self, request: web.Request) -> bool:
        return request.query.get("token") == TOKEN

    async def _index(self, request: web.Request) -> web.StreamResponse:
        if not self._authorised(request):
            return web.Response(status=403, text="403: wrong token; open the URL printed by phonepose record live")
        return web.FileResponse(STATIC / "index.html")

    async def _marker(self, request: web.Request) -> web.Response:
        if not self._authorised(request):
            raise web.HTTPForbidden()
        return web.Response(body=self.png, content_type="image/png")

    async def _config(self, request: web.Request) -> web.Response:
        if not self._authorised(request):
            raise web.HTTPForbidden()
        return web.json_response({"marker": {"dictionary": DICTIONARY, "id": MARKER_ID}})

    async def _ws(self, request: web.Request) -> web.StreamResponse:
        if not self._authorised(request):
            self.rejected_ws += 1
            raise web.HTTPForbidden()
        ws = web.WebSocketResponse()
        await ws.prepare(request)
        # closed by close_all() from another task with the closing handshake, as the real server does
        # (phonepose/record/live/websocket.py says why a plain ws.close() can reach the page as 1006)
        sock = PageSocket(ws)
        self.sockets.append(sock)
        mine: list[dict] = []
        self.connections.append(mine)

        def handle(msg) -> bool:
            if msg.type == WSMsgType.TEXT:
                self.messages.append(json.loads(msg.data))
                mine.append(self.messages[-1])
            return True

        pinger = asyncio.ensure_future(self._ping(sock))
        try:
            await sock.serve(handle)
        finally:
            pinger.cancel()
            await asyncio.gather(pinger, return_exceptions=True)
        return ws

    async def _ping(self, sock: PageSocket) -> None:
        while not sock.closed:
            ping_id = len(self.pings) + 1
            server_ns = time.time_ns()  # > 2**53: the page must echo it digit for digit
            self.pings[ping_id] = server_ns
            try:
                await sock.ws.send_str(json.dumps({"type": "ping", "id": ping_id, "server_ns": server_ns}))
            except ConnectionError:   # closing: the page is going away
                return
            await asyncio.sleep(0.1)

    # -- life cycle
    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        app = web.Application()
        app.router.add_get("/", self._index)
        app.router.add_get("/marker.png", self._marker)
        app.router.add_get("/config", self._config)
        app.router.add_get("/ws", self._ws)
        app.router.add_static("/static/", STATIC)
        self.runner = web.AppRunner(app)
        self.loop.run_until_complete(self.runner.setup())
        site = web.TCPSite(self.runner, "127.0.0.1", 0)
        self.loop.run_until_complete(site.start())
        self.port = site._server.sockets[0].getsockname()[1]
        self._ready.set()
        self.loop.run_forever()

    def start(self) -> LaptopSide:
        self._thread.start()
        assert self._ready.wait(DEADLINE_S)
        return self

    def stop(self) -> None:
        asyncio.run_coroutine_threadsafe(self.runner.cleanup(), self.loop).result(DEADLINE_S)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(DEADLINE_S)

    def send_all(self, obj: dict) -> None:
        async def go() -> None:
            for sock in self.sockets:
                if not sock.closed:
                    await sock.ws.send_str(json.dumps(obj))

        asyncio.run_coroutine_threadsafe(go(), self.loop).result(DEADLINE_S)

    def close_all(self, code: int, message: bytes = b"") -> None:
        async def go() -> None:
            for sock in self.sockets:
                if not sock.closed:
                    await sock.close(code=code, message=message)

        asyncio.run_coroutine_threadsafe(go(), self.loop).result(DEADLINE_S)

    def of_type(self, kind: str) -> list[dict]:
        return [m for m in list(self.messages) if m.get("type") == kind]

    def connection(self, index: int, *kinds: str) -> list[dict]:
        """The messages of the ``index``-th WebSocket (0 = the first of this server) once its first
        messages are of ``kinds`` in that order (the protocol: ``hello``, then ``marker``)."""
        def opened():
            if len(self.connections) <= index:
                return None
            msgs = self.connections[index]
            return msgs if len(msgs) >= len(kinds) else None

        msgs = wait_until(opened, what=f"connection {index + 1} and its first messages {', '.join(kinds)}")
        assert [m["type"] for m in msgs[: len(kinds)]] == list(kinds), msgs[: len(kinds)]
        return msgs


@pytest.fixture(scope="module")
def server():
    s = LaptopSide().start()
    yield s
    s.stop()


@pytest.fixture(scope="module")
def browser():
    chromium = require_browser()
    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS, headless=True, timeout=DEADLINE_S * 1000)
        yield b
        b.close()


def new_context(browser):
    """A phone-sized context whose every navigation and wait has the suite's generous deadline."""
    context = browser.new_context(viewport={"width": 400, "height": 800}, device_scale_factor=DPR)
    context.set_default_timeout(DEADLINE_S * 1000)
    return context


@pytest.fixture
def page(browser):
    context = new_context(browser)
    p = context.new_page()
    yield p
    context.close()


def rect(page, selector: str) -> dict:
    js = "e => { const r = e.getBoundingClientRect(); return {x: r.x, y: r.y, w: r.width, h: r.height}; }"
    return page.eval_on_selector(selector, js)


def test_page_shows_marker_and_streams(server, page):
    base = f"http://127.0.0.1:{server.port}"
    n = len(server.connections)
    response = page.goto(f"{base}/?token={TOKEN}&ppi={PPI}")
    assert response is not None and response.status == 200
    page.wait_for_selector("body[data-ready=true]")

    # hello (the first message on the connection): WebXR unavailable, with the same clear message in the DOM
    conn = server.connection(n, "hello")
    hello = conn[0]
    assert hello["webxr"] is False
    assert hello["message"].startswith(NOT_AVAILABLE)
    assert "ARCore" in hello["message"] and "IMU only" in hello["message"]
    assert "Chrome" in hello["user_agent"]
    assert page.is_visible("#xr-message")
    assert page.inner_text("#xr-message") == hello["message"]
    assert page.is_disabled("#btn-ar")

    # marker message: size of the black square from its CSS width W, dpr and the URL's ppi
    marker = server.connection(n, "hello", "marker")[1]
    canvas = rect(page, "#marker")
    w_css = canvas["w"]
    assert marker["dictionary"] == DICTIONARY and marker["id"] == MARKER_ID
    assert marker["ppi"] == PPI and marker["device_pixel_ratio"] == DPR
    assert marker["size_m"] == pytest.approx(w_css * DPR / PPI * 0.0254, rel=1e-9)
    # as large as the 400 px wide screen allows with a one-cell quiet zone: 6 of 8 cells across
    assert 400 * DPR * 6 / 8 - 8 <= w_css * DPR <= 400 * DPR * 6 / 8

    # ruler: 50 mm at that ppi
    page.click("#btn-settings")
    assert page.is_visible("#ruler")
    assert rect(page, "#ruler")["w"] == pytest.approx(50 / 25.4 * PPI / DPR, abs=0.02)

    # nothing over the marker: it lies inside the white marker area, apart from the controls
    area, controls = rect(page, "#marker-area"), rect(page, "#controls")
    assert area["x"] <= canvas["x"] and canvas["x"] + canvas["w"] <= area["x"] + area["w"]
    assert area["y"] <= canvas["y"] and canvas["y"] + canvas["h"] <= area["y"] + area["h"]
    assert controls["y"] >= canvas["y"] + canvas["h"]

    # the screenshot shows marker 7 of DICT_4X4_50, W * dpr device pixels wide
    shot = cv2.imdecode(np.frombuffer(page.screenshot(), np.uint8), cv2.IMREAD_GRAYSCALE)
    assert shot.shape == (800 * DPR, 400 * DPR)
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    corners, ids, _ = detector.detectMarkers(shot)
    assert ids is not None and MARKER_ID in ids.ravel().tolist()
    c = corners[ids.ravel().tolist().index(MARKER_ID)].reshape(4, 2)
    sides = np.linalg.norm(c - np.roll(c, 1, axis=0), axis=1)
    assert sides == pytest.approx([w_css * DPR] * 4, abs=2.0)
    assert c[:, 0].min() == pytest.approx(canvas["x"] * DPR, abs=1.5)

    # synthetic DeviceMotion events -> imu messages in rad/s, m/s^2, increasing t
    samples = [
        {"alpha": 10.0, "beta": -20.5, "gamma": 0.1, "x": 0.25, "y": 9.80665, "z": -0.3},
        {"alpha": -359.9, "beta": 45.0, "gamma": 1e-3, "x": -1.5, "y": 9.7, "z": 0.0},
        {"alpha": 0.0, "beta": 180.0, "gamma": -90.0, "x": 3.0, "y": -9.81, "z": 2.5},
        {"alpha": 33.3, "beta": 66.6, "gamma": 99.9, "x": 0.1, "y": 0.2, "z": 0.3},
    ]
    wall_ms = time.time() * 1000
    page.evaluate(
        """async (samples) => {
            for (const s of samples) {
                window.dispatchEvent(new DeviceMotionEvent('devicemotion', {
                    rotationRate: {alpha: s.alpha, beta: s.beta, gamma: s.gamma},
                    accelerationIncludingGravity: {x: s.x, y: s.y, z: s.z},
                    interval: 16,
                }));
                await new Promise((r) => setTimeout(r, 5));
            }
        }""",
        samples,
    )
    imu = wait_until(lambda: len(server.of_type("imu")) >= len(samples) and server.of_type("imu"),
                     what=f"{len(samples)} imu messages")
    assert len(imu) == len(samples)
    for m, s in zip(imu, samples, strict=True):
        assert set(m) == {"type", "t", "gyro", "accel"}
        assert m["gyro"] == [math.radians(s["beta"]), math.radians(s["gamma"]), math.radians(s["alpha"])]
        assert m["accel"] == [s["x"], s["y"], s["z"]]
    ts = [m["t"] for m in imu]
    assert all(b > a for a, b in zip(ts, ts[1:], strict=False))
    # epoch ms (performance.timeOrigin + the event's timeStamp): between dispatching and receiving
    assert wall_ms - 1000 < ts[0] < ts[-1] < time.time() * 1000 + 1000

    # pings are answered with their id and server_ns, digit for digit
    pongs = wait_until(lambda: len(server.of_type("pong")) >= 3 and server.of_type("pong"), what="3 pongs")
    for pong in pongs:
        assert set(pong) == {"type", "id", "server_ns", "t"}
        assert server.pings[pong["id"]] == pong["server_ns"] > 2**53
        assert pong["server_ns"] / 1e6 - 1000 < pong["t"] < time.time() * 1000 + 1000   # answered after the ping
    assert [p["id"] for p in pongs] == sorted(p["id"] for p in pongs)

    # status and error messages from the server are shown
    server.send_all({"type": "status", "recording": True, "anchor": False, "marker_seen": True})
    page.wait_for_function("document.getElementById('server-status').textContent.includes('recording: yes')")
    assert "marker seen: yes" in page.inner_text("#server-status")
    assert "anchor: not set" in page.inner_text("#server-status")
    server.send_all({"type": "error", "message": "camera 0 lost: recording stopped"})
    page.wait_for_selector("#error:not([hidden])")
    assert page.inner_text("#error") == "camera 0 lost: recording stopped"

    # correcting the ppi on the page: a new marker message, the ruler follows, the value is remembered
    page.fill("#ppi", "350")
    marker2 = wait_until(lambda: [m for m in server.of_type("marker") if m["ppi"] == 350], what="a marker at 350 ppi")[-1]
    w_css = rect(page, "#marker")["w"]
    assert marker2["size_m"] == pytest.approx(w_css * DPR / 350 * 0.0254, rel=1e-9)
    assert rect(page, "#ruler")["w"] == pytest.approx(50 / 25.4 * 350 / DPR, abs=0.02)
    assert page.evaluate("localStorage.getItem('phonepose.ppi')") == "350"

    # without ?ppi= the remembered value is used; hiding the controls enlarges nothing over the marker
    page.goto(f"{base}/?token={TOKEN}")
    page.wait_for_selector("body[data-ready=true]")
    assert page.input_value("#ppi") == "350"
    assert page.is_hidden("#ppi-warning")


def test_default_ppi_is_flagged(server, browser):
    context = new_context(browser)
    page = context.new_page()
    try:
        page.goto(f"http://127.0.0.1:{server.port}/?token={TOKEN}")
        page.wait_for_selector("body[data-ready=true]")
        assert page.is_visible("#ppi-warning")
        assert "enter your screen's ppi" in page.inner_text("#ppi-warning").lower()
        assert page.is_visible("#ruler")
        assert "50 mm" in page.inner_text("#ruler-box")
    finally:
        context.close()


def test_wrong_token_shows_error(server, page):
    base = f"http://127.0.0.1:{server.port}"
    response = page.goto(f"{base}/?token=wrong")
    assert response is not None and response.status == 403
    assert "token" in page.inner_text("body")

    # The page itself (its assets are public) reports the refused token and does not connect.
    n = len(server.connections)
    page.goto(f"{base}/static/index.html?token=wrong&ppi={PPI}")
    page.wait_for_selector("body[data-ready=true]")
    assert page.is_visible("#error")
    text = page.inner_text("#error")
    assert "403" in text and "token" in text
    assert page.eval_on_selector("#marker", "e => e.dataset.sizeM") is None
    # the page opens its WebSocket (if ever) before it sets data-ready: none was made, so none can arrive
    assert page.evaluate("window.phonepose.link.accessDenied && window.phonepose.link.ws === null") is True
    assert len(server.connections) == n and server.rejected_ws == 0


def test_marker_png_with_wide_border_and_no_quiet_zone(server, page):
    """The page finds the black square and its cell grid in whatever PNG the server serves."""
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    ok, buf = cv2.imencode(".png", cv2.aruco.generateImageMarker(d, MARKER_ID, 330, borderBits=2))
    assert ok
    original, server.png = server.png, buf.tobytes()
    try:
        page.goto(f"http://127.0.0.1:{server.port}/?token={TOKEN}&ppi={PPI}")
        page.wait_for_selector("body[data-ready=true]")
        page.wait_for_function("document.getElementById('marker').dataset.sizeM !== undefined")
        assert page.eval_on_selector("#marker", "e => e.dataset.cells") == "8"  # 4 bits + 2 x 2 border cells
        w_css = rect(page, "#marker")["w"]
        assert int(page.eval_on_selector("#marker", "e => e.dataset.devicePx")) == w_css * DPR
        assert (w_css * DPR) % 8 == 0
        params = cv2.aruco.DetectorParameters()
        params.markerBorderBits = 2
        shot = cv2.imdecode(np.frombuffer(page.screenshot(), np.uint8), cv2.IMREAD_GRAYSCALE)
        corners, ids, _ = cv2.aruco.ArucoDetector(d, params).detectMarkers(shot)
        assert ids is not None and ids.ravel().tolist() == [MARKER_ID]
        c = corners[0].reshape(4, 2)
        assert np.linalg.norm(c - np.roll(c, 1, axis=0), axis=1) == pytest.approx([w_css * DPR] * 4, abs=2.0)
    finally:
        server.png = original


def test_reconnects_unless_closed_normally(server, page):
    """What docs/phone-page.md guarantees: every connection starts with hello then marker; a broken
    connection is retried (one new connection), a normal close (code 1000) is not."""
    n = len(server.connections)
    page.goto(f"http://127.0.0.1:{server.port}/?token={TOKEN}&ppi={PPI}")
    page.wait_for_selector("body[data-ready=true]")
    server.connection(n, "hello", "marker")

    # a broken connection (here: close code 4000) is retried; hello and marker are sent again
    server.close_all(4000)
    server.connection(n + 1, "hello", "marker")

    # a normal close (recording finished, or another page replaced this one) is not fought back
    server.close_all(1000, b"recording finished")
    page.wait_for_function("document.getElementById('conn').textContent === 'closed by the laptop'")
    assert page.is_visible("#error")
    assert "recording finished" in page.inner_text("#error") and "Reload" in page.inner_text("#error")
    # No reconnection follows. An absence has no moment to wait for: a retry would be a page timer of
    # 0.5 s (the delay after a good connection), so let a 2 s page timer run out behind it, then look.
    page.evaluate("() => new Promise((resolve) => setTimeout(resolve, 2000))")
    assert page.inner_text("#conn") == "closed by the laptop"
    assert len(server.connections) == n + 2
