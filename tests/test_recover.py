"""``phonepose recover``: truncated and corrupted sessions salvaged into valid files.

A synthetic 6 s session (30 Hz ~40 KB JPEGs, 400 Hz IMU, 60 Hz VIO) written by SessionWriter
has ~1 MiB zstd chunks flushed at least every second of log time, so any damage must cost at
most about one second.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from mcap.reader import make_reader
from test_reliability_data import read_keys, write_session

from phonepose.errors import DamagedFileError, InputFileError, OutputError
from phonepose.session import SessionReader
from phonepose.session.recover import salvage

SECONDS = 6.0


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "s.mcap"
    write_session(path, SECONDS)
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    return path, path.read_bytes(), chunks, read_keys(path)


def _chunk_messages(path, ci) -> set:
    """(topic, log_time, sequence) of the messages in one chunk of the original file."""
    out = set()
    with open(path, "rb") as f:
        r = make_reader(f)
        s = r.get_summary()
        for _, ch, m in r.iter_messages(starting_at=ci.message_start_time, ending_before=ci.message_end_time + 1,
                                        log_time_order=False):
            out.add((ch.topic, m.log_time, m.sequence))
    del s
    return out


def _keys(keys):
    return {(t, lt, seq) for t, lt, seq, _ in keys}


# a chunk holds at most 1 s of log time plus the one message that crossed the flush boundary
MAX_CHUNK_S = 1.0 + 1 / 400


def test_session_has_several_chunks_of_at_most_a_second(session):
    _, _, chunks, keys = session
    assert len(chunks) >= 6
    for c in chunks:
        assert 0.9 <= (c.message_end_time - c.message_start_time) / 1e9 <= MAX_CHUNK_S
    assert len(keys) == 3300


def test_intact_file_is_copied_exactly(session, tmp_path):
    path, _, chunks, keys = session
    r = salvage(path, tmp_path / "fixed.mcap")
    assert not r.damaged and r.had_summary
    assert r.messages == 3300 and r.chunks_recovered == len(chunks) and r.chunks_skipped == 0
    assert r.messages_per_topic == {"/controller/imu": 2400, "/controller/vio/pose": 360,
                                    "/display/camera/image": 180, "/display/vio/pose": 360}
    assert read_keys(tmp_path / "fixed.mcap") == keys  # same topics, times, sequences, bytes


CUT_SEED = 7


def test_cut_at_10_random_offsets_loses_at_most_a_second(session, tmp_path):
    """A file cut anywhere keeps every chunk written completely before the cut, and nothing more is lost."""
    path, data, chunks, keys = session
    rng = np.random.default_rng(CUT_SEED)
    first_end = chunks[0].chunk_start_offset + chunks[0].chunk_length
    offsets = sorted(int(x) for x in rng.integers(first_end, len(data), 10))
    all_keys = _keys(keys)
    t_first = min(k[1] for k in all_keys)
    lost_s = []
    for off in offsets:
        cut = tmp_path / f"cut{off}.mcap"
        cut.write_bytes(data[:off])
        out = tmp_path / f"fixed{off}.mcap"
        r = salvage(cut, out)
        got = read_keys(out)
        complete = [c for c in chunks if c.chunk_start_offset + c.chunk_length <= off]
        expected = set().union(*(_chunk_messages(path, c) for c in complete)) if complete else set()
        assert _keys(got) == expected                                  # exactly the complete chunks
        assert {(t, lt, s, d) for t, lt, s, d in got} <= set(keys)     # bytes unchanged
        # what the file had started to hold at the cut, vs what came back
        started = [c for c in chunks if c.chunk_start_offset < off]
        t_written = max(c.message_end_time for c in started)
        t_recovered = max(k[1] for k in expected) if expected else t_first
        lost = (t_written - t_recovered) / 1e9
        lost_s.append(round(lost, 3))
        assert lost <= MAX_CHUNK_S + 1e-6, (off, lost)
        assert r.messages == len(expected) and not r.had_summary or off > chunks[-1].chunk_start_offset
        assert r.bytes_unreadable == off - (complete[-1].chunk_start_offset + complete[-1].chunk_length
                                            if complete else 8) - _index_bytes_after(data, complete, off)
    print("cut offsets", offsets, "seconds lost", lost_s)


def test_cut_inside_the_first_chunk_has_nothing_to_recover(session, tmp_path):
    """Cut before the first chunk is complete: under a second was recorded, and recover says nothing is left."""
    path, data, chunks, _ = session
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: chunks[0].chunk_length // 2])
    with pytest.raises(DamagedFileError, match="nothing recoverable"):
        salvage(cut, tmp_path / "fixed.mcap")
    assert (chunks[0].message_end_time - chunks[0].message_start_time) / 1e9 <= MAX_CHUNK_S


def _index_bytes_after(data, complete, off):
    """Bytes of whole message-index records between the last complete chunk and the cut (readable, not lost)."""
    import struct

    pos = complete[-1].chunk_start_offset + complete[-1].chunk_length if complete else 8
    n = 0
    while pos + 9 <= off and data[pos] == 0x07:
        length = struct.unpack_from("<Q", data, pos + 1)[0]
        if pos + 9 + length > off:
            break
        n += 9 + length
        pos += 9 + length
    return n


def _flip(data: bytes, positions) -> bytes:
    b = bytearray(data)
    for p in positions:
        b[p] ^= 0x5A
    return bytes(b)


@pytest.mark.parametrize("where", ["payload", "header", "opcode"])
def test_corrupt_middle_chunk_loses_only_that_chunk(session, tmp_path, where):
    """Damage inside chunk 3 (its compressed data, its length field, its opcode): the chunks after it come back."""
    path, data, chunks, keys = session
    c = chunks[2]
    pos = {"payload": [c.chunk_start_offset + c.chunk_length // 2 + k for k in range(0, 400, 40)],
           "header": [c.chunk_start_offset + 1 + 5],   # high bytes of the record length
           "opcode": [c.chunk_start_offset]}[where]
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(_flip(data, pos))
    r = salvage(bad, tmp_path / "fixed.mcap")
    lost = _chunk_messages(path, c)
    got = _keys(read_keys(tmp_path / "fixed.mcap"))
    assert got == _keys(keys) - lost
    assert r.messages == len(keys) - len(lost)
    assert r.had_summary                    # the summary at the end was read
    assert r.bytes_unreadable >= c.chunk_length
    assert len(r.lost) == 1 and r.lost[0].duration_s is not None
    assert r.lost[0].duration_s == pytest.approx((c.message_end_time - c.message_start_time) / 1e9, abs=0.01)
    assert r.chunks_skipped == (0 if where == "opcode" else 1)


def test_lost_first_chunk_channels_come_from_the_summary(session, tmp_path):
    """The first chunk holds the channel definitions; a finished file repeats them in its summary."""
    path, data, chunks, keys = session
    c = chunks[0]
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(_flip(data, [c.chunk_start_offset + 100]))
    r = salvage(bad, tmp_path / "fixed.mcap")
    assert r.orphan_messages == 0
    assert _keys(read_keys(tmp_path / "fixed.mcap")) == _keys(keys) - _chunk_messages(path, c)


def test_a_damaged_summary_never_renames_a_recovered_channel(session, tmp_path):
    """A flipped bit in a topic of the summary's Channel record: the summary fails its CRC; the chunks' own
    channel definitions win, and topics that only the damaged summary names (their chunk lost) are listed."""
    from phonepose.cli.recover import report_lines

    path, data, chunks, keys = session
    at = data.rindex(b"/controller/vio/pose") + 3          # the summary's copy: /cootroller/...
    assert at > chunks[-1].chunk_start_offset + chunks[-1].chunk_length
    r = salvage(_write(tmp_path / "t.mcap", _flip(data, [at])), tmp_path / "a.mcap")
    assert r.summary_damaged and r.channels_from_damaged_summary == []
    assert read_keys(tmp_path / "a.mcap") == keys          # every channel came from the chunks
    assert "  the summary section fails its CRC: not used, every channel is defined in the chunks" in report_lines(r)
    both = _flip(data, [at, chunks[0].chunk_start_offset + 100])
    r = salvage(_write(tmp_path / "u.mcap", both), tmp_path / "b.mcap")
    damaged_topic = bytes(_flip(b"/controller/vio/pose", [3])).decode("latin-1")
    assert r.summary_damaged and damaged_topic in r.channels_from_damaged_summary
    line = [x for x in report_lines(r) if "fails its CRC" in x][0]
    assert line.startswith("  the summary section fails its CRC; these topics are named only there (their chunk "
                           "was lost), check them: ")


def _write(p, data: bytes):
    p.write_bytes(data)
    return p


def test_lost_first_chunk_of_a_truncated_file_is_reported(session, tmp_path):
    """Without a summary the channel definitions die with the first chunk: said so, exit 3 if nothing is left."""
    path, data, chunks, _ = session
    c = chunks[0]
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(_flip(data[: chunks[3].chunk_start_offset], [c.chunk_start_offset + 100]))
    with pytest.raises(DamagedFileError, match="nothing recoverable"):
        salvage(bad, tmp_path / "fixed.mcap")
    assert not (tmp_path / "fixed.mcap").exists() and not (tmp_path / "fixed.mcap.partial").exists()


def test_garbage_before_and_inside_is_skipped(session, tmp_path):
    path, data, chunks, keys = session
    rng = np.random.default_rng(1)
    junk = rng.integers(0, 256, 5000, dtype=np.uint8).tobytes()
    c = chunks[4]
    bad = tmp_path / "bad.mcap"
    # lost magic and header; 5 KB of noise spliced into chunk 5
    bad.write_bytes(junk + data[20:c.chunk_start_offset + 1000] + junk + data[c.chunk_start_offset + 1000:])
    r = salvage(bad, tmp_path / "fixed.mcap")
    got = _keys(read_keys(tmp_path / "fixed.mcap"))
    assert got == _keys(keys) - _chunk_messages(path, c)
    assert r.chunks_skipped == 1


def test_recover_errors(session, tmp_path):
    path, data, _, _ = session
    with pytest.raises(InputFileError, match="no such file"):
        salvage(tmp_path / "missing.mcap", tmp_path / "o.mcap")
    with pytest.raises(InputFileError, match="is the input file"):
        salvage(path, path)
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(InputFileError, match="empty file"):
        salvage(empty, tmp_path / "o.mcap")
    noise = tmp_path / "noise.mcap"
    noise.write_bytes(np.random.default_rng(3).integers(0, 256, 100_000, dtype=np.uint8).tobytes())
    with pytest.raises(DamagedFileError, match="nothing recoverable"):
        salvage(noise, tmp_path / "o.mcap")
    with pytest.raises(OutputError, match="cannot write"):
        salvage(path, tmp_path / "no-such-dir" / "o.mcap")
    assert path.read_bytes() == data  # the input is never touched


def test_cli_recover_truncated(session, tmp_path, cli):
    path, data, chunks, _ = session
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: chunks[3].chunk_start_offset + 5000])
    r = cli("recover", str(cut), "--out", str(tmp_path / "fixed.mcap"))
    assert r.returncode == 0, r.stderr
    assert "/controller/imu" in r.stdout and "1204" in r.stdout  # IMU of chunks 1-3: 0 .. 3.0075 s at 400 Hz
    assert "lost: 1 damaged chunk(s)" in r.stdout and "ends before its footer" in r.stdout
    info = cli("info", str(tmp_path / "fixed.mcap"), "--json")
    assert info.returncode == 0, info.stderr
    topics = {c["topic"]: c["messages"] for c in json.loads(info.stdout)["channels"]}
    assert topics["/controller/imu"] == 1204 and topics["/display/camera/image"] == 91
    with SessionReader(tmp_path / "fixed.mcap") as reader:
        assert sum(1 for _ in reader.messages()) == 1204 + 91 + 181 + 181


def test_cli_recover_json_and_errors(session, tmp_path, cli):
    path, _, _, _ = session
    r = cli("recover", str(path), "--out", str(tmp_path / "fixed.mcap"), "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["messages"] == 3300 and rep["chunks_skipped"] == 0 and rep["time_lost_s"] == 0
    r = cli("recover", str(path), "--out", str(path))
    assert r.returncode == 2 and "writing it would destroy the input" in r.stderr and r.stderr.count("\n") == 1
    r = cli("recover", str(tmp_path / "nope.mcap"), "--out", str(tmp_path / "o.mcap"))
    assert r.returncode == 2 and "no such file" in r.stderr and "Traceback" not in r.stderr
    r = cli("recover", str(path), "--out", str(tmp_path / "nodir" / "o.mcap"))
    assert r.returncode == 6 and "does not exist" in r.stderr and "Traceback" not in r.stderr


def test_the_cli_writes_only_the_output_rules_temporary(session, tmp_path, cli, monkeypatch):
    """recover wrote the plan's temporary's content to a second one, TMP.partial, renamed over it at the end: a
    recover killed meanwhile (a SIGBUS from a file cut under it, SIGKILL) left a .partial that no later command
    clears. Now the one temporary, whose name the next command finds."""
    import phonepose.session.recover as recover
    from phonepose.files import TMP_SUFFIX

    seen: list[list[str]] = []
    finish = recover.Writer.finish

    def looking(self):
        seen.append(sorted(p.name for p in tmp_path.iterdir()))
        return finish(self)
    monkeypatch.setattr(recover.Writer, "finish", looking)
    path = session[0]
    r = cli("recover", path, "--out", tmp_path / "fixed.mcap")
    assert r.returncode == 0, r.stderr
    assert len(seen) == 1 and len(seen[0]) == 1 and seen[0][0].startswith(".fixed.mcap.") \
        and seen[0][0].endswith(TMP_SUFFIX), seen
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fixed.mcap"]


@pytest.mark.parametrize("when", ["scan", "write"])
def test_a_file_cut_while_recover_reads_it_is_one_line(session, tmp_path, cli, monkeypatch, when):
    """Another program cuts the file (a copy still going on, a rewrite) while recover reads it. recover read
    it through an mmap, and a read past the new end killed it with SIGBUS: exit 135, no line, two temporaries
    left. Now one line, exit 2, no output and no temporary."""
    import phonepose.session.recover as recover

    path, data, chunks, _ = session
    cut = tmp_path / "c.mcap"
    cut.write_bytes(data)
    original = recover._Salvager.parse_chunk
    calls = []
    at = 2 if when == "scan" else len(chunks) + 1     # the second chunk scanned, or the first one written

    def cutting(self, *args):
        calls.append(args)
        if len(calls) == at:       # the file shrinks to half under the reader
            os.truncate(cut, len(data) // 2)
        return original(self, *args)
    monkeypatch.setattr(recover._Salvager, "parse_chunk", cutting)
    r = cli("recover", cut, "--out", tmp_path / "fixed.mcap")
    assert (r.returncode, r.stderr) == (2, f"phonepose: error: {cut}: changed while recover read it ({len(data)} "
                                           f"bytes, now {len(data) // 2}): another program is writing or cutting "
                                           f"it; run recover again when it is done\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.mcap"]


# ----------------------------------------------------------------------------- every record kind kept
def _with_extras(src, dst, seed: int = 3):
    """``src``'s messages through mcap's Writer (profile "phonepose-test", chunks of ~64 KB) with Attachment and
    Metadata records among them: generated names, media types, times and contents (empty to 300 KB)."""
    rng = np.random.default_rng(seed)
    with open(src, "rb") as f:
        records = list(make_reader(f).iter_messages(log_time_order=False))
    extras = []
    with open(dst, "wb") as g:
        from mcap.writer import Writer
        w = Writer(g, chunk_size=64 << 10)
        w.start(profile="phonepose-test", library="a test")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        every = len(records) // 7
        for k, (schema, channel, m) in enumerate(records):
            if k % every == every // 2:
                n = len(extras)
                if n % 2:
                    meta = {f"key{i}": f"value {n} {i}" for i in range(n)}
                    w.add_metadata(f"meta{n}", meta)
                    extras.append(("metadata", f"meta{n}", meta))
                else:
                    data = rng.bytes(int(rng.integers(0, 300_000)) if n else 0)
                    w.add_attachment(m.log_time + 1, m.log_time, f"file{n}.bin", "application/octet-stream", data)
                    extras.append(("attachment", f"file{n}.bin", (m.log_time + 1, m.log_time, data)))
            if schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding, schemas[schema.id])
            w.add_message(channels[channel.id], m.log_time, m.data, m.publish_time, m.sequence)
        w.finish()
    return extras


def _extras_in(path) -> list:
    """The Attachment and Metadata records of a file as :func:`_with_extras` lists them, in file order."""
    with open(path, "rb") as f:
        from mcap.records import Attachment, Metadata
        from mcap.stream_reader import StreamReader
        out = []
        for r in StreamReader(f, skip_magic=False).records:
            if isinstance(r, Attachment):
                out.append(("attachment", r.name, (r.create_time, r.log_time, r.data)))
            elif isinstance(r, Metadata):
                out.append(("metadata", r.name, r.metadata))
    return out


def _record_spans(data: bytes) -> list[tuple[int, int, int]]:
    """(opcode, start, end) of every record of the data section."""
    out, pos = [], 8
    while data[pos] != 0x0F:
        end = pos + 9 + int.from_bytes(data[pos + 1:pos + 9], "little")
        out.append((data[pos], pos, end))
        pos = end
    return out


@pytest.fixture(scope="module")
def extras_session(session, tmp_path_factory):
    path = tmp_path_factory.mktemp("extras") / "x.mcap"
    extras = _with_extras(session[0], path)
    return path, path.read_bytes(), extras


def test_recover_keeps_every_attachment_metadata_record_schema_and_the_profile(extras_session, tmp_path):
    path, _, extras = extras_session
    assert _extras_in(path) == extras and {e[0] for e in extras} == {"attachment", "metadata"}
    r = salvage(path, tmp_path / "r.mcap")
    assert not r.damaged and (r.attachments, r.metadata_records) == (
        sum(e[0] == "attachment" for e in extras), sum(e[0] == "metadata" for e in extras))
    assert _extras_in(tmp_path / "r.mcap") == extras
    with open(tmp_path / "r.mcap", "rb") as f, open(path, "rb") as g:
        got, want = make_reader(f), make_reader(g)
        assert got.get_header().profile == "phonepose-test"
        assert ({s.name for s in got.get_summary().schemas.values()}
                == {s.name for s in want.get_summary().schemas.values()})


def _damage_places(data: bytes, seed: int = 11):
    """(name, damaged bytes, where): a flipped byte inside every chunk and inside every attachment's data (where:
    the attachment's offset), and the file cut at generated offsets after the first chunk (where: the cut)."""
    rng = np.random.default_rng(seed)
    spans = _record_spans(data)
    out = []
    for op, start, end in spans:
        if op in (0x06, 0x09) and end - start > 64:
            at = int(rng.integers(start + 50, end - 8))
            b = bytearray(data)
            b[at] ^= 0xFF
            out.append((f"flip-{op:#04x}-at-{at}", bytes(b), start if op == 0x09 else None))
    first_chunk_end = next(end for op, _, end in spans if op == 0x06)
    for at in sorted(int(x) for x in rng.integers(first_chunk_end, spans[-1][2], 6)):
        out.append((f"cut-at-{at}", data[:at], at))
    return out


def test_recover_keeps_every_attachment_and_metadata_record_damage_spares(extras_session, tmp_path):
    """Damage in generated places: a flipped byte in each chunk keeps every attachment and metadata record; one in
    an attachment loses that attachment alone (its CRC), reported as unreadable bytes; a cut keeps those whole
    before it."""
    path, data, extras = extras_session
    spans = {start: (op, end) for op, start, end in _record_spans(data)}
    order = [(s, e) for s, (op, e) in sorted(spans.items()) if op in (0x09, 0x0C)]
    assert len(order) == len(extras)
    for name, damaged, lost in _damage_places(data):
        src = tmp_path / "d.mcap"
        src.write_bytes(damaged)
        r = salvage(src, tmp_path / "r.mcap")
        if name.startswith("flip-0x09"):
            expected = [x for x, (s, _) in zip(extras, order, strict=True) if s != lost]
        elif name.startswith("cut"):
            expected = [x for x, (_, e) in zip(extras, order, strict=True) if e <= lost]
        else:
            expected = extras
        assert _extras_in(tmp_path / "r.mcap") == expected, name
        assert r.damaged and r.bytes_unreadable > 0, name


def test_another_tools_own_records_are_counted_in_one_warning_line(session, tmp_path, cli, caplog):
    """Records of opcodes 0x80-0xff (valid MCAP, meaningful only to their tool) cannot be copied: recover keeps
    every message around them and says how many it left out."""
    path, data, chunks, keys = session
    rng = np.random.default_rng(5)
    spans = _record_spans(data)
    where = sorted(int(k) for k in rng.choice(np.arange(1, len(spans)), 3, replace=False))
    out, prev = bytearray(), 0
    for k in where:
        at = spans[k][1]
        body = rng.bytes(int(rng.integers(0, 5000)))
        out += data[prev:at] + bytes([int(rng.integers(0x80, 0x100))]) + len(body).to_bytes(8, "little") + body
        prev = at
    src = tmp_path / "u.mcap"
    src.write_bytes(bytes(out + data[prev:]))
    code, _, err = cli("recover", src, "-o", tmp_path / "r.mcap")
    line = f"{src}: 3 record(s) of another tool's own kinds (opcodes 0x80-0xff) not copied: their meaning is that tool's"
    assert code == 0 and err == f"phonepose: warning: {line}\n", err
    assert [r.getMessage() for r in caplog.records if r.levelname == "WARNING"] == [line]
    assert read_keys(tmp_path / "r.mcap") == keys
