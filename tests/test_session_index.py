"""The summary section is data to verify: its CRC, its claims against the chunks, and a fallback.

Every byte of a small session's summary section (summary records, summary offsets, footer) is
flipped once; each time the reader must either refuse the file (DamagedFileError, exit 3) or read
exactly what it reads from the undamaged file, within a time bound. The three flips the red team
found (a Statistics end time, a Channel's topic, a Statistics start time) are also played back end
to end. Files a writer made without Statistics, without channels in the summary, without a
summary, or without chunks are valid MCAP and read like any other.
"""

from __future__ import annotations

import logging
import os
import struct
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer

from phonepose.errors import DamagedFileError
from phonepose.session import SessionReader
from phonepose.session.index import MAX_CHUNK_BYTES, main_span
from phonepose.testing.playback_session import write_test_session

FLIP_BOUND_S = 5.0      # one open of a 20-50 KB file; ~3 ms on a quiet machine


def _footer(data: bytes) -> tuple[int, int, int]:
    _, _, start, offsets, crc = struct.unpack_from("<BQQQI", data, len(data) - 8 - 29)
    return start, offsets, crc


def _schema_data_ranges(data: bytes) -> list[range]:
    """The descriptor bytes of each Schema record in the summary (flipping them all says little more
    than flipping a sample: the CRC is what catches them)."""
    start, offsets, _ = _footer(data)
    end = offsets or len(data) - 8 - 29
    out, p = [], start
    while p < end:
        op, length = struct.unpack_from("<BQ", data, p)
        if op == 0x03:
            q = p + 9 + 2
            for _ in range(2):          # name, encoding
                q += 4 + struct.unpack_from("<I", data, q)[0]
            out.append(range(q + 4, p + 9 + length))
        p += 9 + length
    return out


def _what_is_read(path: Path):
    """Everything a command reads through the index: summary, channels, schemas, chunk locations.
    The messages follow from these and the (undamaged) data section."""
    with SessionReader(path) as r:
        s = r.summary()
        ix = r.index
        chunks = [(c.chunk_start_offset, c.chunk_length, c.message_start_time, c.message_end_time,
                   sorted(c.message_index_offsets)) for c in ix.chunks]
        return ([(c.topic, c.schema, c.encoding, c.count) for c in s.channels], s.start_ns, s.end_ns,
                s.message_count, {k: (v.name, v.encoding, v.data) for k, v in ix.schemas.items()},
                {k: (v.topic, v.schema_id, v.message_encoding, v.metadata) for k, v in ix.channels.items()}, chunks)


def _flip_all(path: Path, positions) -> tuple[int, int, float]:
    """Flip one bit of each byte at ``positions`` in turn (restoring it after); (refused, identical, slowest s)."""
    data = path.read_bytes()
    ref = _what_is_read(path)
    refused = identical = 0
    slowest = 0.0
    fd = os.open(path, os.O_RDWR)
    logging.disable(logging.WARNING)     # the fallback's warning line, once per flip
    try:
        for i in positions:
            os.pwrite(fd, bytes([data[i] ^ (1 << (i % 8))]), i)
            t0 = time.perf_counter()
            try:
                got = _what_is_read(path)
            except DamagedFileError:
                refused += 1
            else:
                assert got == ref, f"flipping a bit of byte {i} changed what is read"
                identical += 1
            slowest = max(slowest, time.perf_counter() - t0)
            os.pwrite(fd, data[i:i + 1], i)
    finally:
        logging.disable(logging.NOTSET)
        os.close(fd)
    assert path.read_bytes() == data
    return refused, identical, slowest


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("index") / "s.mcap"
    write_test_session(p, duration_s=1.0, camera=False, imu=False)
    return p


def test_every_byte_of_the_summary_flipped_is_refused_or_read_as_undamaged(small):
    """Every byte outside the schemas' descriptors, and every 16th inside them (the slow test does all)."""
    data = small.read_bytes()
    start = _footer(data)[0]
    descriptors = set()
    for r in _schema_data_ranges(data):
        descriptors.update(i for i in r if (i - r.start) % 16)
    positions = [i for i in range(start, len(data) - 8) if i not in descriptors]
    refused, identical, slowest = _flip_all(small, positions)
    assert refused + identical == len(positions) > 1000
    # only the footer's own opcode and length make the file unreadable: everything else falls back
    assert refused == 9
    assert slowest < FLIP_BOUND_S


@pytest.mark.slow
@pytest.mark.long
def test_every_byte_of_a_whole_sessions_summary_flipped(tmp_path):
    """Every topic, schema and chunk of a session; low rates (77 messages, not 262): the summary is the same
    14630 bytes, and the data-section scan that each flip falls back to costs 2.5x less."""
    p = tmp_path / "s.mcap"
    write_test_session(p, duration_s=1.0, camera_hz=10.0, imu_hz=25.0, vio_hz=10.0, gt_hz=10.0)
    data = p.read_bytes()
    positions = range(_footer(data)[0], len(data) - 8)
    refused, identical, slowest = _flip_all(p, positions)
    assert refused == 9 and identical == len(positions) - 9
    assert slowest < FLIP_BOUND_S


def _statistics_offset(data: bytes) -> int:
    start, offsets, _ = _footer(data)
    p = start
    while True:
        op, length = struct.unpack_from("<BQ", data, p)
        if op == 0x0B:
            return p + 9
        p += 9 + length


def _playback(cli, session: Path, out: Path, *extra) -> int:
    return cli("playback", session, "-q", "-t", "T1", "--out", out, *extra).returncode


def _flipped(src: Path, dst: Path, at: int, bit: int) -> Path:
    b = bytearray(src.read_bytes())
    b[at] ^= 1 << bit
    dst.parent.mkdir(exist_ok=True)
    dst.write_bytes(bytes(b))
    return dst


@pytest.mark.parametrize("what", ["statistics end time", "gt calibration topic", "statistics start time"])
def test_the_red_teams_summary_flips_play_back_like_the_undamaged_file(small, tmp_path, cli, caplog, what):
    """A flipped Statistics end time ran forever; a flipped topic dropped /gt/calibration (exit 0, other
    metrics); a flipped start time shifted --start/--end. Now: one warning line, the undamaged outputs."""
    data = small.read_bytes()
    if what == "statistics end time":
        at, bit = _statistics_offset(data) + 8 + 2 + 4 * 4 + 8 + 7, 6      # the top byte: ~2^62 ns later
    elif what == "statistics start time":
        at, bit = _statistics_offset(data) + 8 + 2 + 4 * 4, 4
    else:
        at, bit = data.rindex(b"/gt/calibration") + 1, 0                   # the summary's copy: /ft/...
        assert at > _footer(data)[0]
    bad = _flipped(small, tmp_path / "bad" / small.name, at, bit)
    code = _playback(cli, small, tmp_path / "clean", "--start", "0.1", "--end", "0.9")
    assert code == 0
    with caplog.at_level(logging.WARNING, logger="phonepose"):
        code = _playback(cli, bad, tmp_path / "damaged", "--start", "0.1", "--end", "0.9")
    assert code == 0
    warnings = [r.getMessage() for r in caplog.records if "summary section" in r.getMessage()]
    assert len(warnings) == 1 and warnings[0].startswith(
        f"{bad}: the summary section is damaged (CRC ")
    assert warnings[0].endswith("); read the data section instead (`phonepose recover` writes a file with a good "
                                "summary)")
    for f in sorted((tmp_path / "clean").rglob("*")):
        if f.is_file() and f.name != ".phonepose-output":
            assert (tmp_path / "damaged" / f.relative_to(tmp_path / "clean")).read_bytes() == f.read_bytes(), f


def _rewrite(src: Path, dst: Path, **writer_options) -> Path:
    """The same messages through mcap's Writer with other (valid) options."""
    with open(src, "rb") as f, open(dst, "wb") as g:
        w = Writer(g, **writer_options)
        w.start()
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, m in make_reader(f).iter_messages(log_time_order=False):
            if channel.id not in channels:
                if schema.id not in schemas:
                    schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
                channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                          schemas[schema.id], channel.metadata)
            w.add_message(channels[channel.id], m.log_time, m.data, m.publish_time, m.sequence)
        w.finish()
    return dst


@pytest.mark.parametrize("options", [
    {"use_statistics": False},
    {"repeat_channels": False, "repeat_schemas": False},
    {"use_statistics": False, "repeat_channels": False, "repeat_schemas": False, "index_types": IndexType.NONE,
     "use_summary_offsets": False},
    {"use_chunking": False},
    {"enable_crcs": False},
    {"chunk_size": 4096},
    {"chunk_size": 1},
    {"compression": CompressionType.LZ4},
    {"compression": CompressionType.NONE},
], ids=["no-statistics", "no-repeated-channels", "no-summary-records", "unchunked", "no-crcs", "small-chunks",
        "one-chunk-per-message", "lz4", "uncompressed"])
def test_valid_files_without_parts_of_the_summary_read_like_the_full_one(small, tmp_path, options, caplog):
    """Once "empty session" and "damaged (KeyError)": these are valid MCAP, read without a warning."""
    other = _rewrite(small, tmp_path / "o.mcap", **options)
    with SessionReader(small) as a, caplog.at_level(logging.WARNING, logger="phonepose"):
        with SessionReader(other) as b:
            assert b.summary().channels == a.summary().channels
            assert (b.summary().start_ns, b.summary().end_ns) == (a.summary().start_ns, a.summary().end_ns)
            keys = [(m.topic, m.log_time_ns, m.sequence, m.msg) for m in b.messages()]
            assert keys == [(m.topic, m.log_time_ns, m.sequence, m.msg) for m in a.messages()]
            assert b.verify(deep=True) == len(b.index.chunks)
            _assert_times(b.log_times(), _times_by_mcap(small))
    assert caplog.records == []


@pytest.mark.parametrize("options", [{"use_chunking": False}, {"chunk_size": 4096}], ids=["unchunked", "small-chunks"])
def test_messages_out_of_log_time_order_with_every_sequence_0_are_read_in_order(small, tmp_path, options):
    """Another writer's valid file: messages written newest first, each twice (two records of one channel with one
    log time, arriving 1 ns apart), every sequence 0 (MCAP leaves the sequence to the writer; many write 0).
    Overlapping chunks are merged on a heap, which compared two Message records on a tie of (log time, channel,
    sequence): a TypeError reported as "damaged MCAP file ... run phonepose recover"."""
    with open(small, "rb") as f:
        records = list(make_reader(f).iter_messages(log_time_order=True))
    p = tmp_path / "reversed.mcap"
    with open(p, "wb") as g:
        w = Writer(g, **options)
        w.start()
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, _m in records:
            if schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding, schemas[schema.id])
        for _schema, channel, m in reversed(records):
            for arrival in (m.publish_time, m.publish_time + 1):
                w.add_message(channels[channel.id], m.log_time, m.data, arrival, 0)
        w.finish()
    with SessionReader(small) as a, SessionReader(p) as b:
        expected = [(m.log_time_ns, m.topic, m.msg.SerializeToString()) for m in a.messages()]
        got = [(m.log_time_ns, m.topic, m.msg.SerializeToString()) for m in b.messages()]
        assert len(got) == 2 * len(expected) > 100
        assert [t for t, _, _ in got] == sorted(2 * [t for t, _, _ in expected])
        assert sorted(got) == sorted(2 * expected)
        assert b.verify(deep=True) == len(b.index.chunks)


def test_two_channels_on_a_topic_attachments_and_metadata_read_like_one_channel(small, tmp_path):
    """Other writers' valid files: each topic's messages split over two channels (a writer that registers a topic
    again, e.g. after a reconnect), and Attachment and Metadata records among them (Foxglove, rosbag2). The session
    reads exactly as the original: the same messages per topic, in the same order."""
    with open(small, "rb") as f:
        records = list(make_reader(f).iter_messages(log_time_order=True))
    p = tmp_path / "split.mcap"
    with open(p, "wb") as g:
        w = Writer(g, chunk_size=2048)
        w.start(profile="", library="another tool")
        w.add_metadata("rig", {"operator": "someone", "notes": "edited in Foxglove"})
        w.add_attachment(1, 1, "calibration.yaml", "text/yaml", b"k: 1\n")
        schemas: dict[int, int] = {}
        channels: dict[tuple[int, int], int] = {}
        for k, (schema, channel, m) in enumerate(records):
            if schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            key = (channel.id, k % 2)
            if key not in channels:
                channels[key] = w.register_channel(channel.topic, channel.message_encoding, schemas[schema.id])
            w.add_message(channels[key], m.log_time, m.data, m.publish_time, m.sequence)
        w.add_metadata("after", {"x": "y"})
        w.finish()
    with SessionReader(small) as a, SessionReader(p) as b:
        for topic in a.topics():
            expected = [(m.log_time_ns, m.msg) for m in a.messages([topic])]
            assert [(m.log_time_ns, m.msg) for m in b.messages([topic])] == expected, topic
        assert sum(c.count for c in b.summary().channels) == len(records)


def _times_by_mcap(path: Path) -> dict[str, list[int]]:
    """Every message's log time per topic, in file order, as mcap's own reader reads them."""
    out: dict[str, list[int]] = {}
    with open(path, "rb") as f:
        for _schema, channel, m in make_reader(f).iter_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append(m.log_time)
    return out


def _assert_times(got: dict, expected: dict[str, list[int]]) -> None:
    assert set(got) == set(expected)
    for topic, ts in expected.items():
        assert got[topic].dtype == np.uint64 and got[topic].tolist() == ts, topic


def test_log_times_from_the_message_indexes_equal_mcaps_reading(tmp_path):
    """The log times come from the Message Index records after each chunk (parsed as uint64 arrays,
    not through mcap's StreamReader); they equal every message's log time as mcap reads them. When a
    chunk's index records are damaged (they are outside the summary's CRC), its messages are read."""
    path = tmp_path / "s.mcap"
    write_test_session(path, duration_s=2.0, camera=False)
    chunked = _rewrite(path, tmp_path / "chunks.mcap", chunk_size=2048)   # several chunks, each with its indexes
    expected = _times_by_mcap(chunked)
    assert sum(map(len, expected.values())) > 100
    with SessionReader(chunked) as r:
        assert len(r.index.chunks) > 3
        _assert_times(r.log_times(), expected)
        first = r.index.chunks[0]
        at = min(first.message_index_offsets.values())
    data = bytearray(chunked.read_bytes())
    assert data[at] == 0x07                       # a Message Index record
    data[at + 1] ^= 0xFF                          # its length now runs past the chunk's index block
    damaged_index = tmp_path / "damaged-index.mcap"
    damaged_index.write_bytes(bytes(data))
    with SessionReader(damaged_index) as r:
        _assert_times(r.log_times(), expected)
    whole = chunked.read_bytes()                  # no summary at all: the times come from reading the data section
    start, _, _ = _footer(whole)
    no_summary = tmp_path / "no-summary.mcap"
    no_summary.write_bytes(whole[:start] + struct.pack("<BQQQI", 0x02, 20, 0, 0, 0) + whole[-8:])
    with SessionReader(no_summary) as r:
        assert not r.index.from_summary and r.index.times is not None
        assert all(ts.dtype == np.uint64 for ts in r.index.times.values())
        _assert_times(r.log_times(), expected)


@pytest.mark.parametrize("times, span", [
    ([5], (5, 5)),
    ([30, 10, 20], (10, 30)),
    ([10, 20, 20 + 3600 * 10**9 + 1], (10, 20)),                          # one message past the hour: an outlier
    ([1, 10, 20, 20 + 3600 * 10**9], (1, 20 + 3600 * 10**9)),                  # exactly an hour apart: one group
    ([10, 20, 2**64 - 1], (10, 20)),                                          # the largest log time MCAP holds
    ([0, 1, 3600 * 10**9 + 2, 3600 * 10**9 + 3], (0, 1)),                     # two of the same size: the first
    ([0, 1, 10**13, 10**13 + 1, 10**13 + 2], (10**13, 10**13 + 2)),       # the larger group wins
    ([], None),
])
def test_main_span_is_the_largest_group_of_messages_within_an_hour_of_each_other(times, span):
    assert main_span(np.array(times, dtype=np.uint64)) == span


def test_a_file_with_no_summary_section_at_all_is_read(small, tmp_path):
    """The footer says summary_start = 0: what a streaming writer may leave; the data section is read."""
    data = bytearray(small.read_bytes())
    start, _, _ = _footer(bytes(data))
    footer = struct.pack("<BQQQI", 0x02, 20, 0, 0, 0) + data[-8:]
    # the data section ends with the Data End record (13 bytes) before the summary
    body = bytes(data[:start]) + footer
    p = tmp_path / "nosummary.mcap"
    p.write_bytes(body)
    with SessionReader(small) as a, SessionReader(p) as b:
        assert not b.index.from_summary and b.index.problem is None
        assert b.summary().channels == a.summary().channels
        assert [m.data for _, _, m in b.raw_messages()] == [m.data for _, _, m in a.raw_messages()]


def test_a_chunk_claiming_a_gigabyte_is_refused_before_it_is_inflated(tmp_path):
    """A 33 KB file whose chunk inflates to 1 GiB: refused by its declared size, at once, one line."""
    import zstandard

    payload = zstandard.ZstdCompressor(level=1).compress(bytes(1 << 30))
    assert len(payload) < 64_000
    p = tmp_path / "bomb.mcap"
    with open(p, "wb") as f:
        w = Writer(f, compression=CompressionType_none())
        w.start()
        sid = w.register_schema("x", "", b"")
        cid = w.register_channel("/x", "", sid)
        w.add_message(cid, 1, b"a", 1)
        w.finish()
    data = bytearray(p.read_bytes())
    # rewrite the one chunk as a zstd chunk holding the bomb, and its index to match
    with SessionReader(p) as r:
        ci = r.index.chunks[0]
    head = struct.pack("<QQQI", ci.message_start_time, ci.message_end_time, 1 << 30, 0) + \
        struct.pack("<I", 4) + b"zstd" + struct.pack("<Q", len(payload)) + payload
    bomb = bytes(data[:ci.chunk_start_offset]) + struct.pack("<BQ", 0x06, len(head)) + head + b"\x0f" + \
        struct.pack("<QI", 4, 0)
    footer = struct.pack("<BQQQI", 0x02, 20, 0, 0, 0) + b"\x89MCAP0\r\n"
    p.write_bytes(bomb + footer)
    t0 = time.perf_counter()
    with pytest.raises(DamagedFileError) as err:
        SessionReader(p)
    assert time.perf_counter() - t0 < 2.0
    assert str(err.value) == (
        f"{p}: damaged MCAP file: the chunk at byte {ci.chunk_start_offset} (log time 0.00-0.00 s) "
        "claims 1073741824 bytes uncompressed, "
        f"more than the {MAX_CHUNK_BYTES >> 20} MiB any real chunk holds; run `phonepose recover {p} --out FIXED.mcap`")


def CompressionType_none():
    from mcap.writer import CompressionType

    return CompressionType.NONE


def test_info_and_verify_on_a_summary_flip(small, tmp_path, cli):
    """`info` prints what the data section holds, the same as for the undamaged file."""
    data = small.read_bytes()
    bad = _flipped(small, tmp_path / "b" / "s.mcap", _statistics_offset(data) + 3, 0)   # the message count
    outs = [cli("info", "--json", "--verify", f).stdout.replace(str(f), "S") for f in (small, bad)]
    assert outs[0] == outs[1] and '"messages": 128,\n' in outs[0]
