"""Hostile session files: times beyond what phonepose reads, length fields that lie, garbage that looks like
records, record kinds recover must keep, and a FIFO where a session goes. Each class generates its cases;
every command answers in one line and its exit code, at once.
"""

from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path

import pytest
from conftest import deadline
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
                 ["playback", "{good}", "-q", "--gt-calibration", "{fifo}", "-o", "{d}/o"],
                 ["playback", "{good}", "-q", "--gt", "{fifo}", "-o", "{d}/o"]],
    "evaluate": [["evaluate", "--gt", "{fifo}", "--est", "{tum}"], ["evaluate", "--gt", "{tum}", "--est", "{fifo}"],
                 ["evaluate", "--gt", "{tum}", "--est", "{tum}", "--gt-calibration", "{fifo}"],
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


# ----------------------------------------------------------------------------- length fields that lie
# MCAP opcodes: the kinds a data section may hold, those phonepose reads into memory, and one of another tool's own.
OPS = {"Header": 0x01, "Footer": 0x02, "Schema": 0x03, "Channel": 0x04, "Message": 0x05, "Chunk": 0x06,
       "MessageIndex": 0x07, "ChunkIndex": 0x08, "Attachment": 0x09, "AttachmentIndex": 0x0A, "Statistics": 0x0B,
       "Metadata": 0x0C, "MetadataIndex": 0x0D, "SummaryOffset": 0x0E, "DataEnd": 0x0F, "user": 0x80}
READ = {"Schema", "Channel", "Message", "Chunk"}             # read into memory by info and playback
SKIPPED = {"MessageIndex", "Attachment", "Metadata", "user"}  # valid in a data section, not read by info


def _data_records(path: Path) -> list[bytes]:
    """The records of a file's data section, Header first, up to (without) its Data End record."""
    data = path.read_bytes()
    out, pos = [], 8
    while data[pos] != 0x0F:
        end = pos + 9 + int.from_bytes(data[pos + 1:pos + 9], "little")
        out.append(data[pos:end])
        pos = end
    return out


def _tail() -> bytes:
    """A Data End record (no CRC), a footer without a summary section, and the closing magic."""
    return (b"\x0f" + (4).to_bytes(8, "little") + bytes(4) + b"\x02" + (20).to_bytes(8, "little") + bytes(20)
            + b"\x89MCAP0\r\n")


def _with_record(good: Path, dst: Path, op: int, claim: int, body: bytes = b"", hole: int = 0) -> int:
    """``good`` without its summary, a record of opcode ``op`` claiming ``claim`` bytes after its first chunk:
    ``body``, then ``hole`` bytes never written (sparse). Returns the record's offset."""
    records = _data_records(good)
    k = next(i for i, r in enumerate(records) if r[0] == 0x06) + 1
    head = b"\x89MCAP0\r\n" + b"".join(records[:k])
    with open(dst, "wb") as f:
        f.write(head + bytes([op]) + claim.to_bytes(8, "little") + body)
        f.seek(hole, os.SEEK_CUR)
        f.write(b"".join(records[k:]) + _tail())
    return len(head)


def _expected(kind: str, at: int, claim: int, fits: bool) -> tuple[int, str | None]:
    """info's exit code and line for a record of ``kind`` at ``at`` claiming ``claim`` bytes."""
    if not fits:
        return 3, f"the record at byte {at} runs past the end of the data"
    if kind not in READ | SKIPPED:
        return 3, f"the data at byte {at} is not an MCAP record"
    if kind in SKIPPED:
        return 0, None
    return 3, f"the record at byte {at} claims {claim} bytes, more than the 65 MiB any record phonepose reads holds"


def _messages(path: Path) -> int:
    with SessionReader(path) as r:
        return r.summary().message_count


@pytest.mark.parametrize("kind", list(OPS))
def test_a_length_beyond_the_file_is_one_line_and_recover_keeps_every_chunk(good, tmp_path, cli, kind):
    """Each record kind claiming from one byte more than the file holds to 2^64-1: info is one line naming the
    record (or reads past a kind it skips), recover keeps every chunk around it."""
    from phonepose.session.recover import salvage
    ref = tmp_path / "ref.mcap"
    at = _with_record(good, ref, OPS[kind], 0)
    left = ref.stat().st_size - at - 9
    for claim in (left + 1, left + 2**20, 1 << 32, 1 << 63, (1 << 64) - 1):
        path = tmp_path / f"{kind}.mcap"
        _with_record(good, path, OPS[kind], claim)
        code, _, err = cli("info", path)
        want, line = _expected(kind, at, claim, fits=False)
        assert code == want and line in one_error_line(err), (claim, err)
        report = salvage(path, tmp_path / "r.mcap")
        assert report.messages == _messages(good) and report.bytes_unreadable > 0, claim


def _run_limited(argv: list, limit: int):
    """``phonepose ARGV`` in its own process whose address space is at most ``limit`` bytes."""
    import resource
    import subprocess

    def cap():
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    return subprocess.run([sys.executable, "-m", "phonepose", *map(str, argv)], capture_output=True, text=True,
                          preexec_fn=cap, timeout=600)


SPARSE_KINDS = sorted(READ | SKIPPED)


@pytest.mark.slow
@pytest.mark.skipif(sys.platform == "win32", reason="RLIMIT_AS and sparse files are POSIX")
@pytest.mark.parametrize("kind", SPARSE_KINDS)
def test_a_length_of_gigabytes_in_a_sparse_file_is_never_read(good, tmp_path, kind):
    """A record claiming from just over MAX_RECORD_BYTES to 4 GiB, all of it in the file (a sparse hole): info,
    playback and recover run in 1.5 GiB of address space (what they need is under 1 GiB) and answer as for a
    small file: one line naming the claim, or the record skipped; recover keeps every chunk."""
    from phonepose.session.index import MAX_RECORD_BYTES
    limit = 3 << 29
    for claim in (MAX_RECORD_BYTES + 1, (1 << 32) + 1):
        path = tmp_path / f"{kind}.mcap"
        at = _with_record(good, path, OPS[kind], claim, hole=claim)
        assert path.stat().st_size > claim
        want, line = _expected(kind, at, claim, fits=True)
        r = _run_limited(["info", path], limit)
        assert r.returncode == want, (claim, r.stderr)
        if line is None:
            assert r.stderr == "" and f"{_messages(good)}" in r.stdout, r.stdout
        else:
            assert line in one_error_line(r.stderr), r.stderr
            r = _run_limited(["playback", path, "-q", "-t", "T1", "-o", tmp_path / "o"], limit)
            assert r.returncode == 3 and line in one_error_line(r.stderr) and not (tmp_path / "o").exists()
        r = _run_limited(["recover", path, "-o", tmp_path / "r.mcap", "--force", "--json"], limit)
        assert r.returncode == 0 and r.stderr == "", r.stderr
        report = json.loads(r.stdout)
        assert report["messages"] == _messages(good) and report["bytes_unreadable"] >= claim, report


# (field, offset in a chunk record's body, width): the counts inside a chunk record
CHUNK_COUNTS = {"compression length": (28, 4), "records length": (36, 8)}


@pytest.mark.parametrize("field", list(CHUNK_COUNTS))
def test_a_count_inside_a_chunk_beyond_its_record_is_damage_to_that_chunk_only(good, tmp_path, cli, field):
    """A chunk's compression-string length or compressed-data length claiming from one byte more than its record
    to the field's maximum: info names that chunk, recover loses exactly its messages."""
    from phonepose.session.recover import salvage
    records = _data_records(good)
    chunks = [i for i, r in enumerate(records) if r[0] == 0x06]
    k = chunks[len(chunks) // 2]
    at = 8 + sum(len(r) for r in records[:k])
    off, width = CHUNK_COUNTS[field]
    body = len(records[k]) - 9
    with SessionReader(good) as r:
        lost = len(r._chunk_messages(r.index.chunks[chunks.index(k)], None, None, None))
    for claim in (body + 1, body + 2**20, (1 << 8 * width) - 1):
        rec = bytearray(records[k])
        rec[9 + off:9 + off + width] = claim.to_bytes(width, "little")
        path = tmp_path / "c.mcap"
        path.write_bytes(b"\x89MCAP0\r\n" + b"".join(records[:k]) + rec + b"".join(records[k + 1:]) + _tail())
        code, _, err = cli("info", path)
        assert code == 3 and f"the chunk at byte {at} " in one_error_line(err), (claim, err)
        report = salvage(path, tmp_path / "r.mcap")
        assert report.messages == _messages(good) - lost and report.chunks_skipped == 1, claim
