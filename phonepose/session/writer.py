"""SessionWriter: one MCAP file per session, protobuf on every channel.

zstd chunks of about 1 MiB, and ``Writer.flush()`` about once a second of log time, so a
killed recorder loses at most about a second of data (docs/reliability.md). Used as a context
manager it always finishes the file (summary, index, footer), also on exceptions.
"""

from __future__ import annotations

import os
from typing import BinaryIO, cast

from google.protobuf.message import Message as PbMessage
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import build_file_descriptor_set

from phonepose import __version__
from phonepose.errors import RECOVER_HINT, OutputError
from phonepose.schemas.topics import message_type_for

CHUNK_SIZE = 1 << 20
FLUSH_EVERY_NS = 1_000_000_000


def refuse_to_replace(path: str | os.PathLike, force: bool = False, parameter: str = "out",
                      force_parameter: str = "force") -> None:
    """Stop a command before it replaces an existing file at ``path`` unless ``force``; the errors name the
    caller's keywords ``parameter`` (the path's) and ``force_parameter``.

    A live recording cannot be made again and a simulated one costs minutes, so the commands that
    create a session (record sim, record live, recover) call this before they start.
    """
    if os.path.isdir(path):
        raise OutputError(f"{os.fspath(path)}: is a directory; {{{parameter}}} takes a file name", parameter=parameter,
                          value=path)
    if os.path.lexists(path) and not force:
        raise OutputError(f"{os.fspath(path)} already exists: choose another {{{parameter}}}, or add "
                          f"{{{force_parameter}=True}} to replace it", parameter=parameter, value=path,
                          also=[force_parameter])


class SessionWriter:
    def __init__(self, path: str | os.PathLike | BinaryIO, *, flush_every_ns: int = FLUSH_EVERY_NS,
                 chunk_size: int = CHUNK_SIZE, compression: CompressionType = CompressionType.ZSTD):
        if hasattr(path, "write"):
            self._file = cast(BinaryIO, path)   # an open binary file (hasattr does not narrow the union)
            self._owns_file = False
            self.path = getattr(path, "name", None)
        else:
            self.path = os.fspath(path)
            try:
                self._file = open(self.path, "wb")
            except OSError as exc:
                raise OutputError(f"cannot write {self.path}: {exc.strerror or exc}") from None
            self._owns_file = True
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=compression)
        self._writer.start(profile="", library=f"phonepose {__version__}")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence: dict[int, int] = {}
        self._flush_every_ns = flush_every_ns
        self._last_flush_ns: int | None = None
        self._finished = False
        self.message_count = 0

    # ------------------------------------------------------------------ channels
    def _channel_id(self, topic: str, msg: PbMessage) -> int:
        cid = self._channels.get(topic)
        if cid is not None:
            return cid
        expected = _expected_type(topic)
        if expected is not None and not isinstance(msg, expected):
            raise TypeError(f"{topic} carries {expected.DESCRIPTOR.full_name}, got {type(msg).DESCRIPTOR.full_name}")
        name = msg.DESCRIPTOR.full_name
        sid = self._schemas.get(name)
        if sid is None:
            sid = self._writer.register_schema(
                name=name, encoding="protobuf", data=build_file_descriptor_set(type(msg)).SerializeToString()
            )
            self._schemas[name] = sid
        cid = self._writer.register_channel(topic=topic, message_encoding="protobuf", schema_id=sid)
        self._channels[topic] = cid
        self._sequence[cid] = 0
        return cid

    # ------------------------------------------------------------------ writing
    def write(self, topic: str, msg: PbMessage, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        """Write one message; ``log_time_ns`` is the capture time on the display's clock."""
        self.write_bytes(topic, msg, msg.SerializeToString(), log_time_ns, publish_time_ns)

    def write_bytes(self, topic: str, msg_type_example: PbMessage, data: bytes, log_time_ns: int,
                    publish_time_ns: int | None = None) -> None:
        cid = self._channel_id(topic, msg_type_example)
        seq = self._sequence[cid]
        self._sequence[cid] = seq + 1
        try:
            self._writer.add_message(
                channel_id=cid, log_time=int(log_time_ns), data=data,
                publish_time=int(log_time_ns if publish_time_ns is None else publish_time_ns), sequence=seq,
            )
            self.message_count += 1
            if self._last_flush_ns is None:
                self._last_flush_ns = int(log_time_ns)
            elif log_time_ns - self._last_flush_ns >= self._flush_every_ns:
                self.flush()
                self._last_flush_ns = int(log_time_ns)
        except OSError as exc:
            raise OutputError(f"cannot write {self.path}: {exc.strerror or exc}{RECOVER_HINT}") from None

    def flush(self) -> None:
        """Close the open chunk and hand it to the OS: a crash after this loses nothing before it."""
        self._writer.flush()
        self._file.flush()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        self._writer.add_metadata(name, data)

    def finish(self) -> None:
        if self._finished:
            return
        self._finished = True
        try:
            try:
                self._writer.finish()
                self._file.flush()
            finally:
                if self._owns_file:
                    self._file.close()
        except OSError as exc:
            raise OutputError(f"cannot finish {self.path}: {exc.strerror or exc}{RECOVER_HINT}") from None

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self.finish()
        except OutputError:
            if exc_type is None:
                raise
            # already failing (e.g. disk full in write()): keep that error, not the summary's


def _expected_type(topic: str):
    try:
        return message_type_for(topic)
    except KeyError:
        return None
