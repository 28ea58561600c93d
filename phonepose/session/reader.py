"""SessionReader: typed, decoded messages of a session in a deterministic order.

Messages come in (log_time, channel id, sequence) order, streamed chunk by chunk (nothing
loads the whole file), optionally filtered by topic and by a log-time range.
"""

from __future__ import annotations

import os
import struct
import zlib
from dataclasses import dataclass, field
from typing import Any, Iterable, Iterator

from google.protobuf.message import DecodeError
from mcap.data_stream import ReadDataStream
from mcap.reader import SeekingReader, make_reader
from mcap.records import Chunk
from mcap.records import Message as McapMessage
from mcap.stream_reader import breakup_chunk

try:
    import zstandard
except ImportError:  # pragma: no cover - mcap's zstd support is optional too
    zstandard = None
from mcap_protobuf.decoder import DecoderFactory

from phonepose.errors import DamagedFileError, InputFileError, PhoneposeError, SessionContentError
from phonepose.schemas.topics import TOPIC_TYPES, message_type_for

MCAP_MAGIC = b"\x89MCAP0\r\n"

# protobuf schema name -> generated class, for every type a phonepose session uses
_KNOWN_TYPES = {cls.DESCRIPTOR.full_name: cls for cls in TOPIC_TYPES.values()}


def _order_key(m) -> tuple[int, int, int]:
    return m.log_time, m.channel_id, m.sequence


_RECORD_HEAD = struct.Struct("<BQ")       # opcode, record length
_MESSAGE_HEAD = struct.Struct("<HIQQ")    # channel id, sequence, log time, publish time
_OP_MESSAGE = 0x05


def _chunk_messages(chunk: Chunk, wanted: set[int] | None, start_ns: int | None, end_ns: int | None) -> list:
    """The Message records of one chunk that pass the filters, in file order (CRC checked).

    What ``mcap.stream_reader.breakup_chunk`` does, with one ``struct`` call per record instead
    of a stream read per field, and no record built for the messages filtered out.
    """
    if chunk.compression == "zstd" and zstandard is not None:
        data = zstandard.decompress(chunk.data, chunk.uncompressed_size)
    elif chunk.compression == "":
        data = chunk.data
    else:  # lz4 or anything else: the mcap library's path
        return [r for r in breakup_chunk(chunk, validate_crc=True) if isinstance(r, McapMessage)
                and (wanted is None or r.channel_id in wanted)
                and (start_ns is None or r.log_time >= start_ns) and (end_ns is None or r.log_time < end_ns)]
    if chunk.uncompressed_crc != 0 and zlib.crc32(data) != chunk.uncompressed_crc:
        raise ValueError("chunk CRC mismatch")
    out = []
    pos, n = 0, len(data)
    head, msg_head = _RECORD_HEAD.unpack_from, _MESSAGE_HEAD.unpack_from
    while pos < n:
        op, length = head(data, pos)
        pos += 9
        end = pos + length
        if end > n:
            raise ValueError("record runs past the end of its chunk")
        if op == _OP_MESSAGE:
            if length < 22:
                raise ValueError("message record too short")
            cid, seq, log_time, publish_time = msg_head(data, pos)
            if ((wanted is None or cid in wanted) and (start_ns is None or log_time >= start_ns)
                    and (end_ns is None or log_time < end_ns)):
                out.append(McapMessage(channel_id=cid, sequence=seq, log_time=log_time, publish_time=publish_time,
                                       data=data[pos + 22:end]))
        pos = end
    return out


@dataclass(frozen=True)
class Message:
    topic: str
    log_time_ns: int
    publish_time_ns: int
    channel_id: int
    sequence: int
    msg: Any  # the decoded protobuf message, of the topic's type (docs/format.md)


@dataclass
class ChannelSummary:
    topic: str
    schema: str
    encoding: str
    count: int


@dataclass
class SessionSummary:
    path: str
    channels: list[ChannelSummary] = field(default_factory=list)
    start_ns: int = 0
    end_ns: int = 0
    message_count: int = 0

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9

    def has(self, topic: str) -> bool:
        return any(c.topic == topic and c.count > 0 for c in self.channels)


def check_mcap_file(path: str | os.PathLike) -> str:
    """Raise InputFileError unless ``path`` is an existing, readable, non-empty MCAP file."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise InputFileError(f"{path}: no such file")
    if os.path.isdir(path):
        raise InputFileError(f"{path}: is a directory, not an MCAP file")
    try:
        with open(path, "rb") as f:
            head = f.read(len(MCAP_MAGIC))
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(head) == 0:
        raise InputFileError(f"{path}: empty file")
    if head != MCAP_MAGIC:
        raise InputFileError(f"{path}: not an MCAP file")
    return path


class SessionReader:
    """Open a session for reading. Raises InputFileError / DamagedFileError with one clear line."""

    def __init__(self, path: str | os.PathLike):
        self.path = check_mcap_file(path)
        self._file = open(self.path, "rb")
        try:
            self._reader: SeekingReader = make_reader(self._file, validate_crcs=True)  # flipped bits in a chunk: error, not garbage
            self._summary_record = self._reader.get_summary()
        except Exception as exc:  # noqa: BLE001 - any parse failure of a damaged file (MemoryError, struct.error, ...)
            self._file.close()
            raise DamagedFileError(
                f"{self.path}: damaged MCAP file ({type(exc).__name__}); run `phonepose recover {self.path} --out FIXED.mcap`"
            ) from None
        if self._summary_record is None:
            self._file.close()
            raise DamagedFileError(f"{self.path}: MCAP file has no summary (truncated?); run `phonepose recover`")
        self._decoders: dict[int, object] = {}
        self._file_order_chunks: list | None | bool = False  # False: not checked yet
        self._fallback = DecoderFactory()

    # ------------------------------------------------------------------ summary
    def summary(self) -> SessionSummary:
        s = self._summary_record
        stats = s.statistics
        counts = dict(stats.channel_message_counts) if stats else {}
        channels = []
        for cid, ch in sorted(s.channels.items()):
            schema = s.schemas.get(ch.schema_id)
            channels.append(ChannelSummary(ch.topic, schema.name if schema else "", ch.message_encoding,
                                           counts.get(cid, 0)))
        return SessionSummary(
            path=self.path, channels=channels,
            start_ns=stats.message_start_time if stats else 0,
            end_ns=stats.message_end_time if stats else 0,
            message_count=stats.message_count if stats else 0,
        )

    def verify(self, deep: bool = False) -> int:
        """Check the chunks the index lists; DamagedFileError (pointing to recover) if one is not intact.

        Shallow (cheap, a few bytes per chunk): every chunk record is where the index says, with
        the length it says. ``deep``: also decompress every chunk and check its CRC. Returns the
        number of chunks checked.
        """
        chunks = sorted(self._summary_record.chunk_indexes, key=lambda c: c.chunk_start_offset)
        size = os.fstat(self._file.fileno()).st_size
        for ci in chunks:
            self._file.seek(ci.chunk_start_offset)
            head = self._file.read(9)
            ok = (len(head) == 9 and head[0] == 0x06 and ci.chunk_start_offset + ci.chunk_length <= size
                  and int.from_bytes(head[1:9], "little") == ci.chunk_length - 9)
            if not ok:
                raise DamagedFileError(f"{self.path}: damaged MCAP file (chunk at byte {ci.chunk_start_offset} is not "
                                       f"where the index says); run `phonepose recover {self.path} --out FIXED.mcap`")
        if deep:
            for _ in self.raw_messages():
                pass
        return len(chunks)

    def topics(self) -> set[str]:
        return {ch.topic for ch in self._summary_record.channels.values()}

    # ------------------------------------------------------------------ messages
    def _decode(self, schema, channel, data: bytes):
        decoder = self._decoders.get(channel.id)
        if decoder is None:
            if channel.message_encoding != "protobuf" or schema is None:
                raise SessionContentError(
                    f"{self.path}: topic {channel.topic} has encoding {channel.message_encoding!r}, "
                    "phonepose reads protobuf only")
            try:
                expected = message_type_for(channel.topic).DESCRIPTOR.full_name
            except KeyError:
                expected = None
            if expected is not None and schema.name != expected:
                raise SessionContentError(f"{self.path}: topic {channel.topic} has schema {schema.name!r}, "
                                          f"phonepose expects {expected!r}")
            cls = _KNOWN_TYPES.get(schema.name)
            if cls is not None:
                decoder = cls.FromString
            else:
                try:
                    decoder = self._fallback.decoder_for(channel.message_encoding, schema)
                except Exception:  # noqa: BLE001 - a schema whose descriptor data does not parse
                    decoder = None
                if decoder is None:
                    raise SessionContentError(f"{self.path}: unknown schema {schema.name!r} on {channel.topic} "
                                              "(its descriptor cannot be read)")
            self._decoders[channel.id] = decoder
        try:
            return decoder(data)
        except DecodeError:
            raise SessionContentError(f"{self.path}: undecodable {schema.name} message on {channel.topic}") from None

    def _chunks_in_order(self, topics: list[str] | None, start_ns: int | None, end_ns: int | None):
        """The chunks to read, in file order, if their log-time ranges do not overlap (else None).

        SessionWriter writes in log-time order, so its chunks follow each other in time: then
        sorting each chunk's messages on its own gives the global order, one chunk in memory at
        a time, without the mcap reader's per-message heap (its ``log_time_order=True`` path).
        """
        s = self._summary_record
        if self._file_order_chunks is False:
            chunks = sorted(s.chunk_indexes, key=lambda c: c.chunk_start_offset)
            if chunks and all(b.message_start_time >= a.message_end_time for a, b in zip(chunks, chunks[1:])):
                self._file_order_chunks = chunks
            else:
                self._file_order_chunks = None
        chunks = self._file_order_chunks
        if chunks is None:
            return None
        wanted = None if topics is None else {cid for cid, ch in s.channels.items() if ch.topic in topics}
        out = []
        for ci in chunks:
            if start_ns is not None and ci.message_end_time < start_ns:
                continue
            if end_ns is not None and ci.message_start_time >= end_ns:
                continue
            if wanted is not None and ci.message_index_offsets and not wanted.intersection(ci.message_index_offsets):
                continue
            out.append(ci)
        return out, wanted

    def _iter_chunked(self, chunks, wanted, start_ns, end_ns) -> Iterator[tuple]:
        s = self._summary_record
        channels, schemas = s.channels, s.schemas
        for ci in chunks:
            self._file.seek(ci.chunk_start_offset + 1 + 8)
            chunk = Chunk.read(ReadDataStream(self._file))
            msgs = _chunk_messages(chunk, wanted, start_ns, end_ns)
            msgs.sort(key=_order_key)
            for r in msgs:
                channel = channels[r.channel_id]
                yield (schemas[channel.schema_id] if channel.schema_id else None), channel, r

    def raw_messages(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                     end_ns: int | None = None) -> Iterator[tuple]:
        """(schema, channel, mcap message) tuples in (log_time, channel id, sequence) order."""
        topics = list(topics) if topics is not None else None
        pending: list[tuple] = []
        try:
            plan = self._chunks_in_order(topics, start_ns, end_ns)
            if plan is not None:
                it = self._iter_chunked(*plan, start_ns, end_ns)
            else:  # chunks overlap in time (not written by SessionWriter): the mcap reader's merge
                it = self._reader.iter_messages(topics=topics, starting_at=start_ns, ending_before=end_ns,
                                                log_time_order=True)
            for item in it:
                if pending and item[2].log_time != pending[0][2].log_time:
                    if len(pending) > 1:
                        pending.sort(key=lambda x: (x[1].id, x[2].sequence))
                    yield from pending
                    pending.clear()
                pending.append(item)
        except PhoneposeError:
            raise
        except Exception as exc:  # noqa: BLE001 - anything the mcap/zstd/lz4 layers raise on damaged bytes
            raise DamagedFileError(
                f"{self.path}: damaged MCAP data ({type(exc).__name__}); run `phonepose recover {self.path} --out FIXED.mcap`"
            ) from None
        if len(pending) > 1:
            pending.sort(key=lambda x: (x[1].id, x[2].sequence))
        yield from pending

    def messages(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[Message]:
        """Decoded messages; ``end_ns`` is exclusive."""
        for schema, channel, m in self.raw_messages(topics, start_ns, end_ns):
            yield Message(channel.topic, m.log_time, m.publish_time, channel.id, m.sequence,
                          self._decode(schema, channel, m.data))

    def first(self, topic: str):
        """The first decoded message on ``topic``, or None."""
        for m in self.messages([topic]):
            return m.msg
        return None

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> "SessionReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
