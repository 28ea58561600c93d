"""Where a session's messages are: its summary section, checked before it is trusted.

An MCAP file's summary (schemas, channels, statistics, one index record per chunk) is what lets a
reader seek instead of reading the whole file, and what ``info`` prints. It is data like any other:
one flipped bit in it could make playback run forever (a Statistics end time), drop a topic (a
Channel's name) or shift ``--start/--end`` (a start time). So :func:`read_index`

1. checks the footer's summary CRC (the writer's CRC32 of the summary section and footer);
2. cross-checks what the summary claims against the data section where that costs a few bytes
   per chunk: every chunk is where its index says, with the times, sizes and compression it says;
   every channel a chunk index or the statistics name exists; the statistics agree with the chunk
   indexes (count, first and last log time, messages per channel add up);
3. when the summary fails a check, reads the data section instead (what a reader does with a file
   that has no summary) and says so in one warning line. Files without a Statistics record, or
   whose summary does not repeat the channels, are valid MCAP: their data section is read too,
   without a warning.

Records are decoded by ``mcap.records``; only the footer's fixed layout is read with ``struct``
(the CRC covers raw bytes, so they have to be read anyway).
"""

from __future__ import annotations

import io
import logging
import os
import struct
import zlib
from dataclasses import dataclass, field
from typing import BinaryIO

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, ChunkIndex, Message, Schema, Statistics
from mcap.stream_reader import StreamReader, breakup_chunk

from phonepose.errors import DamagedFileError, InputFileError
from phonepose.files import being_written

log = logging.getLogger("phonepose")

MCAP_MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")            # opcode, record length
_FOOTER = struct.Struct("<BQQQI")             # opcode, length, summary start, summary offset start, CRC
_FOOTER_SIZE = _FOOTER.size                    # 29 bytes
_CHUNK_FIXED = struct.Struct("<QQQII")        # start, end, uncompressed size, CRC, compression length

# A chunk that claims more than this uncompressed is damaged (or hostile), not decompressed: a 33 KB
# file could otherwise inflate to 1 GiB. SessionWriter closes chunks at 1 MiB and its largest message
# (a camera JPEG) is far below 1 MiB; 64 MiB leaves room for other writers' larger chunks.
MAX_CHUNK_BYTES = 64 << 20
# Any length or count read from a file is checked against this and against what is left of the file before
# anything is read or allocated: a claim beyond either is damage. The largest record phonepose reads is a
# chunk of MAX_CHUNK_BYTES (its compressed data may exceed that by zstd's bound, 1/256), with its header.
MAX_RECORD_BYTES = MAX_CHUNK_BYTES + (1 << 20)
# A summary larger than this is not one a writer made (1000 chunks of 1 MiB index in ~150 KB).
_MAX_SUMMARY_BYTES = MAX_RECORD_BYTES


@dataclass
class SessionIndex:
    """What is in the file and where: from a verified summary, or from reading the data section."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunks: list[ChunkIndex] = field(default_factory=list)         # in file order
    statistics: Statistics | None = None
    loose: list[Message] = field(default_factory=list)              # messages outside chunks (unchunked writers)
    times: dict[int, np.ndarray] | None = None  # log times per channel (uint64), when the data section was read
    from_summary: bool = True
    problem: str | None = None      # why the summary was not used (None: it was, or the file has none)


def damaged(path: str, what: str) -> DamagedFileError:
    """The one line for a damaged file: what is damaged and where, and what to do."""
    return DamagedFileError(f"{path}: damaged MCAP file: {what}; run `phonepose recover {path} --out FIXED.mcap`")


class _SummaryProblem(Exception):
    """The summary section fails a check; the message says which, for the warning line."""


def read_index(f: BinaryIO, path: str) -> SessionIndex:
    """The index of an open MCAP file (``f`` at any position). DamagedFileError when the file ends
    before its footer, or the data section itself is damaged where it had to be read."""
    size = os.fstat(f.fileno()).st_size
    footer = _footer(f, path, size)
    summary_start = footer[2]
    if summary_start == 0:      # a valid file without a summary section
        return scan_data_section(f, path, size)
    try:
        index = _verified_summary(f, size, footer)
    except _SummaryProblem as exc:
        index = None
        problem = str(exc)
    if index is not None and index.statistics is not None and index.channels and (
            index.chunks or index.statistics.message_count == 0):
        return index
    if index is not None:       # valid but minimal: no Statistics, channels only in the chunks, or unchunked
        return scan_data_section(f, path, size)
    scanned = scan_data_section(f, path, size)     # damaged data too: that is the one line, not this warning
    scanned.problem = problem
    log.warning("%s: the summary section is damaged (%s); read the data section instead "
                "(`phonepose recover` writes a file with a good summary)", path, problem)
    return scanned


def _footer(f: BinaryIO, path: str, size: int) -> tuple:
    if size < 2 * len(MCAP_MAGIC) + _FOOTER_SIZE:
        refuse_while_recorded(path)
        raise damaged(path, f"it ends after {size} bytes, before its footer (truncated)")
    f.seek(size - len(MCAP_MAGIC) - _FOOTER_SIZE)
    tail = f.read(_FOOTER_SIZE + len(MCAP_MAGIC))
    footer = _FOOTER.unpack_from(tail)
    if tail[_FOOTER_SIZE:] != MCAP_MAGIC or footer[0] != Opcode.FOOTER or footer[1] != _FOOTER_SIZE - 9:
        refuse_while_recorded(path)
        raise damaged(path, "it ends without its footer (truncated: a recording killed, or a copy cut short)")
    return footer


def refuse_while_recorded(path: str) -> None:
    """A file without its footer that a recorder holds (the output rule's lock) is not damaged: it is not done."""
    if being_written(path):
        raise InputFileError(f"{path}: a recording in progress (another phonepose is writing it; its footer and "
                             f"index come last): wait for it to finish")


def check_unchanged(path: str, fd: int, before: os.stat_result, reading: str = "it was read",
                    again: str = "run phonepose again") -> None:
    """Damage found after opening may be another program writing or cutting the file meanwhile (a copy still
    going on): then that is the line, not "damaged: run recover". ``before``: the file's stat when opened."""
    now = os.fstat(fd)
    if (now.st_size, now.st_mtime_ns) != (before.st_size, before.st_mtime_ns):
        raise InputFileError(f"{path}: changed while {reading} ({before.st_size} bytes, now {now.st_size}): another "
                             f"program is writing or cutting it; {again} when it is done") from None


def _crc(f: BinaryIO, start: int, end: int) -> int:
    f.seek(start)
    crc, left = 0, end - start
    while left > 0:
        block = f.read(min(left, 1 << 20))
        if not block:
            break
        crc = zlib.crc32(block, crc)
        left -= len(block)
    return crc


def _verified_summary(f: BinaryIO, size: int, footer: tuple) -> SessionIndex:
    """The summary section as an index, if it passes every check; else _SummaryProblem."""
    _, _, start, offset_start, crc = footer
    footer_at = size - len(MCAP_MAGIC) - _FOOTER_SIZE
    if not len(MCAP_MAGIC) < start <= footer_at or (offset_start and not start <= offset_start <= footer_at):
        raise _SummaryProblem(f"the footer puts it at byte {start}, outside the file")
    if footer_at - start > _MAX_SUMMARY_BYTES:
        raise _SummaryProblem(f"the footer puts it at byte {start}, {footer_at - start} bytes before the end")
    if crc != 0:
        # the CRC covers the summary, the summary offsets and the footer up to the CRC field (MCAP spec)
        actual = _crc(f, start, footer_at + _FOOTER_SIZE - 4)
        if actual != crc:
            raise _SummaryProblem(f"CRC {actual:08x}, the footer says {crc:08x}")
    f.seek(start)
    summary = f.read(footer_at - start)
    index = _parse_summary(summary, offset_start - start if offset_start else len(summary))
    _cross_check(f, index, start)
    return index


def _parse_summary(data: bytes, records_end: int) -> SessionIndex:
    index = SessionIndex()
    stream = StreamReader(io.BytesIO(data[:records_end]), skip_magic=True, emit_chunks=True,
                          record_size_limit=len(data))
    try:
        records = list(_until_end(stream))
    except Exception as exc:  # noqa: BLE001 - mcap raises struct.error, EndOfFile, UnicodeDecodeError, ...
        raise _SummaryProblem(f"a record does not parse: {type(exc).__name__}") from None
    for r in records:
        if isinstance(r, Schema):
            index.schemas[r.id] = r
        elif isinstance(r, Channel):
            index.channels[r.id] = r
        elif isinstance(r, Statistics):
            index.statistics = r
        elif isinstance(r, ChunkIndex):
            index.chunks.append(r)
        elif type(r).__name__ not in ("AttachmentIndex", "MetadataIndex"):
            raise _SummaryProblem(f"it holds a {type(r).__name__} record")
    index.chunks.sort(key=lambda c: c.chunk_start_offset)
    return index


def _until_end(stream: StreamReader):
    """mcap's StreamReader over a summary without its footer: records until the bytes end."""
    from mcap.exceptions import EndOfFile

    it = stream.records
    while True:
        try:
            yield next(it)
        except (StopIteration, EndOfFile):
            return


def _cross_check(f: BinaryIO, index: SessionIndex, summary_start: int) -> None:
    """What the summary says against itself and against each chunk's header (a few bytes per chunk)."""
    for cid, ch in index.channels.items():
        if ch.schema_id and ch.schema_id not in index.schemas:
            raise _SummaryProblem(f"channel {cid} ({ch.topic}) names schema {ch.schema_id}, which it lacks")
    end = len(MCAP_MAGIC)
    for ci in index.chunks:
        where = f"chunk index for byte {ci.chunk_start_offset}"
        if ci.chunk_start_offset < end or ci.chunk_start_offset + ci.chunk_length > summary_start:
            raise _SummaryProblem(f"{where}: outside the data section or overlapping the chunk before it")
        if index.channels and any(c not in index.channels for c in ci.message_index_offsets):
            raise _SummaryProblem(f"{where}: names a channel the summary lacks")
        if ci.message_start_time > ci.message_end_time or ci.uncompressed_size > MAX_CHUNK_BYTES:
            raise _SummaryProblem(f"{where}: impossible times or size")
        _check_chunk_header(f, ci, where)
        end = ci.chunk_start_offset + ci.chunk_length
    _check_statistics(index)


def _check_chunk_header(f: BinaryIO, ci: ChunkIndex, where: str) -> None:
    f.seek(ci.chunk_start_offset)
    comp = ci.compression.encode()
    head = f.read(9 + _CHUNK_FIXED.size + len(comp) + 8)
    if len(head) < 9 + _CHUNK_FIXED.size + len(comp) + 8:
        raise _SummaryProblem(f"{where}: past the end of the file")
    op, length = _RECORD_HEAD.unpack_from(head)
    t0, t1, usize, _, clen = _CHUNK_FIXED.unpack_from(head, 9)
    p = 9 + _CHUNK_FIXED.size
    records_len = struct.unpack_from("<Q", head, p + clen)[0] if clen == len(comp) else -1
    if (op, length, t0, t1, usize, clen, head[p:p + clen], records_len) != (
            Opcode.CHUNK, ci.chunk_length - 9, ci.message_start_time, ci.message_end_time, ci.uncompressed_size,
            len(comp), comp, ci.compressed_size):
        raise _SummaryProblem(f"{where}: the chunk there does not match it")


def _check_statistics(index: SessionIndex) -> None:
    s = index.statistics
    if s is None:
        return
    counts = s.channel_message_counts
    if index.channels and any(c not in index.channels for c in counts):
        raise _SummaryProblem("the statistics count messages of a channel the summary lacks")
    if counts and sum(counts.values()) != s.message_count:
        raise _SummaryProblem(f"the statistics count {s.message_count} messages, {sum(counts.values())} by channel")
    if index.chunks:
        if s.chunk_count != len(index.chunks):
            raise _SummaryProblem(f"the statistics count {s.chunk_count} chunks, the index has {len(index.chunks)}")
        t0 = min(c.message_start_time for c in index.chunks)
        t1 = max(c.message_end_time for c in index.chunks)
        if s.message_count and (s.message_start_time, s.message_end_time) != (t0, t1):
            raise _SummaryProblem(f"the statistics' log times {s.message_start_time}..{s.message_end_time} are not "
                                  f"the chunks' {t0}..{t1}")


# ----------------------------------------------------------------------------- the data section
def _chunk_at(offset: int, chunk, t0_ns: int | None) -> str:
    """A chunk in the user's terms: where in the file, and which stretch of the recording it holds."""
    if t0_ns is None or not t0_ns <= chunk.message_start_time <= chunk.message_end_time:
        return f"the chunk at byte {offset}"
    return (f"the chunk at byte {offset} (log time {(chunk.message_start_time - t0_ns) / 1e9:.2f}-"
            f"{(chunk.message_end_time - t0_ns) / 1e9:.2f} s)")


def chunk_records(chunk: Chunk, path: str, offset: int, t0_ns: int | None = None) -> list:
    """The records inside one chunk (mcap's breakup_chunk, its CRC checked), refusing to inflate one
    whose declared size is beyond any real chunk. ``t0_ns``: the session's start, for the error line."""
    if chunk.uncompressed_size > MAX_CHUNK_BYTES:
        raise damaged(path, f"{_chunk_at(offset, chunk, t0_ns)} claims {chunk.uncompressed_size} bytes uncompressed, "
                            f"more than the {MAX_CHUNK_BYTES >> 20} MiB any real chunk holds")
    try:
        return breakup_chunk(chunk, validate_crc=True)
    except Exception as exc:  # noqa: BLE001 - zstd/lz4/CRC/struct errors of damaged bytes
        raise damaged(path, f"{_chunk_at(offset, chunk, t0_ns)} {_what(exc)}") from None


def _what(exc: Exception) -> str:
    name = type(exc).__name__
    if name == "CRCValidationError":
        return "fails its CRC check"
    if name in ("ZstdError", "LZ4FrameError", "RuntimeError"):
        return "does not decompress"
    return "holds records that do not parse"


def too_long(path: str, pos: int, length: int, left: int) -> DamagedFileError | None:
    """The error for a record at ``pos`` whose length field claims more than the ``left`` bytes the file has
    for it, or more than MAX_RECORD_BYTES; None when the claim is possible."""
    if length > left:
        return damaged(path, f"the record at byte {pos} claims {length} bytes, more than the {max(left, 0)} "
                             f"the file has after it")
    if length > MAX_RECORD_BYTES:
        return damaged(path, f"the record at byte {pos} claims {length} bytes, more than the "
                             f"{MAX_RECORD_BYTES >> 20} MiB any record phonepose reads holds")
    return None


def read_chunk(f: BinaryIO, path: str, ci: ChunkIndex, t0_ns: int | None = None) -> list:
    """The records of the chunk ``ci`` points to: its record read whole (its length checked first), then
    parsed from memory, so no length inside it reaches past the record."""
    length = ci.chunk_length - 9
    problem = too_long(path, ci.chunk_start_offset, length, os.fstat(f.fileno()).st_size - ci.chunk_start_offset - 9)
    if problem is not None:
        raise problem
    f.seek(ci.chunk_start_offset + 9)
    chunk = _parse_chunk(f.read(length), path, ci.chunk_start_offset)
    return chunk_records(chunk, path, ci.chunk_start_offset, t0_ns)


def _parse_chunk(body: bytes, path: str, pos: int) -> Chunk:
    """A chunk record's body, parsed from memory: no length inside it reaches past the record."""
    try:
        chunk = Chunk.read(ReadDataStream(io.BytesIO(body)))
        declared = struct.unpack_from("<Q", body, _CHUNK_FIXED.size + len(chunk.compression.encode()))[0]
        if declared != len(chunk.data):     # mcap's read stops quietly at the record's end
            raise ValueError("the compressed data runs past the record")
        return chunk
    except Exception:  # noqa: BLE001 - a header that does not parse
        raise damaged(path, f"the chunk at byte {pos} has a header that does not parse") from None


_DATA_OPS = frozenset((Opcode.CHUNK, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.MESSAGE_INDEX,
                       Opcode.ATTACHMENT, Opcode.METADATA))


def scan_data_section(f: BinaryIO, path: str, size: int) -> SessionIndex:
    """An index built by reading every record of the data section (each chunk decompressed once).

    The records must chain from the header to a Data End record: a byte that is no data-section
    record (an overwritten header, a summary record) is damage, never the end of the data, so a
    damaged file is never read as a shorter one."""
    index = SessionIndex(from_summary=False)
    times: dict[int, list[int]] = {}
    counts: dict[int, int] = {}
    limit = size - len(MCAP_MAGIC) - _FOOTER_SIZE       # where the footer is (checked before)
    f.seek(len(MCAP_MAGIC))
    op, length = _RECORD_HEAD.unpack(f.read(9))
    if op != Opcode.HEADER:
        raise damaged(path, "its header record is overwritten")
    pos = len(MCAP_MAGIC) + 9 + length
    while True:
        if pos == limit:
            break       # no Data End record (the spec requires one, but nothing is lost without it)
        if pos + 9 > limit:
            raise damaged(path, f"the record at byte {pos} runs into the footer")
        f.seek(pos)
        op, length = _RECORD_HEAD.unpack(f.read(9))
        if pos + 9 + length > limit:
            raise damaged(path, f"the record at byte {pos} runs past the end of the data")
        if op == Opcode.DATA_END and length == 4:
            break
        if op not in _DATA_OPS and op < 0x80:       # 0x80-0xff: user records, skipped by every reader
            raise damaged(path, f"the data at byte {pos} is not an MCAP record (overwritten?)")
        if op in (Opcode.CHUNK, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE):     # the kinds read into memory
            problem = too_long(path, pos, length, limit - pos - 9)
            if problem is not None:
                raise problem
            body = f.read(length)
            if op == Opcode.CHUNK:
                index.chunks.append(_scan_chunk(index, counts, times, body, path, pos, length))
            else:
                _add(index, counts, times, _read_record(op, body, length, path, pos))
        pos += 9 + length
    index.statistics = _statistics(index, counts)
    # kept for the whole playback: one uint64 array a channel, not a Python int (32 bytes) a message
    index.times = {cid: np.array(ts, dtype=np.uint64) for cid, ts in times.items()}
    return index


_MESSAGE_INDEX_HEAD = struct.Struct("<BQHI")     # opcode, record length, channel id, records' byte length


def message_index_times(f: BinaryIO, ci: ChunkIndex) -> dict[int, np.ndarray] | None:
    """Log times per channel of one chunk from the Message Index records after it (16 bytes a
    message, nothing decompressed); None when the chunk has none or they do not parse. They are
    outside the summary's CRC, so they only ever serve as a hint (see :func:`main_span`).

    Parsed here rather than by mcap's StreamReader, which makes a tuple of two Python ints per
    message: a transient that grows with the session, partly never returned to the system
    (docs/performance.md#memory). The (log time, offset) pairs are read as one uint64 array per
    record instead."""
    offsets = [o for o in ci.message_index_offsets.values()]
    left = os.fstat(f.fileno()).st_size - min(offsets, default=0)
    if not offsets or min(offsets) == 0 or not 0 < ci.message_index_length <= min(left, MAX_RECORD_BYTES):
        return None
    f.seek(min(offsets))
    block = f.read(ci.message_index_length)
    out: dict[int, np.ndarray] = {}
    pos = 0
    while pos < len(block):
        if pos + _MESSAGE_INDEX_HEAD.size > len(block):
            return None
        op, length, channel_id, n_bytes = _MESSAGE_INDEX_HEAD.unpack_from(block, pos)
        end = pos + 9 + length
        if end > len(block):
            return None
        if op != Opcode.MESSAGE_INDEX:     # another record between them: skipped, as mcap's readers do
            pos = end
            continue
        if length < 6 + n_bytes or n_bytes % 16:
            return None
        pairs = np.frombuffer(block, dtype="<u8", count=n_bytes // 8, offset=pos + _MESSAGE_INDEX_HEAD.size)
        out[channel_id] = pairs[0::2].copy()
        pos = end
    return out if set(out) == set(ci.message_index_offsets) else None


# Messages whose log time lies more than this from every other message are outliers (a clock jump,
# a flipped bit): playback skips them with a warning instead of planning ticks across the gap.
OUTLIER_GAP_NS = 3600 * 10**9


def main_span(times: np.ndarray) -> tuple[int, int] | None:
    """The first and last log time of the largest group of messages not separated by more than
    OUTLIER_GAP_NS (None for no messages); the first such group on a tie."""
    if len(times) == 0:
        return None
    ts = np.sort(np.asarray(times, dtype=np.uint64))
    cuts = np.flatnonzero(np.diff(ts) > OUTLIER_GAP_NS) + 1          # where a new group starts
    starts = np.concatenate(([0], cuts))
    ends = np.concatenate((cuts, [ts.size]))
    best = int(np.argmax(ends - starts))
    return int(ts[starts[best]]), int(ts[ends[best] - 1])


def _read_record(op: int, body: bytes, length: int, path: str, pos: int):
    stream = ReadDataStream(io.BytesIO(body))
    try:
        if op == Opcode.SCHEMA:
            return Schema.read(stream)
        if op == Opcode.CHANNEL:
            return Channel.read(stream)
        return Message.read(stream, length)
    except Exception:  # noqa: BLE001 - a record that does not parse
        raise damaged(path, f"the record at byte {pos} does not parse") from None


def _add(index: SessionIndex, counts: dict[int, int], times: dict[int, list[int]], r) -> None:
    if isinstance(r, Schema):
        index.schemas.setdefault(r.id, r)
    elif isinstance(r, Channel):
        index.channels.setdefault(r.id, r)
    elif isinstance(r, Message):
        index.loose.append(r)
        times.setdefault(r.channel_id, []).append(r.log_time)
        counts[r.channel_id] = counts.get(r.channel_id, 0) + 1


def _scan_chunk(index: SessionIndex, counts: dict[int, int], times: dict[int, list[int]], body: bytes, path: str,
                pos: int, length: int) -> ChunkIndex:
    chunk = _parse_chunk(body, path, pos)
    in_chunk: dict[int, int] = {}
    lo = hi = None
    t0 = index.chunks[0].message_start_time if index.chunks else chunk.message_start_time
    for r in chunk_records(chunk, path, pos, t0):
        if isinstance(r, Message):
            in_chunk[r.channel_id] = in_chunk.get(r.channel_id, 0) + 1
            times.setdefault(r.channel_id, []).append(r.log_time)
            lo = r.log_time if lo is None else min(lo, r.log_time)
            hi = r.log_time if hi is None else max(hi, r.log_time)
        else:
            _add(index, counts, times, r)
    for cid, n in in_chunk.items():
        counts[cid] = counts.get(cid, 0) + n
    return ChunkIndex(message_start_time=lo or 0, message_end_time=hi or 0, chunk_start_offset=pos,
                      chunk_length=9 + length, message_index_offsets={cid: 0 for cid in in_chunk},
                      message_index_length=0, compression=chunk.compression, compressed_size=len(chunk.data),
                      uncompressed_size=chunk.uncompressed_size)


def _statistics(index: SessionIndex, counts: dict[int, int]) -> Statistics:
    times = [(c.message_start_time, c.message_end_time) for c in index.chunks if c.message_index_offsets]
    times += [(m.log_time, m.log_time) for m in index.loose]
    return Statistics(
        message_count=sum(counts.values()), schema_count=len(index.schemas), channel_count=len(index.channels),
        attachment_count=0, metadata_count=0, chunk_count=len(index.chunks),
        message_start_time=min((t[0] for t in times), default=0), message_end_time=max((t[1] for t in times), default=0),
        channel_message_counts=dict(sorted(counts.items())))
