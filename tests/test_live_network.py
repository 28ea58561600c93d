"""``record live`` on a real network (issue 20), against the real server: clock pings answered late
or never, a malformed first sample, oversized and invalid-UTF-8 messages, idle connections.

Wi-Fi power saving delays packets by 100-1000 ms, so the recorder must keep every well-formed
sample whatever happens to the clock pings: samples wait until an offset exists, then are stamped.
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
import ssl
import statistics

import aiohttp
import numpy as np
import pytest
import test_record_live
from conftest import DEADLINE_S, wait_until, wait_until_async
from test_record_live import STAMP_ROUNDING_NS, Phone, _finish, _messages, _start, _wait_video_start

from phonepose.record.live.recording import SIZE_MISMATCH, LiveRecording
from phonepose.schemas.topics import Topic

media = test_record_live.media              # the same fixtures: a video of the marker and its calibration
long_media = test_record_live.long_media


class SlowPhone(Phone):
    """A scripted phone whose pongs leave ``pong_delay_s`` after the ping arrived (None: never)."""

    def __init__(self, *args, pong_delay_s: float | None):
        super().__init__(*args)
        self.pong_delay_s = pong_delay_s

    async def answer_ping(self, ws, ping: dict) -> None:
        """No pong at all (``pong_delay_s`` None), or the page's pong after the delay (a late ping delivery),
        while the reader goes on."""
        if self.pong_delay_s is not None:
            asyncio.ensure_future(self._late_pong(ws, ping))

    async def _late_pong(self, ws, ping: dict) -> None:
        await asyncio.sleep(self.pong_delay_s)
        await super().answer_ping(ws, ping)


async def _imu(phone: Phone, ws, n: int, *, first_t_ms: float | None = None) -> None:
    for i in range(n):
        now = phone.clock.now_ns()
        t_ms = phone.phone_ms(now) if (i or first_t_ms is None) else first_t_ms
        await ws.send_str(json.dumps({"type": "imu", "t": t_ms, "gyro": [0.01, 0.02, 0.03], "accel": [0.1, 9.8, 0.2]}))
        phone.sent.append(("imu", t_ms, now))
        await asyncio.sleep(0.01)


def _record(long_media, tmp_path, pong_delay_s, n, *, first_t_ms=None, wait_for=None):
    s, out, th, lines = _start(long_media, tmp_path)
    phone = SlowPhone(s, s.port, s.token, pong_delay_s=pong_delay_s)
    _wait_video_start(s)

    async def script():
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as http:
            ws, reader = await phone.connect(http)
            await _imu(phone, ws, n, first_t_ms=first_t_ms)
            if wait_for is not None:
                await wait_until_async(lambda: wait_for(s), what="the recorder to take the samples")
            await ws.close()
            reader.cancel()

    asyncio.run(script())
    s.stop("test done")
    _finish(th)
    msgs = _messages(tmp_path / "s.mcap")
    return phone, msgs, lines, s


def _waiting_samples(n: int, kept: list):
    """A ``wait_for`` of :func:`_record`: true once the phone's connection holds ``n`` samples waiting for a pong;
    keeps their (t ms, receipt ns) in ``kept``: what a fallback offset is taken from."""
    def waiting(s) -> bool:
        conn = s.source.server.current.get("phone")
        pending = list(conn.pending) if conn is not None else []
        kept[:] = [(m["t"], receipt) for m, receipt in pending]
        return len(pending) >= n
    return waiting


def _zero_delay_stamps(kept: list) -> np.ndarray:
    """Samples stamped assuming zero network delay: t minus the median over the waiting samples of t - receipt."""
    offset = int(statistics.median(int(round(t * 1e6)) - receipt for t, receipt in kept))
    return np.array([int(round(t * 1e6)) - offset for t, _ in kept])


def test_pongs_1_5_s_late_lose_no_sample(long_media, tmp_path):
    n = 200
    phone, msgs, lines, s = _record(long_media, tmp_path, 1.5, n,
                                    wait_for=lambda s: s.source.recording.stats["imu"] >= n)
    imu = [m for m in msgs if m.topic == Topic.CONTROLLER_IMU]
    assert len(imu) == n
    offsets = [m.msg.message for m in msgs if m.topic == Topic.LOG and "page clock offset" in m.msg.message]
    rtt_ms = float(offsets[0].split("best round trip ")[1].split(" ms")[0])
    assert rtt_ms >= 1500
    # stamped with the first offset there was: off by at most half its round trip (NTP's bound)
    stamps = np.array([m.msg.timestamp.ToNanoseconds() for m in imu])
    true = np.array([true for kind, _, true in phone.sent if kind == "imu"])
    assert np.max(np.abs(stamps - true)) <= (rtt_ms / 2 + 20) * 1e6
    assert any("samples wait for one, none is dropped" in line for line in lines)


def test_no_pong_at_all_loses_no_sample(long_media, tmp_path):
    n = 100
    kept: list = []
    phone, msgs, lines, s = _record(long_media, tmp_path, None, n, wait_for=_waiting_samples(n, kept))
    imu = [m for m in msgs if m.topic == Topic.CONTROLLER_IMU]
    assert len(imu) == n
    stamps = np.array([m.msg.timestamp.ToNanoseconds() for m in imu])
    true = np.array([true for kind, _, true in phone.sent if kind == "imu"])
    # zero network delay assumed, median over the samples: every stamp late by the median delivery delay as it
    # was (receipt - true capture; loopback's is ~1 ms on a quiet machine, much more on a loaded one)
    assert [t for t, _ in kept] == [t for kind, t, _ in phone.sent if kind == "imu"]
    delays = np.array([receipt for _, receipt in kept]) - true
    assert np.all(delays > 0)
    assert np.array_equal(stamps, _zero_delay_stamps(kept))
    assert np.max(np.abs(stamps - true - np.median(delays))) <= 2 * STAMP_ROUNDING_NS, (stamps - true, np.median(delays))
    assert any(f"no answer to the clock pings; {n} samples stamped assuming zero network delay" in line
               for line in lines)


def test_a_malformed_first_sample_never_becomes_the_offset(long_media, tmp_path):
    n = 60
    an_hour_ms = 3_600_000.0
    s, out, th, lines = _start(long_media, tmp_path)
    phone = SlowPhone(s, s.port, s.token, pong_delay_s=None)
    _wait_video_start(s)

    kept: list = []
    waiting = _waiting_samples(n, kept)

    async def script():
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as http:
            ws, reader = await phone.connect(http)
            await _imu(phone, ws, n, first_t_ms=phone.phone_ms(phone.clock.now_ns()) - an_hour_ms)
            await wait_until_async(lambda: waiting(s), what="the samples waiting for a pong")
            await ws.close()
            reader.cancel()

    asyncio.run(script())
    s.stop("test done")
    _finish(th)
    msgs = _messages(tmp_path / "s.mcap")
    imu = [m for m in msgs if m.topic == Topic.CONTROLLER_IMU]
    assert len(imu) == n - 1                         # every good sample; the one an hour off is not
    stamps = np.array([m.msg.timestamp.ToNanoseconds() for m in imu])
    true = np.array([true for kind, _, true in phone.sent[1:] if kind == "imu"])
    # the offset is the median over all n waiting samples, the one an hour off among them (a median: it moves
    # the offset by one rank, not an hour); each stamp late by about the delivery delay as it was
    assert [t for t, _ in kept] == [t for kind, t, _ in phone.sent if kind == "imu"]
    assert np.array_equal(stamps, _zero_delay_stamps(kept)[1:])
    delays = np.array([receipt for _, receipt in kept[1:]]) - true
    assert np.all(delays > 0)
    assert np.min(delays) - 2 * STAMP_ROUNDING_NS <= np.min(stamps - true) <= np.max(stamps - true) \
        <= np.max(delays) + 2 * STAMP_ROUNDING_NS, (stamps - true, delays)
    assert s.source.recording.malformed_kinds["imu 't' is not on the page's clock"] == 1


@pytest.mark.parametrize("phase", ["settled", "waiting for a pong", "no pong ever"])
def test_a_huge_finite_t_is_one_malformed_message_and_loses_no_good_sample(long_media, tmp_path, phase):
    """docs/reliability.md: nothing well-formed is dropped. A ``t`` of 1e305 ms is finite but no time the
    recorder's int64-ns clock can hold: one malformed message; the good sample before it and the 50 after it
    are all recorded, whether the offset is known, samples wait for a first pong, or no pong ever comes."""
    n_after = 50
    s, out, th, lines = _start(long_media, tmp_path)
    phone = SlowPhone(s, s.port, s.token, pong_delay_s={"settled": 0.0, "waiting for a pong": 1.5}.get(phase))
    _wait_video_start(s)

    def conn():
        return s.source.server.current.get("phone")

    async def script():
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as http:
            ws, reader = await phone.connect(http)
            if phase == "settled":
                await wait_until_async(lambda: conn() is not None and conn().settled, what="the clock offset")
            await _imu(phone, ws, 1)
            await ws.send_str(json.dumps({"type": "imu", "t": 1e305, "gyro": [0, 0, 0], "accel": [0, 0, 9.8]}))
            await ws.send_str(json.dumps({"type": "pose", "t": -1e305, "p": [0, 0, 0], "q": [0, 0, 0, 1]}))
            await _imu(phone, ws, n_after)
            if phase == "settled":
                await wait_until_async(lambda: s.source.recording.stats["imu"] >= 1 + n_after, what="the samples")
            else:   # all 51 wait for a pong (the bad ones never join them)
                await wait_until_async(lambda: not conn().settled and len(conn().pending) == 1 + n_after,
                                       what="the samples waiting for a pong")
                if phase == "waiting for a pong":
                    await wait_until_async(lambda: s.source.recording.stats["imu"] >= 1 + n_after,
                                           what="the samples stamped at the first pongs")
            await ws.close()
            reader.cancel()

    asyncio.run(script())
    s.stop("test done")
    _finish(th)
    rec = s.source.recording
    assert rec.malformed_kinds == {"imu 't' is out of range": 1, "pose 't' is out of range": 1}
    msgs = _messages(tmp_path / "s.mcap")
    imu = [m for m in msgs if m.topic == Topic.CONTROLLER_IMU]
    assert len(imu) == 1 + n_after
    assert not any(m.topic == Topic.CONTROLLER_VIO_POSE for m in msgs)
    logs = [m.msg.message for m in msgs if m.topic == Topic.LOG]
    assert sum("'t' is out of range" in line for line in lines) == 2   # each kind once
    assert sum("'t' is out of range" in t for t in logs) == 3          # and in the closing summary
    assert any("malformed messages ignored: 2 (" in t for t in logs)
    assert not any("could not be handled" in t for t in logs)


def test_a_sample_that_raises_while_waiting_costs_only_itself(long_media, tmp_path, monkeypatch):
    """A waiting sample whose handling raises (a recorder bug, not the page's fault) is counted and logged
    once; the samples waiting behind it are still stamped and written."""
    n = 40
    on_imu = LiveRecording.on_imu

    def fragile(self, capture_ns, receipt_ns, gyro, accel):
        if gyro[0] == 9.0:
            raise OverflowError("a bug")
        on_imu(self, capture_ns, receipt_ns, gyro, accel)

    monkeypatch.setattr(LiveRecording, "on_imu", fragile)
    s, out, th, lines = _start(long_media, tmp_path)
    phone = SlowPhone(s, s.port, s.token, pong_delay_s=None)
    _wait_video_start(s)

    async def script():
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as http:
            ws, reader = await phone.connect(http)
            await _imu(phone, ws, 1)
            for _ in range(3):
                await ws.send_str(json.dumps({"type": "imu", "t": phone.phone_ms(phone.clock.now_ns()),
                                              "gyro": [9.0, 0, 0], "accel": [0, 0, 9.8]}))
            await _imu(phone, ws, n)
            await wait_until_async(lambda: len(s.source.server.current["phone"].pending) == n + 4,
                                   what="the samples waiting for a pong")
            await ws.close()
            reader.cancel()

    asyncio.run(script())
    s.stop("test done")
    _finish(th)
    assert sum(m.topic == Topic.CONTROLLER_IMU for m in _messages(tmp_path / "s.mcap")) == 1 + n
    assert s.source.recording.malformed_kinds == {"could not be handled (OverflowError)": 3}
    assert sum("a message could not be handled (OverflowError: a bug)" in line for line in lines) == 1


EVIL = "\x1b]0;owned\x07\x1b[2J\rfake: anchor set\n\u202eevil"      # a title, a clear, a forged line, bidi
EVIL_SHOWN = "\\x1b]0;owned\\x07\\x1b[2J\\rfake: anchor set\\n\\u202eevil"


def test_page_text_reaches_the_terminal_escaped_and_cut(long_media, tmp_path):
    """docs/phone-page.md: every text a page sends (hello user agent and reason, marker dictionary,
    xrsession space and message) is printed with its control characters escaped, cut to 200 characters."""
    s, out, th, lines = _start(long_media, tmp_path)
    phone = Phone(s, s.port, s.token)
    _wait_video_start(s)

    async def script():
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as http:
            ws, reader = await phone.connect(http)
            await ws.send_str(json.dumps({"type": "hello", "user_agent": EVIL, "webxr": False, "message": EVIL}))
            await ws.send_str(json.dumps({"type": "marker", "dictionary": EVIL, "id": 3, "size_m": 0.05}))
            hs = await http.ws_connect(f"{phone.base}/ws?token={phone.token}&role=headset")
            await hs.send_str(json.dumps({"type": "hello", "user_agent": "A" * 300, "webxr": True, "message": ""}))
            await hs.send_str(json.dumps({"type": "xrsession", "state": "started", "space": EVIL, "message": EVIL}))
            await hs.send_str(json.dumps({"type": "xrsession", "state": "ended", "message": EVIL}))
            await wait_until_async(lambda: sum(EVIL_SHOWN in line for line in lines) >= 4, what="the page's lines",
                                   timeout=30)
            await hs.close()
            await ws.close()
            reader.cancel()

    asyncio.run(script())
    s.stop("test done")
    _finish(th)
    assert all(line.isprintable() for line in lines), [line for line in lines if not line.isprintable()]
    # hello (agent, reason), marker, started (space, message), ended
    assert sum(line.count(EVIL_SHOWN) for line in lines) == 6
    assert not any(line.startswith("fake") for line in lines)
    assert sum(("A" * 197 + "...; WebXR immersive-vr available") in line for line in lines) == 1
    assert not any("A" * 198 in line for line in lines)


@pytest.mark.parametrize("cli_size", [None, 0.05])
def test_a_page_repeating_marker_and_xrsession_messages_gets_a_few_lines_and_counts(long_media, tmp_path, cli_size):
    """docs/phone-page.md: 300 marker messages with a changing size, 300 of another marker and 300 xrsession
    messages from one connection each give at most 3 lines (1 for another marker), the rest is counted in
    the closing summary."""
    n = 300
    s, out, th, lines = _start(long_media, tmp_path, marker_size_m=cli_size)
    phone = Phone(s, s.port, s.token)
    _wait_video_start(s)
    rec = s.source.recording

    def logged(kind: str) -> int:
        return sum(k for (_, what), k in rec._logged.items() if what == kind)

    async def script():
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as http:
            ws, reader = await phone.connect(http)
            for i in range(n):
                await ws.send_str(json.dumps({"type": "marker", "dictionary": "DICT_4X4_50", "id": 7,
                                              "size_m": 0.04 + i * 1e-4}))
                await ws.send_str(json.dumps({"type": "marker", "dictionary": "DICT_5X5_100", "id": i,
                                              "size_m": 0.05}))
            hs = await http.ws_connect(f"{phone.base}/ws?token={phone.token}&role=headset")
            for i in range(n):
                await hs.send_str(json.dumps({"type": "xrsession", "state": ("started", "ended")[i % 2],
                                              "space": "local-floor"}))
            # each connection's messages are handled in order: its last one's count says all were
            await wait_until_async(lambda: logged("immersive session ends") == n // 2, what="the xrsession messages")
            await wait_until_async(lambda: logged("reports of another marker") == n, what="the marker messages")
            await hs.close()
            await ws.close()
            reader.cancel()

    asyncio.run(script())
    s.stop("test done")
    _finish(th)
    logs = [m.msg.message for m in _messages(tmp_path / "s.mcap") if m.topic == Topic.LOG]
    assert sum("immersive-vr session started" in t for t in logs) == 3
    assert sum("the immersive session ended" in t for t in logs) == 3
    assert sum("the recorder looks for DICT_4X4_50 id 7" in t for t in logs) == 1
    if cli_size is None:   # every size differs from the one before: 300 changes, 3 lines
        assert sum("marker side " in t and "mm (ppi" in t for t in logs) == 3
        assert rec.unlogged == {"immersive session starts": n // 2 - 3, "immersive session ends": n // 2 - 3,
                                "reports of another marker": n - 1, "marker side changes": n - 3}
        assert any(f"the session's marker side: {(0.04 + (n - 1) * 1e-4) * 1000:.1f} mm" in t for t in logs)
    else:                  # --marker-size: one line, the count is the existing "marker size" summary line
        assert sum("the session uses marker_size_m 50.0 mm" in t for t in logs) == 1   # no CLI: the keyword
        assert rec.unlogged == {"immersive session starts": n // 2 - 3, "immersive session ends": n // 2 - 3,
                                "reports of another marker": n - 1}
        ignored = sum(abs(0.04 + i * 1e-4 - 0.05) > 0.05 * SIZE_MISMATCH for i in range(n))
        assert rec.stats["marker size changes ignored"] == ignored
        assert any(f"the page reported another marker size {ignored} time(s)" in t for t in logs)
    summary = next(t for t in logs if t.startswith("lines not repeated (only counted): "))
    assert f"reports of another marker: {n - 1}" in summary and f"immersive session starts: {n // 2 - 3}" in summary
    assert len(logs) < 40


def test_a_page_reconnecting_in_a_loop_gets_lines_for_its_first_connections_and_a_count(long_media, tmp_path):
    """docs/phone-page.md: the first LOGGED_CONNECTIONS WebSockets get their connected/closed lines, the next one
    says that later ones are only counted, and the closing summary counts the rest."""
    from phonepose.record.live.server import LOGGED_CONNECTIONS

    n = LOGGED_CONNECTIONS + 5
    s, out, th, lines = _start(long_media, tmp_path)
    _wait_video_start(s)
    server = s.source.server

    async def script():
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as http:
            for _ in range(n):
                ws = await http.ws_connect(f"https://127.0.0.1:{s.port}/ws?token={s.token}")
                await ws.close()
                # closed on the recorder's side too before the next one: no "replaced by" line
                await wait_until_async(lambda: "phone" not in server.current, what="the recorder to close it")

    asyncio.run(script())
    s.stop("test done")
    _finish(th)
    logs = [m.msg.message for m in _messages(tmp_path / "s.mcap") if m.topic == Topic.LOG]
    connected = [t for t in logs if ": connected" in t]
    closed = [t for t in logs if " after 0 messages" in t]
    assert [t.split(" (")[0] for t in connected] == [f"phone #{i}" for i in range(1, LOGGED_CONNECTIONS + 2)]
    assert connected[-1].endswith("connected; the lines of this and later connections are only counted (closing summary)")
    assert len(closed) == LOGGED_CONNECTIONS
    kind = f"lines of connections after the first {LOGGED_CONNECTIONS}"
    assert s.source.recording.unlogged == {kind: 2 * (n - LOGGED_CONNECTIONS) - 1}
    assert any(f"{kind}: {2 * (n - LOGGED_CONNECTIONS) - 1}" in t for t in logs if t.startswith("lines not repeated"))
    assert sum(": connected" in line for line in lines) == LOGGED_CONNECTIONS + 1    # the terminal's lines too


def test_oversized_invalid_utf8_and_repeated_messages_are_ignored_and_logged_once(long_media, tmp_path):
    """docs/phone-page.md: such a message is ignored and logged once per kind, the connection stays."""
    s, out, th, lines = _start(long_media, tmp_path)
    phone = Phone(s, s.port, s.token)
    _wait_video_start(s)
    big = json.dumps({"type": "hello", "user_agent": "x" * 70_000, "webxr": False, "message": ""})
    hello = json.dumps({"type": "hello", "user_agent": "scripted phone", "webxr": False, "message": ""})

    async def script():
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as http:
            ws, reader = await phone.connect(http)
            for _ in range(3):
                await ws.send_str(big)
                await ws.send_frame(b'{"type": "hello", "user_agent": "\xff\xfe"}', aiohttp.WSMsgType.TEXT)
            for _ in range(3000):
                await ws.send_str(hello)
            await _imu(phone, ws, 20)
            await wait_until_async(lambda: s.source.recording.stats["imu"] >= 20, what="the samples after them")
            assert not ws.closed
            await ws.close()
            reader.cancel()

    asyncio.run(script())
    s.stop("test done")
    _finish(th)
    rec = s.source.recording
    assert rec.malformed_kinds == {"text message over 64 KiB": 3, "text message that is not valid UTF-8": 3}
    assert rec.repeats == {"hello messages after the first on a connection": 2999}
    msgs = _messages(tmp_path / "s.mcap")
    logs = [m.msg.message for m in msgs if m.topic == Topic.LOG]
    assert sum("over 64 KiB" in t for t in logs) == 2          # once when it came, once in the summary
    assert sum("not valid UTF-8" in t for t in logs) == 2
    assert sum("scripted phone" in t for t in logs) == 1       # the first hello
    assert sum("hello messages after the first" in t for t in logs) == 2
    assert any("repeated messages ignored: hello messages after the first on a connection: 2999" in t for t in logs)
    assert sum(m.topic == Topic.CONTROLLER_IMU for m in msgs) == 20


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


@pytest.mark.long
def test_2000_idle_connections_neither_grow_memory_nor_lock_out_the_phone(long_media, tmp_path):
    """2000 TCP connections that never start TLS (anyone on the network can open them) from one address, then
    the phone from another: the gate (phonepose/record/live/gate.py) holds at most PER_ADDRESS of them and
    refuses or drops the rest, so the phone is served and memory stays flat."""
    from phonepose.record.live.server import PER_ADDRESS

    s, out, th, lines = _start(long_media, tmp_path)
    _wait_video_start(s)
    before = _rss_mb()
    idle = []
    try:
        for _ in range(2000):
            idle.append(socket.create_connection(("127.0.0.1", s.port), timeout=DEADLINE_S))
        gate = s.source.server.gate
        wait_until(lambda: gate.dropped + gate.refused >= 2000 - PER_ADDRESS, what="the gate to refuse the idle ones")
        assert len(gate.untrusted.get("127.0.0.1", ())) <= PER_ADDRESS
        grown = _rss_mb() - before
        phone = Phone(s, s.port, s.token)

        async def script():
            connector = aiohttp.TCPConnector(ssl=False, local_addr=(PHONE_ADDRESS, 0))
            async with aiohttp.ClientSession(connector=connector) as http:
                ws, reader = await phone.connect(http)
                await _imu(phone, ws, 20)
                await wait_until_async(lambda: s.source.recording.stats["imu"] >= 20, what="the phone's samples")
                await ws.close()
                reader.cancel()

        asyncio.run(script())
    finally:
        for sock in idle:
            sock.close()
    s.stop("test done")
    _finish(th)
    assert grown < 80, f"{grown:.0f} MB for 2000 idle connections"     # ~590 MB before the gate, 35 MB in a bare server
    assert sum(m.topic == Topic.CONTROLLER_IMU for m in _messages(tmp_path / "s.mcap")) == 20
    assert any("connections without the token closed" in line for line in lines)


PHONE_ADDRESS = "127.0.0.2"    # another loopback address (Linux routes 127/8 to lo): the phone, apart from attackers


@pytest.mark.parametrize("mode", ["halfopen", "slow"])
def test_an_attacker_on_one_address_never_keeps_the_token_bearer_out(long_media, tmp_path, mode):
    """tools/live_attack.py from 127.0.0.1 (in its own process): 80 connections that send a ClientHello and no more,
    reopened as soon as they are closed, or 4 new connections a second that finish TLS and send their request a
    byte a second. The gate keeps the attacker to PER_ADDRESS untrusted connections, closes the slow ones at the
    request deadline, and the page with the token is served to the phone's address throughout."""
    import subprocess
    import sys
    from pathlib import Path

    from phonepose.record.live.server import PER_ADDRESS

    tools = Path(__file__).resolve().parents[1] / "tools"
    sys.path.insert(0, str(tools))
    try:
        import live_attack
    finally:
        sys.path.remove(str(tools))
    s, out, th, lines = _start(long_media, tmp_path)
    _wait_video_start(s)
    gate = s.source.server.gate
    attacker = subprocess.Popen([sys.executable, str(tools / "live_attack.py"), mode, "--port", str(s.port)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    shares: list[int] = []

    def attacker_share() -> int:
        shares.append(len(gate.untrusted.get("127.0.0.1", ())))
        return shares[-1]

    try:
        if mode == "halfopen":   # its share full and newer connections refused
            wait_until(lambda: attacker_share() == PER_ADDRESS and gate.refused >= 100, what="the flood at its cap")
        else:                    # slow clients closed at the deadline, others still trickling
            wait_until(lambda: gate.dropped >= 4 and attacker_share() >= 4, what="slow clients closed at the deadline")
        closed_before = gate.dropped + gate.refused

        async def probes():
            results = []
            for _ in range(5):
                results.append((await live_attack.probe("127.0.0.1", s.port, s.token, PHONE_ADDRESS, DEADLINE_S))[0])
                attacker_share()
            return results

        assert asyncio.run(probes()) == [200] * 5
        # the attack went on: it is still running and the gate goes on closing its connections (the probes may
        # all be served before a slow client reaches its deadline)
        wait_until(lambda: gate.dropped + gate.refused > closed_before, what="the gate closing more of the attack")
        assert attacker.poll() is None
    finally:
        attacker.kill()
        attacker.wait(timeout=DEADLINE_S)
    s.stop("test done")
    _finish(th)
    assert max(shares) <= PER_ADDRESS
    assert any("connections without the token closed" in line for line in lines)


def test_deep_static_paths_and_oversized_request_lines_are_one_line_not_a_traceback(long_media, tmp_path, capfd):
    s, out, th, lines = _start(long_media, tmp_path)
    ctx = ssl.create_default_context()
    ctx.check_hostname, ctx.verify_mode = False, ssl.CERT_NONE

    def status(request: bytes) -> bytes:
        with ctx.wrap_socket(socket.create_connection(("127.0.0.1", s.port), timeout=DEADLINE_S)) as c:
            c.sendall(request)
            return c.recv(64).split(b"\r\n")[0]

    for _ in range(3):
        assert status(b"GET /static/" + b"a/" * 3000 + b"x HTTP/1.1\r\nHost: x\r\n\r\n") == b"HTTP/1.1 404 Not Found"
        assert status(b"GET /" + b"a" * 20000 + b" HTTP/1.1\r\nHost: x\r\n\r\n") == b"HTTP/1.0 400 Bad Request"
    s.stop("test done")
    _finish(th)
    err = capfd.readouterr().err
    assert "Traceback" not in err and "File name too long" not in err
    assert sum("bad HTTP requests (LineTooLong)" in line for line in lines) == 1
    assert s.source.recording.repeats["bad HTTP requests (LineTooLong)"] == 3
