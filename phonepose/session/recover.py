"""Salvage a truncated or partly corrupted session into a valid, indexed MCAP file.

The damaged file is scanned record by record (no summary, no index needed, read through a window so
nothing loads the whole file). Every chunk whose compressed data decompresses to the size and
CRC its header promises is kept; a record that does not parse (truncated tail, flipped bits,
overwritten bytes) is skipped by scanning forward for the next chunk record (opcode 0x06) that
validates, so damage in the middle loses only the chunks it touches. Schemas and channels come
from the chunks and, when the file was finished, from its summary section too (so a lost first
chunk does not make the channels of later chunks unknown).

Messages are written again with the SessionWriter's settings (zstd, 1 MiB chunks), keeping
their topic, schema, log_time, publish_time and sequence, into a temporary file renamed over
``out`` only when complete.
"""

from __future__ import annotations

import io
import logging
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.records import Attachment, Channel, Chunk, Header, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer

from phonepose import __version__
from phonepose.errors import DamagedFileError, InputFileError, OutputError
from phonepose.files import check_input
from phonepose.session.index import MAX_CHUNK_BYTES, MAX_RECORD_BYTES, MCAP_MAGIC, check_unchanged
from phonepose.session.writer import CHUNK_SIZE, refuse_to_replace

log = logging.getLogger("phonepose")

# opcodes (MCAP spec)
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
OP_ATTACHMENT, OP_METADATA, OP_DATA_END = 0x09, 0x0C, 0x0F
_MAX_OPCODE = 0x0F
_USER_OPCODES = range(0x80, 0x100)     # other tools' own records: valid MCAP, meaningful only to them
_COMPRESSIONS = (b"", b"zstd", b"lz4")


class _Bad(Exception):
    """A record that does not parse or validate."""


@dataclass
class LostSpan:
    """Log-time range of data that could not be recovered (``end_ns`` None: unknown, at the tail)."""

    start_ns: int | None
    end_ns: int | None
    bytes: int

    @property
    def duration_s(self) -> float | None:
        if self.start_ns is None or self.end_ns is None:
            return None
        return max(0, self.end_ns - self.start_ns) / 1e9


@dataclass
class RecoveryReport:
    path: str
    out: str
    file_size: int = 0
    messages_per_topic: dict[str, int] = field(default_factory=dict)
    chunks_recovered: int = 0
    chunks_skipped: int = 0
    bytes_unreadable: int = 0
    lost: list[LostSpan] = field(default_factory=list)
    orphan_messages: int = 0      # messages whose channel definition was lost
    start_ns: int | None = None   # of what was recovered
    end_ns: int | None = None
    had_summary: bool = False     # the input was a finished file (only damage inside, if any)
    summary_damaged: bool = False  # its summary fails its CRC
    channels_from_damaged_summary: list[str] = field(default_factory=list)   # topics only that summary named
    metadata_records: int = 0
    attachments: int = 0
    user_records: int = 0         # records of opcodes 0x80-0xff (another tool's own), not copied

    @property
    def messages(self) -> int:
        return sum(self.messages_per_topic.values())

    @property
    def time_lost_s(self) -> float:
        """Approximate log time lost: the spans of skipped chunks (known where their header survived)."""
        return sum(s.duration_s or 0.0 for s in self.lost)

    @property
    def damaged(self) -> bool:
        return bool(self.chunks_skipped or self.bytes_unreadable or self.orphan_messages or not self.had_summary
                    or self.summary_damaged)


# ---------------------------------------------------------------------------- parsing
# Records are decoded by mcap.records. Only a chunk's fixed header is read with struct: the resync
# scan tries it at every 0x06 byte of a damaged region, and decoding it with Chunk.read would copy
# the chunk's data (up to megabytes) for each candidate.
_U8 = struct.Struct("<Q")
_U4 = struct.Struct("<I")


def _u8(b, off: int) -> int:
    return _U8.unpack(b[off:off + 8])[0]


def _decode(cls, b, start: int, end: int, *args):
    """``cls.read`` (an mcap.records class) over the record body ``b[start:end]`` (so no length inside it reaches
    past the record); _Bad if it does not parse."""
    try:
        return cls.read(ReadDataStream(io.BytesIO(bytes(b[start:end]))), *args)
    except Exception as exc:  # noqa: BLE001 - struct.error, EndOfFile, UnicodeDecodeError on damaged bytes
        raise _Bad(f"{cls.__name__}: {type(exc).__name__}") from None


def _attachment(b, start: int, end: int) -> Attachment:
    """An Attachment record whose CRC (over the record's fields before it) holds, or is 0 (not computed)."""
    r = _decode(Attachment, b, start, end)
    crc = _U4.unpack(b[end - 4:end])[0]
    if crc and zlib.crc32(b[start:end - 4]) != crc:
        raise _Bad("attachment CRC")
    return r


def _schema(b, off: int, end: int):
    r = _decode(Schema, b, off, end)
    return r.id, r.name, r.encoding, r.data


def _channel(b, off: int, end: int):
    r = _decode(Channel, b, off, end)
    return r.id, r.schema_id, r.topic, r.message_encoding, r.metadata


def _message(b, off: int, end: int):
    if off + 22 > end:
        raise _Bad("message")
    r = _decode(Message, b, off, end, end - off)
    return r.channel_id, r.sequence, r.log_time, r.publish_time, r.data


def _chunk_header(b, off: int, end: int):
    """(start, end, uncompressed size, crc, compression, data offset, data length) of a chunk record body."""
    if off + 32 > end:
        raise _Bad("chunk header")
    t0, t1, usize, crc, clen = struct.unpack("<QQQII", b[off:off + 32])
    if clen > 4 or off + 32 + clen + 8 > end:
        raise _Bad("chunk compression")
    comp = bytes(b[off + 32:off + 32 + clen])
    if comp not in _COMPRESSIONS:
        raise _Bad("chunk compression")
    p = off + 32 + clen
    dlen = _u8(b, p)
    p += 8
    if p + dlen != end or end - off > MAX_RECORD_BYTES or t1 < t0 or usize > MAX_CHUNK_BYTES:
        raise _Bad("chunk lengths")
    return t0, t1, usize, crc, comp.decode(), p, dlen


class _Salvager:
    def __init__(self, buf, report: RecoveryReport):
        self.b = buf
        self.n = len(buf)
        self.report = report
        self.schemas: dict[int, tuple[str, str, bytes]] = {}
        self.channels: dict[int, tuple[int, str, str, dict]] = {}
        # every good chunk, in file order: (record start, record end, {channel id: (count, t_min, t_max)},
        # t_min, t_max). Its messages are not kept: _write decompresses each chunk again, so memory
        # stays at one chunk whatever the size of the file.
        self.chunks: list[tuple[int, int, dict, int | None, int | None]] = []
        self.loose: list = []   # messages outside chunks (unchunked writers)
        # Metadata and Attachment records by where they are, (opcode, body start, body end): read again to be written
        self.extra: list[tuple[int, int, int]] = []
        self.profile = ""       # the Header's: what kind of session the file says it is
        # schemas and channels read after the Data End record: the summary's, used only if its CRC holds
        self.in_summary = False
        self.summary_schemas: dict[int, tuple[str, str, bytes]] = {}
        self.summary_channels: dict[int, tuple[int, str, str, dict]] = {}
        self.from_summary: set[int] = set()     # channels only the summary defines
        self.bad_regions: list[tuple[int, int, int | None, int | None]] = []  # (from, to, t0, t1)

    # one record at ``pos``: returns the next position, or raises _Bad
    def record(self, pos: int) -> int:
        b, n = self.b, self.n
        if pos + 9 > n:
            raise _Bad("truncated record header")
        op = b[pos]
        length = _u8(b, pos + 1)
        if op == 0 or _MAX_OPCODE < op < _USER_OPCODES.start:
            raise _Bad("opcode")
        start, end = pos + 9, pos + 9 + length
        if end > n:
            raise _Bad("truncated record")
        if length > MAX_RECORD_BYTES:   # checked before any byte of it is read: a claim beyond it is damage
            raise _Bad("record length")
        if op == OP_CHUNK:
            self.chunk(start, end)
        elif op == OP_SCHEMA:
            sid, name, enc, data = _schema(b, start, end)
            (self.summary_schemas if self.in_summary else self.schemas).setdefault(sid, (name, enc, data))
        elif op == OP_CHANNEL:
            cid, sid, topic, enc, meta = _channel(b, start, end)
            (self.summary_channels if self.in_summary else self.channels).setdefault(cid, (sid, topic, enc, meta))
        elif op == OP_DATA_END:
            self.in_summary = True
        elif op == OP_MESSAGE:
            self.loose.append(_message(b, start, end))
        elif op == OP_METADATA:
            _decode(Metadata, b, start, end)
            self.extra.append((op, start, end))
        elif op == OP_ATTACHMENT:
            _attachment(b, start, end)
            self.extra.append((op, start, end))
        elif op == OP_HEADER:
            self.profile = _decode(Header, b, start, end).profile
        elif op in _USER_OPCODES:
            self.report.user_records += 1
        elif op == OP_FOOTER:
            self.report.had_summary = True
            self._take_summary(start, end)
        return end

    def _take_summary(self, start: int, end: int) -> None:
        """The summary's schemas and channels, for the channels of a lost first chunk. When the footer's
        CRC over the summary fails they may be wrong: chunks' own definitions always win, and the ones
        taken from a damaged summary are counted for the report."""
        if end - start < 20:
            return
        summary_start, _, crc = struct.unpack("<QQI", self.b[start:start + 20])
        if crc and (summary_start >= start or self._crc(summary_start, start + 16) != crc):
            self.report.summary_damaged = True
        for k, v in self.summary_schemas.items():
            self.schemas.setdefault(k, v)
        for k, v in self.summary_channels.items():
            if k not in self.channels:
                self.channels[k] = v
                self.from_summary.add(k)

    def _crc(self, start: int, end: int) -> int:
        """CRC32 of the bytes [start, end), read a window at a time (the footer says where they start)."""
        crc = 0
        for at in range(start, end, self.b.WINDOW):
            crc = zlib.crc32(self.b[at:min(at + self.b.WINDOW, end)], crc)
        return crc

    def chunk(self, start: int, end: int) -> None:
        msgs, schemas, channels = self.parse_chunk(start, end)
        for k, v in schemas.items():
            self.schemas.setdefault(k, v)
        for k, v in channels.items():
            self.channels.setdefault(k, v)
        per_channel: dict[int, tuple[int, int, int]] = {}
        for cid, _, log_time, _, _ in msgs:
            n, lo, hi = per_channel.get(cid, (0, log_time, log_time))
            per_channel[cid] = (n + 1, min(lo, log_time), max(hi, log_time))
        times = [m[2] for m in msgs]
        self.chunks.append((start - 9, end, per_channel, min(times) if times else None, max(times) if times else None))

    def parse_chunk(self, start: int, end: int):
        """(messages, schemas, channels) of the chunk record body [start, end); _Bad unless wholly intact."""
        t0, t1, usize, crc, comp, doff, dlen = _chunk_header(self.b, start, end)
        chunk = Chunk(compression=comp, data=bytes(self.b[doff:doff + dlen]), message_start_time=t0,
                      message_end_time=t1, uncompressed_crc=crc, uncompressed_size=usize)
        try:   # every inner record must parse: a chunk is kept whole or not at all
            records = breakup_chunk(chunk, validate_crc=True)
        except Exception as exc:  # noqa: BLE001 - zstd/lz4 errors, CRC mismatch, records cut short
            raise _Bad(f"chunk: {type(exc).__name__}") from None
        msgs, schemas, channels = [], {}, {}
        for r in records:
            if isinstance(r, Message):
                msgs.append((r.channel_id, r.sequence, r.log_time, r.publish_time, r.data))
            elif isinstance(r, Schema):
                schemas[r.id] = (r.name, r.encoding, r.data)
            elif isinstance(r, Channel):
                channels[r.id] = (r.schema_id, r.topic, r.message_encoding, r.metadata)
        return msgs, schemas, channels

    def _plausible_chunk_at(self, pos: int) -> bool:
        b, n = self.b, self.n
        if pos + 9 + 32 > n:
            return False
        length = _u8(b, pos + 1)
        if pos + 9 + length > n:
            return False
        try:
            _chunk_header(b, pos + 9, pos + 9 + length)
        except _Bad:
            return False
        return True

    def resync(self, pos: int) -> int | None:
        """The offset of the next chunk record after ``pos`` that validates, or None."""
        for p in self.b.record_starts(pos + 1, OP_CHUNK):
            if not self._plausible_chunk_at(p):
                continue
            try:
                self.record(p)  # the chunk is appended by record(); pop it, run() re-reads it
            except _Bad:
                continue
            self.chunks.pop()
            return p
        return None

    def _framed_end(self, pos: int) -> int | None:
        """The end of the bad record at ``pos`` when its framing holds though its content does not (a chunk whose
        data fails its CRC, an attachment whose CRC fails): the lengths inside it add up to its length field, so
        the next record starts there and nothing between is lost to a resync; else None."""
        b, n = self.b, self.n
        try:        # a short read (the file cut meanwhile) is damage here like any other
            if pos + 9 > n:
                return None
            op, length = b[pos], _u8(b, pos + 1)
            start, end = pos + 9, pos + 9 + length
            if end > n or length > MAX_RECORD_BYTES or end == pos + 9:
                return None
            if op == OP_CHUNK:
                _chunk_header(b, start, end)
                return end
            if op == OP_ATTACHMENT:
                p = start + 16
                for _ in range(2):          # name, media type
                    p += 4 + _U4.unpack(b[p:p + 4])[0]
                return end if p + 8 <= end and p + 8 + _u8(b, p) + 4 == end else None
        except (_Bad, struct.error, IndexError):
            return None
        return None

    def _time_at(self, pos: int) -> tuple[int | None, int | None]:
        """Log times a damaged chunk header at ``pos`` still tells, if it parses."""
        b, n = self.b, self.n
        try:        # a short read (the file cut meanwhile): nothing told
            if pos + 9 + 16 <= n and b[pos] == OP_CHUNK:
                t0, t1 = struct.unpack("<QQ", b[pos + 9:pos + 25])
                if t0 <= t1 and (t1 - t0) < 3600 * 10**9:
                    return t0, t1
        except (IndexError, struct.error):
            pass
        return None, None

    def run(self) -> None:
        b, n = self.b, self.n
        if n >= len(MCAP_MAGIC) and bytes(b[:len(MCAP_MAGIC)]) == MCAP_MAGIC:
            pos = len(MCAP_MAGIC)
        else:
            pos = 0
            nxt = self.resync(-1)
            if nxt is None:
                self.bad_regions.append((0, n, None, None))
                return
            if nxt > 0:
                self.bad_regions.append((0, nxt, None, None))
            pos = nxt
        while pos < n:
            if self.report.had_summary and pos + len(MCAP_MAGIC) == n:
                break  # trailing magic
            try:
                pos = self.record(pos)
                continue
            except (_Bad, struct.error, IndexError, ValueError):
                pass
            t0, t1 = self._time_at(pos)
            nxt = self._framed_end(pos)
            if nxt is None:
                nxt = self.resync(pos)
            stop = n if nxt is None else nxt
            self.bad_regions.append((pos, stop, t0, t1))
            if nxt is None:
                break
            pos = nxt


def _topic_of(channels, cid):
    ch = channels.get(cid)
    return None if ch is None else ch[1]


def salvage(path: str | os.PathLike, out: str | os.PathLike, replace: bool = True,
            staged: bool = True) -> RecoveryReport:
    """Recover every intact chunk of ``path`` into ``out``; returns what was recovered and lost.

    ``staged``: written to ``OUT.partial`` and renamed when complete; False when ``out`` is already a temporary
    of :mod:`phonepose.files` (the CLI's), whose name the next command finds and clears after a crash (a
    ``.partial`` beside it stayed for good).

    Raises InputFileError (missing, unreadable, or the same file as ``out``), OutputError
    (``out`` not writable, or existing while ``replace`` is false) and DamagedFileError when
    nothing at all can be recovered.
    """
    src, dst = os.fspath(path), os.fspath(out)
    check_input(src, "MCAP file")      # a FIFO, socket or device: refused before open() could wait forever
    if os.path.exists(dst) and os.path.samefile(src, dst) or Path(src).resolve() == Path(dst).resolve():
        raise InputFileError(f"{dst}: is the input file; recover writes a new file (choose another {{out}})",
                             parameter="out", value=dst)
    refuse_to_replace(dst, replace, force_parameter="replace")
    report = RecoveryReport(path=src, out=dst)
    try:
        f = open(src, "rb")
    except OSError as exc:
        raise InputFileError(f"{src}: cannot read ({exc.strerror or exc})") from None
    with f:
        before = os.fstat(f.fileno())
        report.file_size = before.st_size
        if before.st_size == 0:
            raise InputFileError(f"{src}: empty file, nothing to recover")
        def unchanged() -> None:
            check_unchanged(src, f.fileno(), before, reading="recover read it", again="run recover again")

        sal = _Salvager(_FileBytes(f.fileno(), before.st_size), report)
        sal.run()
        unchanged()
        if report.user_records:     # every other record kind is kept (or rebuilt: the index records)
            log.warning("%s: %d record(s) of another tool's own kinds (opcodes 0x80-0xff) not "
                        "copied: their meaning is that tool's", src, report.user_records)
        try:
            _write(sal, report, dst, staged)
        finally:
            unchanged()   # its chunks were read again to be written
    return report


def _pread(fd: int, n: int, offset: int) -> bytes:
    """``os.pread``, or a seek and a read where the system has none (Windows): the salvager reads from one thread."""
    if hasattr(os, "pread"):
        return os.pread(fd, n, offset)
    os.lseek(fd, offset, os.SEEK_SET)
    return os.read(fd, n)


class _FileBytes:
    """The input as the salvager reads it: ``b[i]``, ``b[i:j]`` and ``b.find``, by ``os.pread`` through a 1 MiB
    window, not an mmap: a file another program cuts while recover reads it (a copy still going on) would
    kill an mmap reader with SIGBUS; a short read is damage like any other here, and :func:`salvage` then
    says the file changed."""

    WINDOW = 1 << 20

    def __init__(self, fd: int, size: int):
        self.fd, self.n = fd, size
        self._at, self._window = 0, b""

    def __len__(self) -> int:
        return self.n

    def _read(self, start: int, stop: int) -> bytes:
        stop = min(stop, self.n)
        if start >= stop:
            return b""
        if self._at <= start and stop <= self._at + len(self._window):
            return self._window[start - self._at:stop - self._at]
        if stop - start > self.WINDOW:          # a chunk's data: read once, not through the window
            return _pread(self.fd, stop - start, start)
        self._at, self._window = start, _pread(self.fd, self.WINDOW, start)
        return self._window[:stop - start]

    def __getitem__(self, key):
        if isinstance(key, slice):
            start, stop, _ = key.indices(self.n)
            return self._read(start, stop)
        byte = self._read(key, key + 1)
        if not byte:
            raise IndexError("beyond the end of the file")
        return byte[0]

    def record_starts(self, start: int, opcode: int):
        """Every offset from ``start`` on whose byte is ``opcode`` and whose length field fits in the file, in
        order: a window at a time with numpy, so garbage full of ``opcode`` bytes costs linear time, not a Python
        step a byte."""
        pos = max(start, 0)
        while pos < self.n:
            block = np.frombuffer(_pread(self.fd, self.WINDOW + 8, pos), dtype=np.uint8)
            if block.size == 0:
                return
            head = block[:self.WINDOW]
            at = np.flatnonzero(head == opcode)
            at = at[at + 9 <= block.size]            # the rest have no whole length field in the file
            lengths = np.zeros(at.size, dtype=np.uint64)
            for k in range(8):                       # the little-endian uint64 after each opcode
                lengths |= block[at + 1 + k].astype(np.uint64) << np.uint64(8 * k)
            room = self.n - 9 - (pos + at)           # bytes the file has for the record's body
            room = np.minimum(room, MAX_RECORD_BYTES)
            at = at[(room >= 0) & (lengths <= np.maximum(room, 0).astype(np.uint64))]
            for a in at.tolist():
                yield pos + a
            pos += head.size

    def find(self, sub: bytes, start: int = 0) -> int:
        """Searched inside the window, never copied out of it: the resync scan calls this once a candidate byte,
        so each call costs what it scans (a slice of the window's rest made garbage full of 0x06 quadratic)."""
        pos = max(start, 0)
        while pos < self.n:
            if not self._at <= pos < self._at + len(self._window):
                self._at, self._window = pos, _pread(self.fd, self.WINDOW, pos)
            found = self._window.find(sub, pos - self._at)
            if found >= 0:
                return self._at + found
            end = self._at + len(self._window)
            if end >= self.n or not self._window:
                return -1
            pos = end - len(sub) + 1        # a match across the window's end: read a window from there
            self._at, self._window = pos, _pread(self.fd, self.WINDOW, pos)
        return -1


def _write(sal: _Salvager, report: RecoveryReport, dst: str, staged: bool = True) -> None:
    counts: dict[str, int] = {}
    t_min = t_max = None
    stats = [per_channel for _, _, per_channel, _, _ in sal.chunks]
    stats += [{m[0]: (1, m[2], m[2])} for m in sal.loose]
    for per_channel in stats:
        for cid, (n, lo, hi) in per_channel.items():
            topic = _topic_of(sal.channels, cid)
            if topic is None:
                report.orphan_messages += n
                continue
            counts[topic] = counts.get(topic, 0) + n
            t_min = lo if t_min is None else min(t_min, lo)
            t_max = hi if t_max is None else max(t_max, hi)
    if report.summary_damaged:
        report.channels_from_damaged_summary = sorted(sal.channels[c][1] for c in sal.from_summary)
    report.chunks_recovered = len(sal.chunks)
    report.metadata_records = sum(op == OP_METADATA for op, _, _ in sal.extra)
    report.attachments = sum(op == OP_ATTACHMENT for op, _, _ in sal.extra)
    report.start_ns, report.end_ns = t_min, t_max
    _account_losses(sal, report)
    if not counts:
        raise DamagedFileError(
            f"{report.path}: nothing recoverable ({report.bytes_unreadable} of {report.file_size} bytes unreadable, "
            "no intact chunk with known channels)")
    report.messages_per_topic = dict(sorted(counts.items()))

    tmp = dst + ".partial" if staged else dst
    try:
        fo = open(tmp, "wb")
    except OSError as exc:
        raise OutputError(f"cannot write {dst}: {exc.strerror or exc}") from None
    try:
        with fo:
            w = Writer(fo, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
            w.start(profile=sal.profile, library=f"phonepose {__version__} (recovered)")
            schema_ids: dict[int, int] = {}
            channel_ids: dict[int, int] = {}
            for sid, (name, senc, data) in sorted(sal.schemas.items()):    # every schema, used by a channel or not
                schema_ids[sid] = w.register_schema(name=name, encoding=senc, data=data)
            for cid, (sid, topic, enc, meta) in sorted(sal.channels.items()):
                channel_ids[cid] = w.register_channel(topic=topic, message_encoding=enc,
                                                      schema_id=schema_ids.get(sid, 0), metadata=meta)
            def write(msgs):
                for cid, seq, log, pub, data in msgs:
                    new = channel_ids.get(cid)
                    if new is not None:
                        w.add_message(channel_id=new, log_time=log, data=data, publish_time=pub, sequence=seq)

            for start, end, _, _, _ in sal.chunks:   # one chunk in memory at a time
                write(sal.parse_chunk(start + 9, end)[0])
            write(sal.loose)
            for op, start, end in sal.extra:        # one record in memory at a time, in file order
                if op == OP_METADATA:
                    r = _decode(Metadata, sal.b, start, end)
                    w.add_metadata(r.name, r.metadata)
                else:
                    a = _attachment(sal.b, start, end)
                    w.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
            w.finish()
            fo.flush()
            os.fsync(fo.fileno())
        if staged:
            os.replace(tmp, dst)
    except (OSError, _Bad) as exc:    # _Bad: a chunk read again no longer parses (the file changed meanwhile)
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(exc, _Bad):
            raise
        raise OutputError(f"cannot write {dst}: {exc.strerror or exc}") from None


def _account_losses(sal: _Salvager, report: RecoveryReport) -> None:
    """Bytes and approximate log time of every damaged region.

    A region between two good chunks lost at most the log time between them; at the tail, the
    span its surviving chunk header tells (unknown when that header is gone too).
    """
    report.bytes_unreadable = sum(e - s for s, e, _, _ in sal.bad_regions)
    good = sorted((s, e, lo, hi) for s, e, _, lo, hi in sal.chunks if lo is not None)
    for s, e, t0, t1 in sal.bad_regions:
        before = [c for c in good if c[1] <= s]
        after = [c for c in good if c[0] >= e]
        prev_end = before[-1][3] if before else None
        next_start = after[0][2] if after else None
        if prev_end is not None and next_start is not None:
            lo, hi = prev_end, max(prev_end, next_start)
        elif next_start is not None:
            lo, hi = (t0 if t0 is not None and t0 <= next_start else None), next_start
        elif t1 is not None and (prev_end is None or t1 >= prev_end):
            lo, hi = (prev_end if prev_end is not None else t0), t1
        elif sal.b[s] != OP_CHUNK and _cut_record(sal, s):
            lo = hi = prev_end  # the file ends inside an index/summary record: no message data lost
        else:
            lo, hi = prev_end, None
        if sal.b[s] == OP_CHUNK:
            report.chunks_skipped += 1
        report.lost.append(LostSpan(lo, hi, e - s))


def _cut_record(sal: _Salvager, pos: int) -> bool:
    """Whether the record at ``pos`` is valid-looking but cut off by the end of the file."""
    if pos + 9 > sal.n:
        return True
    op = sal.b[pos]
    return 0 < op <= _MAX_OPCODE and op != OP_CHUNK and pos + 9 + _u8(sal.b, pos + 1) > sal.n
