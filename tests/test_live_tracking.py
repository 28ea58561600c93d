"""Live tracking (``record live -t``): the hold-back's order, live estimates equal to playback's bit for bit,
the pose stream and its example client, a failing tracker, ``playback --check-live``."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
import time
from pathlib import Path

import aiohttp
import numpy as np
import pytest
from conftest import DEADLINE_S, wait_until
from hypothesis import given, settings
from hypothesis import strategies as st

from phonepose.pipeline.trackers import make_trackers
from phonepose.playback.livecheck import check_live
from phonepose.playback.livereport import live_report, summary_lines
from phonepose.record.live.posestream import PoseStreamServer
from phonepose.record.live.tracking import HOLD_BACK_NS, LiveTracker, StreamMerger
from phonepose.record.source import Record
from phonepose.schemas.topics import Topic
from phonepose.session import SessionReader
from phonepose.testing.live_feed import arrival_order, replay_live
from phonepose.testing.playback_session import write_test_session

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "pose_client.py"
STREAMS = (Topic.CAMERA_IMAGE, Topic.DISPLAY_VIO_POSE, Topic.CONTROLLER_VIO_POSE, Topic.CONTROLLER_IMU,
           Topic.GT_CONTROLLER_POSE)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    p = tmp_path_factory.mktemp("live") / "s.mcap"
    write_test_session(p, duration_s=3.0)
    return p


@pytest.fixture(scope="module")
def n_ticks(session) -> int:
    """The ticks playback forms on the session."""
    from phonepose.playback.scheduler import TickScheduler
    from phonepose.session.context import read_context
    with SessionReader(session) as reader:
        return len(TickScheduler(reader, read_context(reader)))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(1_000_000, HOLD_BACK_NS // 4), st.integers(0, 10**9), st.integers(1, 40),
                          st.integers(0, HOLD_BACK_NS // 2), st.integers(0, 2**32)), min_size=1, max_size=4))
def test_merger_passes_interleaved_streams_on_in_log_time_order(streams):
    """Streams each in order (a sample at least every hold-back / 4), each arriving up to hold-back / 2 late,
    once each has said hello (a stream not heard of yet is not waited for): passed on whole, in log-time order,
    none late."""
    arrivals = [(0, k, 0) for k in range(len(streams))]
    for k, (period, start, n, max_delay, seed) in enumerate(streams):
        rng = np.random.default_rng(seed)
        last = 0
        for i in range(n):
            t = 1 + start % period + i * period
            last = max(last, t + int(rng.integers(0, max_delay + 1)))
            arrivals.append((last, k, t))
    arrivals.sort()
    merger = StreamMerger()
    out = []
    for _, k, t in arrivals:
        out += [m[2] for m in merger.push(f"/s{k}", None, t)]
    out += [m[2] for m in merger.flush()]
    assert out == sorted(t for _, _, t in arrivals)
    assert not merger.late


def _delays(seed: int) -> dict[str, int]:
    rng = np.random.default_rng(seed)
    return {topic: int(rng.integers(0, HOLD_BACK_NS * 4 // 5)) for topic in STREAMS}


@pytest.mark.parametrize("seed", range(4))
def test_live_estimates_equal_playback_for_every_tracker(session, n_ticks, tmp_path, seed, cli):
    """Every tracker, streams interleaved by generated delays within the hold-back: every tick identical."""
    out = tmp_path / "live.mcap"
    tracker = replay_live(session, out, ["all"], seed=seed, max_delay_ns=_delays(seed))
    assert not tracker.merger.late and not tracker.stopped
    checks = check_live(out)
    assert [c.tracker for c in checks] == [t.name for t in make_trackers(["all"])]
    for c in checks:
        assert (c.compared, c.identical, c.different) == (tracker.ticks, tracker.ticks, 0), c
    assert tracker.ticks == n_ticks == 61   # 3 s at 20 Hz from the first frame, both ends
    r = cli("playback", out, "--check-live")
    assert r.returncode == 0, r.stderr
    assert f"T8: {tracker.ticks} ticks compared, {tracker.ticks} identical, 0 different" in r.stdout.splitlines()


def test_a_stream_later_than_the_hold_back_is_counted_and_check_live_fails(session, tmp_path, cli):
    out = tmp_path / "late.mcap"
    late = {Topic.CAMERA_IMAGE: 3 * HOLD_BACK_NS, Topic.DISPLAY_VIO_POSE: 3 * HOLD_BACK_NS}
    tracker = replay_live(session, out, ["T4"], seed=0, max_delay_ns=late)
    assert tracker.merger.late[Topic.CAMERA_IMAGE] > 0
    assert any("late messages" in line for line in tracker.summary())
    r = cli("playback", out, "--check-live")
    assert r.returncode == 1
    [line] = r.stderr.strip().splitlines()
    assert line.startswith("phonepose: error: live estimates differ from playback's: T4 at ")


def test_check_live_on_a_session_without_live_tracking_is_one_line(session, cli):
    r = cli("playback", session, "--check-live")
    assert r.returncode == 4
    assert r.stderr.strip() == (f"phonepose: error: {session}: no live tracking in this session (record it with "
                             "`record live -t TRACKER`)")


class _Boom:
    """A tracker that raises at its ``k``-th step."""
    needs_camera = False
    uses_vio_samples = False

    def __init__(self, k: int):
        self.name, self.k, self.n = "Boom", k, 0

    def reset(self) -> None:
        self.n = 0

    def step(self, obs):
        self.n += 1
        if self.n == self.k:
            raise ValueError("broken on purpose")
        return None


@pytest.mark.parametrize("k", [1, 7, 33])
def test_a_tracker_that_raises_is_one_warning_and_the_rest_goes_on(session, n_ticks, tmp_path, k):
    tracker = replay_live(session, tmp_path / "boom.mcap", [*make_trackers(["T1"]), _Boom(k)], seed=k)
    boom = [w for w in tracker.warnings if "Boom" in w]
    assert boom == [f"tracker Boom raised at tick {k - 1} (ValueError: broken on purpose); it is stepped no more, "
                    "the recording and the other trackers go on"]
    assert tracker.ticks == n_ticks and tracker.report()["per_tracker"]["T1"]["estimates"] > 0
    assert tracker.report()["per_tracker"]["Boom"]["failed"] == "ValueError: broken on purpose"


def _records(path) -> tuple[list[Record], list[Record]]:
    from phonepose.session.context import STATIC_TOPICS
    with SessionReader(path) as reader:
        msgs = [Record(m.topic, m.msg, m.log_time_ns, m.publish_time_ns) for m in reader.messages()]
    return [r for r in msgs if r.topic in STATIC_TOPICS], [r for r in msgs if r.topic not in STATIC_TOPICS]


def test_pose_stream_example_client_reads_a_live_run(session, n_ticks, tmp_path):
    """The tracking thread fed through offer() as the recorder feeds it; the example client prints every estimate."""
    server = PoseStreamServer("127.0.0.1", 0)
    server.start()
    published: list[Record] = []
    sent: list[str] = []

    def lines(batch: list[str]) -> None:
        sent.extend(batch)
        server.send(batch)

    tracker = LiveTracker(make_trackers(["T4", "T8"]), publish=published.append, now_ns=time.time_ns,
                          warn=lambda text: None, lines=lines)
    client = subprocess.Popen([sys.executable, str(EXAMPLE), server.url], stdout=subprocess.PIPE, text=True)
    try:
        wait_until(lambda: server.clients or client.poll() is not None, what="the example client to connect")
        assert client.poll() is None
        tracker.start()
        static, data = _records(session)
        for r in static + arrival_order(data, _delays(9), 9):
            tracker.offer(r)
        tracker.finish(DEADLINE_S)
    finally:
        server.stop()
        out, _ = client.communicate(timeout=DEADLINE_S)
    assert tracker.dropped == 0 and server.dropped == 0
    docs = [json.loads(line) for line in sent]
    assert len(docs) == 2 * tracker.ticks == 2 * n_ticks
    expect = [f"{d['t_ns']} {d['tracker']} "
              + ("no pose" if d["position"] is None else " ".join(f"{v:+.3f}" for v in d["position"]))
              + f" in_view={d['in_view']}" for d in docs]
    assert out.splitlines() == expect
    assert sum(d["position"] is not None for d in docs) == len(published) > 0


def test_pose_stream_opened_to_the_network_wants_the_token():
    server = PoseStreamServer("0.0.0.0", 0, token="s3cret")
    port = server.start()
    try:
        async def attempt(query: str) -> int:
            async with aiohttp.ClientSession() as s:
                try:
                    async with s.ws_connect(f"ws://127.0.0.1:{port}/poses{query}"):
                        return 101
                except aiohttp.WSServerHandshakeError as exc:
                    return exc.status
        assert asyncio.run(attempt("")) == 403
        assert asyncio.run(attempt("?token=wrong")) == 403
        assert asyncio.run(attempt("?token=s3cret")) == 101
        assert server.refused == 2
    finally:
        server.stop()
    assert server.url == f"wss://localhost:{port}/poses?token=s3cret"


def test_report_is_stored_and_read_back(session, n_ticks, tmp_path):
    out = tmp_path / "live.mcap"
    tracker = replay_live(session, out, ["T1", "T8"], seed=3)
    rep = live_report(out)
    assert rep == json.loads(json.dumps(tracker.report()))
    assert rep["trackers"] == ["T1", "T8"] and rep["ticks"] == n_ticks
    for name in ("T1", "T8"):
        for key in ("compute_ms", "input_to_publish_ms"):
            p = rep["per_tracker"][name][key]
            assert p["n"] == n_ticks and 0 <= p["p50"] <= p["p99"] <= p["max"]


@pytest.mark.slow
def test_rehearsed_recording_tracks_live_as_playback_does(tmp_path):
    """``record rehearse -t T8 -t T4``: the real live path (pages in Chromium, the video as the camera); every
    live estimate in the session equals playback's."""
    from conftest import require_browser

    from phonepose.errors import ConfigError
    from phonepose.record.live.session import LiveTracking
    from phonepose.record.rehearse import rehearse
    from phonepose.record.rehearse.browser import find_iwer

    try:
        find_iwer()
    except ConfigError as exc:   # no node: tools/install-test-browser.sh could not run npm ci
        pytest.skip(str(exc))
    require_browser()
    tracking = LiveTracking(make_trackers(["T8", "T4"]), pose_port=0)
    lines: list[str] = []
    result = rehearse(tmp_path / "r", lead_in_s=30.0, timeout_s=DEADLINE_S, echo=lines.append, headset=False,
                      tracking=tracking)
    live = result.files["live.mcap"]
    report = live_report(live)
    assert report is not None and report["dropped"] == 0 and not report["stopped"]
    assert report["ticks"] > 20 * 30   # the lead-in and the motion at 20 Hz
    n = report["ticks"]
    checks = check_live(live)
    assert [c.tracker for c in checks] == ["T8", "T4"] and all(c.compared == n for c in checks)
    assert any(line.startswith("live T8: ") for line in result.tracking)
    # the rehearsal's own summary says per tracker what --check-live says
    for c in checks:
        want = f"live {c.tracker} vs playback: {c.identical} of {n} ticks identical"
        assert (want + (f", {c.different} different" if c.different else "")) in result.tracking
    if not report["late"]:
        # no stream fell more than the hold-back behind (a machine starved of CPU can delay the browser's pages
        # that long: then the late messages are counted and --check-live shows the ticks they changed)
        assert all(c.identical == n for c in checks), checks
    else:
        assert any(line.startswith("live tracking took late messages") for line in summary_lines(report))
    received = [line for line in result.tracking if line.startswith("pose stream: an application client received")]
    dropped = any("dropped for slow clients" in line for line in result.tracking)
    assert received == [f"pose stream: an application client received {2 * n} estimate(s)"] or dropped, received


def _damaged_reports(good: dict) -> list[str]:
    """The good report with each key removed, each value of the wrong type, and text that is not JSON."""
    out = ["", "{", "null", "[]", json.dumps("report")]
    for key in good:
        out.append(json.dumps({k: v for k, v in good.items() if k != key}))
        out.append(json.dumps({**good, key: {"not": "this"} if not isinstance(good[key], dict) else "x"}))
    return out


def test_damaged_live_figures_are_one_line(session, tmp_path, cli):
    from phonepose.playback.livereport import METADATA_NAME
    from phonepose.session import SessionWriter

    src = tmp_path / "live.mcap"
    good = replay_live(session, src, ["T1"], seed=0).report()
    with SessionReader(src) as reader:
        msgs = list(reader.messages())
    required = ("trackers", "rate_hz", "correction_math", "first_tick_ns", "last_tick_ns", "ticks", "per_tracker")
    cases = [c for c in _damaged_reports(good)
             if not (c.startswith("{\"") and all(k in json.loads(c) and json.loads(c)[k] == good[k] for k in required))]
    assert len(cases) > 10
    for i, text in enumerate(cases):
        bad = tmp_path / f"bad{i}.mcap"
        with SessionWriter(bad) as w:
            for m in msgs:
                w.write(m.topic, m.msg, m.log_time_ns, m.publish_time_ns)
            w.add_metadata(METADATA_NAME, {"report": text})
        r = cli("playback", bad, "--check-live")
        assert r.returncode == 4, (text, r)
        assert r.stderr.strip() == (f"phonepose: error: {bad}: its live tracking figures (MCAP metadata "
                                    f"{METADATA_NAME}) are damaged"), text
        r = cli("info", bad)
        assert r.returncode == 0 and "live tracking" not in r.stdout
        assert r.stderr.strip().startswith("phonepose: warning: ")


class _Slow:
    """A tracker whose every step lasts at least ``at_least_s`` (busy: no sleep's granularity)."""
    needs_camera = False
    uses_vio_samples = False
    name = "Slow"

    def __init__(self, at_least_s: float):
        self.at_least_s = at_least_s

    def reset(self) -> None:
        pass

    def step(self, obs):
        end = time.perf_counter() + self.at_least_s
        while time.perf_counter() < end:
            pass
        return None


@pytest.mark.parametrize("rate_hz", [500.0, 1000.0])
def test_a_tracker_longer_than_the_tick_period_is_one_warning_and_counted(tmp_path, rate_hz):
    short = tmp_path / "short.mcap"
    write_test_session(short, duration_s=0.4)
    tracker = replay_live(short, tmp_path / "slow.mcap", [_Slow(2.0 / rate_hz)], rate_hz=rate_hz)
    slow = [w for w in tracker.warnings if "Slow" in w]
    assert len(slow) == 1 and slow[0].startswith("tracker Slow took ")
    assert tracker.report()["per_tracker"]["Slow"]["overruns"] == tracker.ticks > 0
    assert f"{tracker.ticks} tick(s) over the period" in tracker.summary()[1]


@pytest.mark.parametrize("n", [7, 100])
def test_input_beyond_the_queue_is_dropped_counted_and_said_once(session, n):
    warnings: list[str] = []
    tracker = LiveTracker(make_trackers(["T1"]), publish=lambda r: None, now_ns=time.time_ns, warn=warnings.append,
                          queue_max=5)
    _static, data = _records(session)
    for r in data[:n]:
        tracker.offer(r)       # the thread is not started: nothing is taken out
    assert tracker.dropped == n - 5
    assert len(warnings) == 1 and warnings[0].startswith("live tracking falls behind the streams: input dropped")
    assert tracker.report()["dropped"] == n - 5


@pytest.mark.parametrize("n", [2, 50])
def test_a_client_that_does_not_read_loses_lines_and_delays_nothing(n):
    server = PoseStreamServer("127.0.0.1", 0, queue_max=1)
    server.start()
    try:
        async def idle_client(ready, done) -> None:
            async with aiohttp.ClientSession() as s, s.ws_connect(server.url):
                ready.set()
                await asyncio.get_running_loop().run_in_executor(None, done.wait)

        import threading
        ready, done = threading.Event(), threading.Event()
        t = threading.Thread(target=asyncio.run, args=(idle_client(ready, done),), daemon=True)
        t.start()
        wait_until(lambda: ready.is_set() and server.clients, what="the idle client to connect")
        server.send([f"line {i}" for i in range(n)])   # one call: the queue takes 1, the rest is dropped at once
        wait_until(lambda: server.dropped == n - 1, what="the lines beyond the client's queue to be dropped")
        done.set()
        t.join(DEADLINE_S)
    finally:
        server.stop()
    assert f"{n - 1} line(s) dropped for slow clients" in server.summary()[0]
