"""Playback's work is bounded by the data, not by the clock its timestamps claim.

One message with a far-future log time made playback plan ~3e11 ticks (and a batch with such a
session never finished). Now a message more than an hour away from the rest of the session is a
time outlier: skipped and reported (one warning line per topic, with the count), and the outputs
are those of the session without it. A long stretch without any message (a paused recording, a lost
chunk) gets no ticks beyond what the data before it supports.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import pytest
from test_reliability_cli import rewrite

from phonepose.playback.scheduler import TickScheduler
from phonepose.schemas.topics import Topic
from phonepose.session import SessionReader
from phonepose.session.context import read_context
from phonepose.testing.playback_session import write_test_session

HOUR_NS = 3600 * 10**9


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("bounded") / "s.mcap"
    write_test_session(p, duration_s=2.0, camera=False)
    return p


def _with_extra_vio(src: Path, dst: Path, *offsets_ns: int) -> Path:
    """A copy with the last controller VIO sample repeated at ``last + offset`` log times."""
    dst.parent.mkdir(exist_ok=True)
    with SessionReader(src) as r:
        *_, last = r.messages([Topic.CONTROLLER_VIO_POSE])
    msg, t = last.msg, last.log_time_ns
    done = False

    def add(topic, m, lt):
        nonlocal done
        out = [(topic, m, lt)]
        if topic == Topic.CONTROLLER_VIO_POSE and lt == t and not done:
            done = True
            for off in offsets_ns:
                extra = type(msg).FromString(msg.SerializeToString())
                extra.timestamp.FromNanoseconds(t + off)
                out.append((topic, extra, t + off))
        return out

    return rewrite(src, dst, add)


def _play(cli, session: Path, out: Path) -> int:
    return cli("playback", session, "-q", "-t", "T1,T2", "--out", out).returncode


def test_a_far_future_message_is_skipped_and_reported_and_changes_nothing(clean, tmp_path, cli, caplog):
    bad = _with_extra_vio(clean, tmp_path / "far" / "s.mcap", 9 * 10**18 - 1_700_000_010 * 10**9)  # year ~2255, within int64 ns
    assert _play(cli, clean, tmp_path / "clean") == 0
    t0 = time.perf_counter()
    with caplog.at_level(logging.WARNING, logger="phonepose"):
        code = _play(cli, bad, tmp_path / "bad")
    assert code == 0 and time.perf_counter() - t0 < 60
    assert [r.getMessage() for r in caplog.records] == [
        "/controller/vio/pose: 1 sample(s) skipped: log time more than an hour away from the "
        "rest of the session"]
    for f in sorted((tmp_path / "clean").rglob("*")):
        if f.is_file():
            assert (tmp_path / "bad" / f.relative_to(tmp_path / "clean")).read_bytes() == f.read_bytes(), f


def test_ticks_only_where_there_is_data(clean, tmp_path):
    """Two samples 1000 s and 2000 s after the session (inside the hour: data, not outliers): the
    ticks the data supports around them, not 40000 ticks of nothing."""
    bad = _with_extra_vio(clean, tmp_path / "gap.mcap", 1000 * 10**9, 2000 * 10**9)
    with SessionReader(clean) as r:
        n_clean = sum(1 for _ in TickScheduler(r, read_context(r)))
    with SessionReader(bad) as r:
        sched = TickScheduler(r, read_context(r))
        ticks = list(sched)
    hold = 0.5 * 20                     # MAX_GAP_S of held pose after each sample, at 20 Hz
    assert n_clean < len(ticks) <= n_clean + 2 * (hold + 2)
    assert sched.ticks_skipped > 39_000
    assert ticks[-1].T_cvio_controller is not None


def test_a_rate_of_a_billion_is_refused_before_any_work(clean, tmp_path, cli):
    code, _, err = cli("playback", clean, "-q", "--rate", "1e9", "--out", tmp_path / "o")
    assert code == 5 and err == "phonepose: error: --rate 1000000000: expected a finite number in [0.1, 1000] Hz\n"
    assert not (tmp_path / "o").exists()
