"""SessionReader: typed, decoded messages of a session in a deterministic order.

Messages come in (log_time, channel id, sequence) order, streamed chunk by chunk (nothing
loads the whole file), optionally filtered by topic and by a log-time range.
"""

from __future__ import annotations

import heapq
import itertools
import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from google.protobuf.message import DecodeError
from mcap.records import ChunkIndex
from mcap.records import Message as McapMessage
from mcap_protobuf.decoder import DecoderFactory

from phonepose.errors import DamagedFileError, InputFileError, PhoneposeError, SessionContentError
from phonepose.files import check_input
from phonepose.schemas.topics import TOPIC_TYPES, message_type_for
from phonepose.session.codec import MAX_TIME_NS, TIME_RANGE, times_problem
from phonepose.session.index import (
    MCAP_MAGIC,
    SessionIndex,
    check_unchanged,
    damaged,
    message_index_times,
    read_chunk,
    read_index,
    refuse_while_recorded,
)

# protobuf schema name -> generated class, for every type a phonepose session uses
_KNOWN_TYPES = {cls.DESCRIPTOR.full_name: cls for cls in TOPIC_TYPES.values()}


def _order_key(m) -> tuple[int, int, int]:
    return m.log_time, m.channel_id, m.sequence


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
    check_input(path, "MCAP file")     # a FIFO, socket or device: refused before open() could wait forever
    try:
        with open(path, "rb") as f:
            head = f.read(len(MCAP_MAGIC))
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if head != MCAP_MAGIC:
        refuse_while_recorded(path)    # a recorder that has not written its header yet
        raise InputFileError(f"{path}: {'not an MCAP file' if head else 'empty file'}")
    return path


class SessionReader:
    """Open a session for reading. Raises InputFileError / DamagedFileError with one clear line.

    Where the messages are comes from :func:`phonepose.session.index.read_index`: the summary
    section when it passes its CRC and cross-checks, else the data section (one warning line).
    """

    def __init__(self, path: str | os.PathLike):
        self.path = check_mcap_file(path)
        self._file = open(self.path, "rb")
        self._opened = os.fstat(self._file.fileno())
        try:
            self.index: SessionIndex = read_index(self._file, self.path)
        except PhoneposeError:
            self._file.close()
            raise
        except Exception:  # noqa: BLE001 - any parse failure of a damaged file (MemoryError, struct.error, ...)
            self._file.close()
            raise damaged(self.path, "its summary and index cannot be read") from None
        self._decoders: dict[int, Callable[[bytes], Any]] = {}
        self._file_order_chunks: list | None | bool = False  # False: not checked yet
        self._fallback = DecoderFactory()

    # ------------------------------------------------------------------ summary
    def summary(self) -> SessionSummary:
        ix = self.index
        stats = ix.statistics
        counts = dict(stats.channel_message_counts) if stats else {}
        channels = []
        for cid, ch in sorted(ix.channels.items()):
            schema = ix.schemas.get(ch.schema_id)
            channels.append(ChannelSummary(ch.topic, schema.name if schema else "", ch.message_encoding,
                                           counts.get(cid, 0)))
        if stats is not None and stats.message_count and stats.message_end_time > MAX_TIME_NS:
            self.log_times()        # names the topic
            self._bad_log_time(None, stats.message_end_time)   # only a chunk header claims it
        return SessionSummary(
            path=self.path, channels=channels,
            start_ns=stats.message_start_time if stats else 0,
            end_ns=stats.message_end_time if stats else 0,
            message_count=stats.message_count if stats else 0,
        )

    def verify(self, deep: bool = False) -> int:
        """Check the chunks; DamagedFileError (pointing to recover) if one is not intact.

        Opening already checked that every chunk is where the index says, with the header it says
        (or read every chunk, when the summary could not be used). ``deep``: also decompress every
        chunk and check its CRC. Returns the number of chunks checked.
        """
        if deep:
            try:
                for ci in self.index.chunks:
                    self._chunk_messages(ci, None, None, None)
            except DamagedFileError:
                self._check_unchanged()
                raise
        return len(self.index.chunks)

    def _check_unchanged(self) -> None:
        check_unchanged(self.path, self._file.fileno(), self._opened)

    def log_times(self) -> dict[str, np.ndarray]:
        """The log time of every message, per topic (uint64 ns as in MCAP, in file order): from the message index
        records when every chunk has them (a few bytes a message), else from the chunks themselves."""
        ix = self.index
        by_channel: dict[int, list] = {}
        if ix.times is not None:
            by_channel = {cid: [ts] for cid, ts in ix.times.items()}
        else:
            for ci in ix.chunks:
                got = message_index_times(self._file, ci)
                if got is None:
                    lists: dict[int, list[int]] = {}
                    for m in self._chunk_messages(ci, None, None, None):
                        lists.setdefault(m.channel_id, []).append(m.log_time)
                    got = {cid: np.asarray(ts, dtype=np.uint64) for cid, ts in lists.items()}
                for cid, arr in got.items():
                    by_channel.setdefault(cid, []).append(arr)
            for m in ix.loose:
                by_channel.setdefault(m.channel_id, []).append(np.array([m.log_time], dtype=np.uint64))
        parts: dict[str, list] = {}
        for cid, arrays in by_channel.items():
            ch = ix.channels.get(cid)
            if ch is not None:
                parts.setdefault(ch.topic, []).extend(arrays)
        out = {topic: np.concatenate(arrays) for topic, arrays in parts.items()}
        for topic, ts in out.items():
            if ts.size and int(ts.max()) > MAX_TIME_NS:
                self._bad_log_time(topic, int(ts.max()))
        return out

    def topics(self) -> set[str]:
        return {ch.topic for ch in self.index.channels.values()}

    # ------------------------------------------------------------------ messages
    def _decode(self, schema, channel, data: bytes):
        decoder = self._decoders.get(channel.id)
        if decoder is None:
            if channel.message_encoding != "protobuf":
                raise SessionContentError(
                    f"{self.path}: topic {channel.topic} has encoding {channel.message_encoding!r}, "
                    "phonepose reads protobuf only")
            if schema is None:      # schema id 0: allowed by MCAP, but protobuf bytes cannot be read without one
                raise SessionContentError(f"{self.path}: topic {channel.topic} has no schema: phonepose reads protobuf "
                                          "messages by their schema (a FileDescriptorSet)")
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

    def _chunk_messages(self, ci: ChunkIndex, wanted: set[int] | None, start_ns: int | None,
                        end_ns: int | None) -> list[McapMessage]:
        """The Message records of one chunk that pass the filters, in file order (CRC checked). A
        Channel record in the chunk that the index defines differently is damage (a summary without
        a CRC can only be checked here)."""
        channels = self.index.channels
        out = []
        t0 = self.index.statistics.message_start_time if self.index.statistics else None
        for r in read_chunk(self._file, self.path, ci, t0):
            if isinstance(r, McapMessage):
                if ((wanted is None or r.channel_id in wanted) and (start_ns is None or r.log_time >= start_ns)
                        and (end_ns is None or r.log_time < end_ns)):
                    if r.channel_id not in channels:
                        raise damaged(self.path, f"the chunk at byte {ci.chunk_start_offset} holds messages of "
                                                 f"channel {r.channel_id}, which the file does not define")
                    out.append(r)
            elif getattr(r, "topic", None) is not None:     # a Channel record
                known = channels.get(r.id)
                if known is not None and (known.topic, known.schema_id) != (r.topic, r.schema_id):
                    raise damaged(self.path, f"the summary's channel {r.id} ({known.topic}) is {r.topic} in the "
                                             f"chunk at byte {ci.chunk_start_offset}")
        return out

    def _chunks(self, topics: list[str] | None, start_ns: int | None, end_ns: int | None):
        """The chunks that may hold wanted messages, in file order, and the wanted channel ids."""
        ix = self.index
        wanted = None if topics is None else {cid for cid, ch in ix.channels.items() if ch.topic in topics}
        out = []
        for ci in ix.chunks:
            if start_ns is not None and ci.message_end_time < start_ns:
                continue
            if end_ns is not None and ci.message_start_time >= end_ns:
                continue
            if wanted is not None and ci.message_index_offsets and not wanted.intersection(ci.message_index_offsets):
                continue
            out.append(ci)
        return out, wanted

    def _in_file_order(self) -> bool:
        """Whether the chunks follow each other in log time (SessionWriter writes so) and no message
        lies outside a chunk. Then sorting each chunk's messages on its own gives the global order,
        one chunk in memory at a time, with no per-message heap."""
        if self._file_order_chunks is False:
            c = self.index.chunks
            self._file_order_chunks = not self.index.loose and all(
                b.message_start_time >= a.message_end_time for a, b in zip(c, c[1:], strict=False))
        return bool(self._file_order_chunks)

    def _iter_sorted(self, chunks, wanted, start_ns, end_ns) -> Iterator[McapMessage]:
        if self._in_file_order():
            return self._iter_file_order(chunks, wanted, start_ns, end_ns)
        return self._iter_merged(chunks, wanted, start_ns, end_ns)

    def _iter_file_order(self, chunks, wanted, start_ns, end_ns) -> Iterator[McapMessage]:
        """Chunks that follow each other in time: each one sorted on its own."""
        carry: list[McapMessage] = []    # the last log time of a chunk: the next one may start at it
        for ci in chunks:
            msgs = self._chunk_messages(ci, wanted, start_ns, end_ns)
            if not msgs:
                continue
            msgs.sort(key=_order_key)
            if carry and msgs[0].log_time == carry[0].log_time:
                msgs = sorted(carry + msgs, key=_order_key)
            else:
                yield from carry
            k = len(msgs)
            while k and msgs[k - 1].log_time == msgs[-1].log_time:
                k -= 1
            yield from msgs[:k]
            carry = msgs[k:]
        yield from carry

    def _iter_merged(self, chunks, wanted, start_ns, end_ns) -> Iterator[McapMessage]:
        """Chunks that overlap in time (another writer), and messages outside chunks: merged, each chunk
        opened when its first log time comes up (what the mcap reader's log_time_order does)."""
        def keep(m: McapMessage) -> bool:
            return ((wanted is None or m.channel_id in wanted) and (start_ns is None or m.log_time >= start_ns)
                    and (end_ns is None or m.log_time < end_ns))

        # Each entry ends in a count unique to it: messages equal in (log time, channel, sequence) (writers that
        # leave every sequence 0) come in the order they were read, and the heap never compares two records.
        count = itertools.count()
        heap: list = [(ci.message_start_time, 0, 0, 0, next(count), ci) for ci in chunks]
        heap += [(m.log_time, 1, m.channel_id, m.sequence, next(count), m) for m in self.index.loose if keep(m)]
        heapq.heapify(heap)
        while heap:
            _, kind, _, _, _, item = heapq.heappop(heap)
            if kind == 0:
                for m in self._chunk_messages(item, wanted, start_ns, end_ns):
                    heapq.heappush(heap, (m.log_time, 1, m.channel_id, m.sequence, next(count), m))
            else:
                yield item

    def raw_messages(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                     end_ns: int | None = None) -> Iterator[tuple]:
        """(schema, channel, mcap message) tuples in (log_time, channel id, sequence) order."""
        topics = list(topics) if topics is not None else None
        ix = self.index
        channels, schemas = ix.channels, ix.schemas
        try:
            chunks, wanted = self._chunks(topics, start_ns, end_ns)
            for m in self._iter_sorted(chunks, wanted, start_ns, end_ns):
                channel = channels[m.channel_id]
                if m.log_time > MAX_TIME_NS or m.publish_time > MAX_TIME_NS:
                    self._bad_log_time(channel.topic, max(m.log_time, m.publish_time))
                yield schemas.get(channel.schema_id) if channel.schema_id else None, channel, m
        except DamagedFileError:
            self._check_unchanged()
            raise
        except PhoneposeError:
            raise
        except Exception:  # noqa: BLE001 - anything the mcap/zstd/lz4 layers raise on damaged bytes
            self._check_unchanged()
            raise damaged(self.path, "its data cannot be read where the index points") from None

    def messages(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[Message]:
        """Decoded messages; ``end_ns`` is exclusive."""
        for schema, channel, m in self.raw_messages(topics, start_ns, end_ns):
            msg = self._decode(schema, channel, m.data)
            problem = times_problem(msg)
            if problem is not None:
                raise SessionContentError(f"{self.path}: topic {channel.topic}: the message at log time {m.log_time} "
                                          f"has {problem}")
            yield Message(channel.topic, m.log_time, m.publish_time, channel.id, m.sequence, msg)

    def _bad_log_time(self, topic: str | None, value: int) -> None:
        where = f"topic {topic}: " if topic is not None else ""
        raise SessionContentError(f"{self.path}: {where}log time {value} is outside the times phonepose reads "
                                  f"({TIME_RANGE})")

    def first(self, topic: str):
        """The first decoded message on ``topic``, or None."""
        for m in self.messages([topic]):
            return m.msg
        return None

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> SessionReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
