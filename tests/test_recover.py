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
