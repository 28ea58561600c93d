"""Interrupted recordings: SIGKILL at random moments loses at most ~1 s; SIGINT/SIGTERM leave a complete file.

The simulator is deterministic (same seed, same bytes), so a killed recording is compared with
a complete recording of the same seed: what ``recover`` gets back must be exactly the first N
messages the complete file holds, and the gap to what the recorder had handed to its writer
when it died must be at most the writer's flush interval (1 s of log time).
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import aiohttp
import numpy as np
import pyarrow.parquet as pq
import pytest
import test_record_live
from conftest import DEADLINE_S, wait_until, wait_until_async, within
from mcap.reader import make_reader
from test_reliability_data import mounted_tmpfs

from phonepose.errors import DamagedFileError
from phonepose.schemas.topics import Topic
from phonepose.session import SessionReader
from phonepose.session.recover import salvage

pytestmark = pytest.mark.slow
media = test_record_live.media                # a video of the marker and its calibration (record live)
long_media = test_record_live.long_media

SCENARIO = ["--scenario", "exp2", "--path", "TRI1", "--trial", "1", "--seed", "3"]
PROGRESS_EVERY_S = 0.1   # the recorder reports progress about every 0.1 s of session time

# The child reports (after each write) how far it has recorded, so the parent knows what the
# writer had been handed when the kill landed: at least the last report, less than 0.1 s more.
CHILD = """
import sys
from phonepose.record.sim import record_sim
def progress(done_ns, total_ns):
    print(done_ns, flush=True)
record_sim(sys.argv[1], scenario="exp2", path="TRI1", trial=1, seed=3, progress=progress)
"""


def _file_order(path) -> list[tuple]:
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.sequence, m.data)
                for _, c, m in make_reader(f).iter_messages(log_time_order=False)]


@pytest.fixture(scope="module")
def complete(tmp_path_factory):
    out = tmp_path_factory.mktemp("kill") / "complete.mcap"
    r = subprocess.run([sys.executable, "-m", "phonepose", "record", "sim", *SCENARIO, "--out", str(out), "-q"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    with SessionReader(out) as reader:
        start = reader.summary().start_ns
    return out, _file_order(out), start


def test_sigkill_at_random_moments_loses_at_most_a_second(complete, tmp_path):
    path, full, start = complete
    end_s = (max(m[1] for m in full) - start) / 1e9
    rng = np.random.default_rng(11)
    targets = sorted(float(x) for x in rng.uniform(1.5, end_s - 1.0, 3))
    results = []
    for i, target in enumerate(targets):
        out = tmp_path / f"killed{i}.mcap"
        child = subprocess.Popen([sys.executable, "-c", CHILD, str(out)], stdout=subprocess.PIPE, text=True)
        reported = 0
        for line in child.stdout:
            reported = max(reported, int(line))
            if reported / 1e9 >= target:
                child.send_signal(signal.SIGKILL)
                break
        reported = max([reported] + [int(x) for x in child.stdout.read().split()])  # written before death
        child.wait(timeout=DEADLINE_S)
        assert child.returncode == -signal.SIGKILL
        with pytest.raises(DamagedFileError):
            SessionReader(out)       # no summary: the file needs recover
        fixed = tmp_path / f"fixed{i}.mcap"
        report = salvage(out, fixed)
        got = _file_order(fixed)
        assert got == full[: len(got)]                     # exactly the first N messages, byte for byte
        recovered_s = (max(m[1] for m in got) - start) / 1e9
        handed_max_s = reported / 1e9 + PROGRESS_EVERY_S   # the writer had at most this much
        lost_s = handed_max_s - recovered_s
        results.append((round(target, 2), len(got), len(full), round(reported / 1e9 - recovered_s, 3),
                        round(lost_s, 3), report.chunks_skipped))
        assert lost_s <= 1.0 + PROGRESS_EVERY_S + 0.02, results[-1]
    print("SIGKILL (target s, recovered, complete, lost >= s, lost <= s, damaged chunks):", results)
    # the recovered recording is a normal session again: it plays back
    r = subprocess.run([sys.executable, "-m", "phonepose", "playback", str(fixed), "-q", "-t", "T1", "-t", "T7",
                        "--out", str(tmp_path / "playback")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    ticks = int(r.stdout.split(" ticks in ")[0].split()[-1])
    assert ticks >= 20 * (recovered_s - 1.0)          # a tick every 50 ms over what was recovered
    assert (tmp_path / "playback" / "metrics.json").exists()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_sigint_sigterm_leave_a_complete_file(complete, tmp_path, sig):
    path, full, start = complete
    out = tmp_path / "stopped.mcap"
    child = subprocess.Popen([sys.executable, "-m", "phonepose", "record", "sim", *SCENARIO, "--out", str(out), "-q"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_until(lambda: child.poll() is not None or (out.exists() and out.stat().st_size > 4_000_000),
               what="the recording to pass 4 MB")                 # a few seconds into the session
    assert child.poll() is None, "recording ended before the signal"
    child.send_signal(sig)
    stdout, stderr = child.communicate(timeout=DEADLINE_S)
    assert child.returncode == 0, stderr
    assert "interrupted, file is valid" in stdout
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()               # summary and index exist
    assert summary is not None and summary.statistics.message_count > 0
    got = _file_order(out)
    assert summary.statistics.message_count == len(got)
    assert 0 < len(got) < len(full) and got == full[: len(got)]
    with SessionReader(out) as reader:
        assert reader.summary().message_count == len(got)


def test_disk_full_while_recording_is_one_line_and_the_file_recovers(tmp_path):
    """A real 2 MiB tmpfs (root with mount permission only; the ENOSPC double in test_reliability_session runs everywhere)."""
    with mounted_tmpfs(tmp_path / "mnt", "size=2m") as mnt:
        out = mnt / "s.mcap"
        r = subprocess.run([sys.executable, "-m", "phonepose", "record", "sim", *SCENARIO, "--out", str(out), "-q"],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 6
        assert r.stderr.strip() == (f"phonepose: error: cannot write {out}: No space left on device "
                                    "(the file written so far stays readable; run `phonepose recover`)")
        report = salvage(out, tmp_path / "fixed.mcap")
        # at least the first flushed second of the recording (the writer flushes once per second of log time)
        assert report.chunks_recovered >= 1 and report.end_ns - report.start_ns >= 900_000_000 and report.messages > 300
        with SessionReader(tmp_path / "fixed.mcap") as reader:
            assert reader.summary().has("/display/camera/image")


# ----------------------------------------------------------------------------- a stopped batch stops its workers
def _session_members(sid: int) -> list[tuple[int, str]]:
    """(pid, command) of the live processes of session ``sid`` (zombies excluded)."""
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                stat = f.read()
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                cmd = f.read().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        if int(fields[3]) == sid and fields[0] != "Z":
            out.append((int(entry), cmd))
    return out


@pytest.fixture(scope="module")
def batch_sessions(tmp_path_factory):
    from phonepose.testing.playback_session import write_test_session

    d = tmp_path_factory.mktemp("batch")
    write_test_session(d / "s0.mcap", duration_s=30.0)
    for i in range(1, 4):        # copies: four units of work to be killed in, for the cost of writing one
        shutil.copyfile(d / "s0.mcap", d / f"s{i}.mcap")
    return d


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_stopping_a_batch_stops_its_workers(batch_sessions, tmp_path, sig):
    """`kill -TERM` or `kill -9` of `phonepose batch`: its workers and multiprocessing's resource tracker are
    gone within seconds (PR_SET_PDEATHSIG; before: over a minute, holding the caller's stdout open); SIGTERM
    also writes the finished rows and says so in one line."""
    out = tmp_path / "t.parquet"
    p = subprocess.Popen([sys.executable, "-m", "phonepose", "batch", *sorted(map(str, batch_sessions.glob("*.mcap"))),
                          "-t", "all", "-p", "rate_hz=20,40", "--workers", "2", "-q", "--out", str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    def running() -> bool:                         # both workers up and a first unit written
        assert p.poll() is None, p.communicate()
        return len([c for _, c in _session_members(p.pid) if "spawn_main" in c]) >= 2 and out.exists()
    wait_until(running, what="the batch's two workers and its first unit", timeout=300)
    rows_before = pq.read_table(out).num_rows
    t0 = time.monotonic()
    p.send_signal(sig)
    wait_until(lambda: not _session_members(p.pid), what="every process of the batch to end", timeout=60)
    gone_s = time.monotonic() - t0
    stdout, stderr = p.communicate(timeout=60)     # the pipes close: nothing holds them any more
    assert not _session_members(p.pid), _session_members(p.pid)
    print(f"{sig.name}: every process of the batch gone {gone_s:.2f} s after the signal")
    assert gone_s < 20
    assert "leaked semaphore" not in stderr.decode()
    rows = pq.read_table(out).num_rows
    assert rows >= rows_before > 0
    if sig == signal.SIGTERM:
        assert p.returncode == 143
        assert stderr.decode().strip().splitlines()[-1] == (
            f"phonepose: error: terminated (SIGTERM): {rows} finished rows are in {out}; the next run with the same "
            "--out goes on from there")


# ------------------------------------------------------------------------ record live: phone and headset connected
LIVE_SAMPLE_S = 0.01       # each scripted page sends a sample every 10 ms


def _live_child(long_media, tmp_path, out):
    """``record live`` in a child process; returns it and its two links (phone, headset)."""
    _, video, calib = long_media
    child = subprocess.Popen([sys.executable, "-m", "phonepose", "record", "live", "--camera", str(video),
                              "--calibration", str(calib), "--out", str(out), "--host", "127.0.0.1", "--port", "0",
                              "--tls-dir", str(tmp_path / "tls"), "--marker-size", "0.06", "--no-qr"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    urls = []
    for line in child.stdout:
        if line.strip().startswith("https://"):
            urls.append(line.strip())
            if len(urls) == 2:
                return child, urls[0], urls[1]
    raise AssertionError(f"record live printed no links: {child.communicate(timeout=DEADLINE_S)}")


class _Page:
    """A scripted page on the recorder's machine: its clock is the wall clock (the recorder's clock is wall
    time advanced by the monotonic clock), it answers pings at once and streams one sample every 10 ms until
    the recorder says it stopped recording (a status with recording false) or the connection breaks."""

    def __init__(self, url: str, role: str):
        base, token = url.split("?token=")
        self.ws_url = base.rsplit("/", 1)[0] + "/ws?token=" + token + ("&role=headset" if role == "headset" else "")
        self.role = role
        self.sent: list[float] = []       # t (ms) of every sample sent
        self.stopped = False

    def sample(self, t_ms: float) -> dict:
        """The next sample, its number (len(sent)) in it: which ones a file holds needs no clock (see sample_numbers)."""
        i = len(self.sent)
        if self.role == "phone":
            return {"type": "imu", "t": t_ms, "gyro": [0.01, 0.02, float(i)], "accel": [0.1, 9.8, 0.2]}
        return {"type": "xrframe", "t": t_ms, "viewer": {"p": [0.0, 1.6, 0.0], "q": [0.0, 0.0, 0.0, 1.0]},
                "controllers": [{"hand": "right", "p": [0.1, 1.2, -0.3 - i * 1e-3], "q": [0.0, 0.0, 0.0, 1.0]}]}

    @staticmethod
    def sample_numbers(path, topic: str) -> list[int]:
        """The numbers :meth:`sample` put in the samples of ``topic`` in the file (gt_world x = -WebXR z)."""
        with SessionReader(path) as reader:
            if topic == Topic.CONTROLLER_IMU:
                return [round(m.msg.gyro_z) for m in reader.messages([topic])]
            return [round((m.msg.pose.position.x - 0.3) * 1e3) for m in reader.messages([topic])]

    async def run(self, http, until: asyncio.Event) -> None:
        ws = await http.ws_connect(self.ws_url)

        async def read():
            async for msg in ws:
                if msg.type != aiohttp.WSMsgType.TEXT:
                    break
                m = json.loads(msg.data)
                if m["type"] == "ping":
                    await ws.send_str(json.dumps({"type": "pong", "id": m["id"], "t": time.time_ns() / 1e6}))
                elif m["type"] == "status" and not m["recording"]:
                    self.stopped = True

        reader = asyncio.ensure_future(read())
        await ws.send_str(json.dumps({"type": "hello", "user_agent": f"scripted {self.role}", "webxr": True,
                                      "message": ""}))
        try:
            while not (self.stopped or until.is_set() or ws.closed):
                t_ms = time.time_ns() / 1e6
                await ws.send_str(json.dumps(self.sample(t_ms)))
                self.sent.append(t_ms)
                await asyncio.sleep(LIVE_SAMPLE_S)
        except (ConnectionError, RuntimeError):
            pass                           # the recorder died under the page
        await asyncio.gather(reader, return_exceptions=True)


def _stamps(path, topic: str) -> np.ndarray:
    with SessionReader(path) as reader:
        return np.array([m.msg.timestamp.ToNanoseconds() / 1e6 for m in reader.messages([topic])])



async def _stream_then_kill(child, pages: list[_Page], after_s: float) -> float:
    """Both pages stream; after ``after_s`` the recorder is SIGKILLed: the wall time of the kill (ms)."""
    until = asyncio.Event()
    async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as http:
        runs = asyncio.gather(*(p.run(http, until) for p in pages))
        await asyncio.sleep(after_s)
        killed_ms = time.time_ns() / 1e6
        child.send_signal(signal.SIGKILL)
        until.set()
        await within(runs, what="the pages to stop")
    return killed_ms


def test_live_sigkill_with_phone_and_headset_loses_at_most_a_second(long_media, tmp_path):
    """issue 20: the reorder buffer (HOLD_NS) plus the writer's flush (FLUSH_NS) is all a SIGKILL costs, for the
    phone's samples and the headset's ground truth alike: what recover gets back reaches to within 1 s of the kill."""
    from phonepose.record.live.session import FLUSH_NS, HOLD_NS

    rng = np.random.default_rng(20)
    results = []
    for i, after_s in enumerate(float(x) for x in rng.uniform(2.0, 4.0, 3)):
        out = tmp_path / f"live{i}.mcap"
        child, phone_url, headset_url = _live_child(long_media, tmp_path, out)
        pages = [_Page(phone_url, "phone"), _Page(headset_url, "headset")]
        try:
            killed_ms = asyncio.run(_stream_then_kill(child, pages, after_s))
            child.wait(timeout=DEADLINE_S)
        finally:
            if child.poll() is None:
                child.kill()
        assert child.returncode == -signal.SIGKILL
        fixed = tmp_path / f"fixed{i}.mcap"
        salvage(out, fixed)
        row = [round(after_s, 2)]
        for page, topic in zip(pages, (Topic.CONTROLLER_IMU, Topic.GT_CONTROLLER_POSE), strict=True):
            got = _stamps(fixed, topic)
            sent = np.array(page.sent)
            assert len(got) > 0, topic
            # a prefix of what was sent, nothing skipped: by the samples' own numbers (their stamps carry the clock
            # sync's error, half a round trip, which a loaded machine can stretch past any fixed ms)
            assert page.sample_numbers(fixed, topic) == list(range(len(got))), topic
            lost_s = float(killed_ms - sent[len(got) - 1]) / 1e3        # since the last one kept was sent
            row += [len(got), len(sent), round(lost_s, 3)]
            # HOLD + FLUSH, and what a loaded 2-core machine adds: the page's sends, the recorder's loop and its flush
            # all wait for a core (quiet: 0.57-0.94 s; a CI run beside exp2's workers: 1.30 s, with the page loop so
            # starved that it sent 62 samples a second instead of 100)
            assert lost_s <= (HOLD_NS + FLUSH_NS) / 1e9 + 0.5, (topic, row)
        # of that, held by the recorder: an IMU sample's log time is its receipt on the recorder's clock
        with SessionReader(fixed) as reader:
            received_ns = max(m.log_time_ns for m in reader.messages([Topic.CONTROLLER_IMU]))
        row.append(round((killed_ms * 1e6 - received_ns) / 1e9, 3))
        results.append(tuple(row))
    print("record live SIGKILL (after s, imu recovered, imu sent, imu lost s, gt recovered, gt sent, gt lost s, "
          "imu held by the recorder s):",
          results)


def test_live_sigint_with_phone_and_headset_loses_nothing(long_media, tmp_path):
    out = tmp_path / "live.mcap"
    child, phone_url, headset_url = _live_child(long_media, tmp_path, out)
    pages = [_Page(phone_url, "phone"), _Page(headset_url, "headset")]

    async def script():
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as http:
            runs = asyncio.gather(*(p.run(http, asyncio.Event()) for p in pages))
            await wait_until_async(lambda: all(len(p.sent) > 200 for p in pages), what="2 s of samples from both pages")
            child.send_signal(signal.SIGINT)             # both pages still streaming
            await within(runs, what="the recorder to stop the pages")

    try:
        asyncio.run(script())
        stdout, stderr = child.communicate(timeout=DEADLINE_S)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == 0, stderr
    assert "interrupted, file is valid" in stdout and "Traceback" not in stderr
    for page, topic in zip(pages, (Topic.CONTROLLER_IMU, Topic.GT_CONTROLLER_POSE), strict=True):
        assert page.stopped, page.role                   # told by the recorder, so every sample it sent was sent before
        got = _stamps(out, topic)
        assert len(got) == len(page.sent), (topic, len(got), len(page.sent))
