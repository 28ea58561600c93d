"""Hostile session files: times beyond what phonepose reads, length fields that lie, garbage that looks like
records, record kinds recover must keep, and a FIFO where a session goes. Each class generates its cases;
every command answers in one line and its exit code, at once.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.writer import Writer
from test_reliability_cli import rewrite

from phonepose.schemas.topics import Topic
from phonepose.session import SessionReader, codec
from phonepose.testing.playback_session import write_test_session

INT64_MAX = (1 << 63) - 1


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("hostile") / "good.mcap"
    write_test_session(path, duration_s=2.0)
    return path


@contextlib.contextmanager
def deadline(seconds: int):
    """A command that blocks (a FIFO opened by mistake) fails the test instead of hanging it."""
    def expired(signum, frame):
        raise TimeoutError(f"no answer within {seconds} s")
    old = signal.signal(signal.SIGALRM, expired)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("phonepose: error: ") and "a bug in phonepose" not in err, err
    return lines[0]


# ----------------------------------------------------------------------------- times
@settings(max_examples=300, deadline=None, derandomize=True)
@given(seconds=st.integers(-(1 << 63), (1 << 63) - 1), nanos=st.integers(-(1 << 31), (1 << 31) - 1))
def test_a_stamp_is_read_exactly_when_it_is_an_int64_of_nanoseconds(seconds, nanos):
    from google.protobuf.timestamp_pb2 import Timestamp
    ns = seconds * 10**9 + nanos
    ok = 0 <= nanos < 10**9 and -(1 << 63) <= ns <= INT64_MAX
    ts = Timestamp(seconds=seconds, nanos=nanos)
    assert (codec.time_problem(seconds, nanos) is None) == ok
    if ok:
        assert codec.timestamp_ns(ts) == ns
        back = Timestamp()
        back.FromNanoseconds(ns)
        assert (back.seconds, back.nanos) == (seconds, nanos)
    else:
        with pytest.raises(ValueError, match=f"seconds={seconds} nanos={nanos}"):
            codec.timestamp_ns(ts)


# (seconds, nanos) just outside the range on each side, protobuf's own limits, and nanos out of [0, 1e9)
BAD_STAMPS = [(INT64_MAX // 10**9 + 1, 0), (INT64_MAX // 10**9, INT64_MAX % 10**9 + 1), (-(1 << 63) // 10**9 - 1, 0),
              (253402300800, 0), (-62135596801, 0), (10**15, 0), (1_700_000_000, -1), (1_700_000_000, 10**9)]
# the topics every command among playback, calibrate-gt and calibrate-hand-eye reads, and the task window
STAMPED = [Topic.CONTROLLER_VIO_POSE, Topic.GT_CONTROLLER_POSE, Topic.CONTROLLER_IMU, Topic.CAMERA_IMAGE,
           Topic.SESSION_INFO]


def _with_stamp(good: Path, dst: Path, topic: str, field: str, seconds: int, nanos: int) -> Path:
    def fn(t, msg, lt):
        if t == topic:
            ts = getattr(msg, field)
            ts.seconds, ts.nanos = seconds, nanos
        return [(t, msg, lt)]
    return rewrite(good, dst, fn)


@pytest.mark.parametrize("k", range(len(BAD_STAMPS)))
def test_a_stamp_outside_the_times_read_is_one_line_naming_file_topic_and_value(good, tmp_path, cli, k):
    seconds, nanos = BAD_STAMPS[k]
    topic = STAMPED[k % len(STAMPED)]
    field = ("task_start", "task_end", "timestamp")[k % 3] if topic == Topic.SESSION_INFO else "timestamp"
    path = _with_stamp(good, tmp_path / "s.mcap", topic, field, seconds, nanos)
    expected = rf"s\.mcap: topic {re.escape(topic)}: the message at log time \d+ has {field} seconds={seconds} " \
               rf"nanos={nanos}: "
    code, _, err = cli("playback", path, "-q", "-t", "T1", "-o", tmp_path / "o")
    assert code == 4 and re.search(expected, one_error_line(err)), err
    assert not (tmp_path / "o").exists()
    for argv in (["info", path], ["calibrate-gt", path, "-o", tmp_path / "gt.yaml"],
                 ["calibrate-hand-eye", path, "-o", tmp_path / "he.yaml"]):
        code, _, err = cli(*argv)
        if code != 0:       # a command that reads this topic: the same line; one that does not: its own answer
            line = one_error_line(err)
            assert code != 1 and (code != 4 or re.search(expected, line) or "phone turned" in line), err


def _with_log_time(good: Path, dst: Path, topic: str, log_time: int, every: int) -> Path:
    """The session with every ``every``-th message of ``topic`` at ``log_time`` (raw mcap: uint64)."""
    with SessionReader(good) as r, open(dst, "wb") as f:
        w = Writer(f)
        w.start()
        cids: dict[str, int] = {}
        for i, (schema, ch, m) in enumerate(r.raw_messages()):
            if ch.topic not in cids:
                cids[ch.topic] = w.register_channel(ch.topic, ch.message_encoding,
                                                    w.register_schema(schema.name, schema.encoding, schema.data))
            w.add_message(cids[ch.topic], log_time if ch.topic == topic and i % every == 0 else m.log_time, m.data,
                          m.publish_time, m.sequence)
        w.finish()
    return dst


@pytest.mark.parametrize("log_time", [INT64_MAX + 1, INT64_MAX + 12345, (1 << 64) - 1])
@pytest.mark.parametrize("topic,every", [(Topic.CONTROLLER_IMU, 7), (Topic.SESSION_INFO, 1)])
def test_a_log_time_beyond_int64_is_one_line_in_every_command(good, tmp_path, cli, log_time, topic, every):
    path = _with_log_time(good, tmp_path / "s.mcap", topic, log_time, every)
    expected = f"s.mcap: topic {topic}: log time {log_time} is outside the times phonepose reads"
    for argv in (["info", path], ["playback", path, "-q", "-t", "T1", "-o", tmp_path / "o"],
                 ["calibrate-gt", path, "-o", tmp_path / "gt.yaml"],
                 ["calibrate-hand-eye", path, "-o", tmp_path / "he.yaml"]):
        code, _, err = cli(*argv)
        assert code == 4 and expected in one_error_line(err), (argv, err)
    assert not any(p.name != "s.mcap" for p in tmp_path.iterdir())


# ----------------------------------------------------------------------------- a FIFO as an input
# Every command that reads a path the user gives, with a FIFO there; {fifo} is the FIFO, {good} a valid session.
# Commands not listed take no input path (board, marker, demo: their outputs are checked elsewhere).
FIFO_INPUTS = {
    "info": [["info", "{fifo}"]],
    "playback": [["playback", "{fifo}", "-q", "-o", "{d}/o"],
                 ["playback", "{good}", "-q", "--hand-eye", "{fifo}", "-o", "{d}/o"],
                 ["playback", "{good}", "-q", "--gt", "{fifo}", "-o", "{d}/o"]],
    "evaluate": [["evaluate", "--gt", "{fifo}", "--est", "{tum}"], ["evaluate", "--gt", "{tum}", "--est", "{fifo}"],
                 ["evaluate", "--gt", "{tum}", "--est", "{tum}", "--hand-eye", "{fifo}"],
                 ["evaluate", "--gt", "{tum}", "--est", "{tum}", "--metric", "paper", "--in-view", "{fifo}"]],
    "recover": [["recover", "{fifo}", "-o", "{d}/r.mcap"]],
    "calibrate-camera": [["calibrate-camera", "-q", "--video", "{fifo}", "-o", "{d}/c.yaml"]],
    "calibrate-hand-eye": [["calibrate-hand-eye", "{fifo}", "-o", "{d}/he.yaml"]],
    "calibrate-gt": [["calibrate-gt", "{fifo}", "-o", "{d}/gt.yaml"],
                     ["calibrate-gt", "{good}", "--gt", "{fifo}", "-o", "{d}/gt.yaml"]],
    "batch": [["batch", "{fifo}", "-t", "T1", "-q", "--workers", "1", "-o", "{d}/r.parquet"]],
    "record sim": [["record", "sim", "-q", "--config", "{fifo}", "-o", "{d}/s.mcap"],
                   ["record", "sim", "-q", "--motion", "{fifo}", "-o", "{d}/s.mcap"]],
    "record rehearse": [["record", "rehearse", "--config", "{fifo}", "-o", "{d}/reh"],
                        ["record", "rehearse", "--iwer", "{fifo}", "-o", "{d}/reh"]],
    "record live": [["record", "live", "--calibration", "{fifo}", "-o", "{d}/l.mcap", "--duration", "1"],
                    ["record", "live", "--camera", "{fifo}", "--calibration", "{fifo}", "-o", "{d}/l.mcap"]],
    "experiment exp1": [["experiment", "exp1", "-q", "--config", "{fifo}", "-o", "{d}/e1"]],
    "experiment exp2": [["experiment", "exp2", "--config", "{fifo}", "-o", "{d}/e2"]],
}
NO_INPUT_PATH = {"board", "marker", "demo"}
FIFO_CASES = [(name, k) for name, argvs in FIFO_INPUTS.items() for k in range(len(argvs))]


def _leaf_commands() -> set[str]:
    from phonepose.cli import command

    def walk(cmd, prefix):
        subs = getattr(cmd, "commands", None)
        if not subs:
            return {" ".join(prefix)}
        return set().union(*(walk(c, [*prefix, n]) for n, c in subs.items()))
    return walk(command(), [])


def test_the_fifo_cases_cover_every_command():
    assert set(FIFO_INPUTS) | NO_INPUT_PATH == _leaf_commands()


@pytest.mark.skipif(sys.platform == "win32", reason="no FIFOs on Windows")
@pytest.mark.parametrize("name,k", FIFO_CASES, ids=[f"{n}-{k}" for n, k in FIFO_CASES])
def test_every_command_refuses_a_fifo_as_an_input_at_once(good, tmp_path, cli, name, k):
    fifo = tmp_path / "in.fifo"
    os.mkfifo(fifo)
    tum = tmp_path / "t.tum"
    tum.write_text("".join(f"{i / 10:.1f} {i / 100:.2f} 0 0 0 0 0 1\n" for i in range(20)))
    argv = [a.format(fifo=fifo, good=good, d=tmp_path, tum=tum) for a in FIFO_INPUTS[name][k]]
    with deadline(120):
        code, _, err = cli(*argv)
    line = one_error_line(err)
    assert code in (2, 5) and "in.fifo" in line and "not a regular file" in line, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.fifo", "t.tum"]


# ----------------------------------------------------------------------------- recover's resynchronisation
GARBAGE = {"opcode 0x06 bytes": b"\x06", "0x06 and a zero length": b"\x06" + bytes(8),
           "0x06 and a length that fits": b"\x06" + (40).to_bytes(8, "little") + bytes(40)}   # an empty chunk: valid


@pytest.mark.parametrize("pattern", list(GARBAGE), ids=list(GARBAGE))
def test_recover_reads_garbage_that_looks_like_records_in_linear_work(good, tmp_path, monkeypatch, pattern):
    """A valid prefix, then garbage of 1, 4 and 16 MiB made of record starts: recover reads each byte a bounded
    number of times and tries at most one candidate record a start, whatever the size."""
    from phonepose.session import recover as R
    prefix = good.read_bytes()                  # a whole valid session, then the garbage
    with SessionReader(good) as r:
        messages = r.summary().message_count
    read, tried = [0], [0]
    pread, plausible = os.pread, R._Salvager._plausible_chunk_at

    def counting_pread(fd, n, off):
        data = pread(fd, n, off)
        read[0] += len(data)
        return data

    def counting_plausible(self, pos):
        tried[0] += 1
        return plausible(self, pos)
    monkeypatch.setattr(R.os, "pread", counting_pread)
    monkeypatch.setattr(R._Salvager, "_plausible_chunk_at", counting_plausible)
    for mib in (1, 4, 16):
        unit = GARBAGE[pattern]
        path = tmp_path / f"g{mib}.mcap"
        path.write_bytes(prefix + unit * ((mib << 20) // len(unit)))
        read[0] = tried[0] = 0
        with deadline(600):
            report = R.salvage(path, tmp_path / f"o{mib}.mcap")
        size = path.stat().st_size
        assert read[0] <= 4 * size + (4 << 20), (mib, read[0])
        assert tried[0] <= (mib << 20) // len(unit) + 1, (mib, tried[0])
        assert report.messages == messages    # every message of the session, none made of the garbage
