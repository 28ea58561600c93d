"""Fuzzing the session reader, ``info``, ``recover`` and the message decoders with hypothesis.

Random and mutated bytes (bit flips, truncations, overwritten ranges, splices, insertions of a
valid session) may only ever produce a PhoneposeError subclass, never another exception type.
Bounded example counts keep this fast enough for CI.
"""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from phonepose.errors import PhoneposeError, SessionContentError
from phonepose.schemas.topics import TOPIC_TYPES
from phonepose.session import SessionReader, SessionWriter
from phonepose.session.recover import salvage
from phonepose.testing.sample import sample_messages, write_sample

FUZZ = settings(max_examples=int(os.environ.get("PHONEPOSE_FUZZ_EXAMPLES", "150")), deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

@pytest.fixture(scope="module")
def work(tmp_path_factory) -> str:
    """The folder every example writes its input (and recover its output) into."""
    return str(tmp_path_factory.mktemp("fuzz"))


@pytest.fixture(scope="module")
def bases(work) -> list[bytes]:
    """The valid sessions the mutations start from: the sample, and every message type three times
    flushed after every message (many small chunks)."""
    sample = os.path.join(work, "sample.mcap")
    write_sample(sample)
    multi = os.path.join(work, "multi.mcap")
    with SessionWriter(multi, flush_every_ns=1) as w:
        for k in range(3):
            for topic, msg, t in sample_messages(t0_ns=1_700_000_000_000_000_000 + k * 10**9):
                w.write(topic, msg, t)
    out = []
    for path in (sample, multi):
        with open(path, "rb") as f:
            out.append(f.read())
    return out


@st.composite
def mutated(draw, bases: list[bytes]) -> bytes:
    data = bytearray(bases[draw(st.integers(0, len(bases) - 1))])
    n = len(data)
    kind = draw(st.sampled_from(["truncate", "flip", "overwrite", "splice", "insert", "duplicate"]))
    if kind == "truncate":
        return bytes(data[: draw(st.integers(0, n - 1))])
    if kind == "flip":
        for _ in range(draw(st.integers(1, 8))):
            i = draw(st.integers(0, n - 1))
            data[i] ^= 1 << draw(st.integers(0, 7))
        return bytes(data)
    a = draw(st.integers(0, n - 1))
    b = draw(st.integers(a, min(n, a + 4096)))
    if kind == "overwrite":
        data[a:b] = draw(st.binary(min_size=b - a, max_size=b - a))
        return bytes(data)
    if kind == "splice":
        return bytes(data[:a] + data[b:])
    if kind == "insert":
        return bytes(data[:a] + draw(st.binary(min_size=1, max_size=64)) + data[a:])
    return bytes(data[:b] + data[a:b] + data[b:])  # duplicate a range


def _write(work: str, data: bytes, name: str = "in.mcap") -> str:
    path = os.path.join(work, name)
    with open(path, "wb") as f:
        f.write(data)
    return path


def _read_everything(path: str) -> int:
    with SessionReader(path) as r:
        r.summary()
        return sum(1 for _ in r.messages())


def test_bases_are_valid_sessions(work, bases):
    n = len(sample_messages())
    assert _read_everything(_write(work, bases[0])) == n
    assert _read_everything(_write(work, bases[1])) == 3 * n


@FUZZ
@given(draw=st.data())
def test_reader_raises_only_our_errors(work, bases, draw):
    data = draw.draw(st.one_of(mutated(bases), st.binary(max_size=2048),
                               st.binary(max_size=512).map(lambda b: b"\x89MCAP0\r\n" + b)))
    path = _write(work, data)
    try:
        _read_everything(path)
    except PhoneposeError as exc:
        assert str(exc) and "\n" not in str(exc)


@FUZZ
@given(draw=st.data())
def test_info_raises_only_our_errors(work, bases, draw):
    from phonepose.cli.info import info

    path = _write(work, draw.draw(mutated(bases)))
    try:
        info(path, as_json=True)
    except PhoneposeError as exc:
        assert "\n" not in str(exc)


@FUZZ
@given(draw=st.data())
def test_recover_raises_only_our_errors_and_writes_readable_files(work, bases, draw):
    path = _write(work, draw.draw(st.one_of(mutated(bases), st.binary(min_size=1, max_size=2048))))
    out = os.path.join(work, "out.mcap")
    try:
        report = salvage(path, out)
    except PhoneposeError as exc:
        assert "\n" not in str(exc)
        return
    # whatever was recovered is a valid session: summary, index, every message readable
    assert report.messages > 0
    with SessionReader(out) as r:
        s = r.summary()
        assert s.message_count == report.messages
        assert sum(1 for _ in r.raw_messages()) == report.messages
    try:
        _read_everything(out)
    except SessionContentError:
        pass  # a flipped bit inside a message payload of a chunk without CRC can still be undecodable


_TYPES = sorted({cls.DESCRIPTOR.full_name: cls for cls in TOPIC_TYPES.values()}.items())


@FUZZ
@given(idx=st.integers(0, len(_TYPES) - 1), payload=st.binary(max_size=512))
def test_decoders_raise_only_our_error(work, bases, idx, payload):
    """Random bytes through the reader's decode path: a message or SessionContentError."""
    path = _write(work, bases[0], "decode.mcap")
    with SessionReader(path) as r:
        name, cls = _TYPES[idx]

        class _Schema:
            pass

        class _Channel:
            pass

        schema, channel = _Schema(), _Channel()
        schema.name, schema.encoding, schema.data, schema.id = name, "protobuf", b"", 1
        channel.id, channel.topic, channel.message_encoding, channel.schema_id = 1000 + idx, "/fuzz", "protobuf", 1
        try:
            msg = r._decode(schema, channel, payload)
        except SessionContentError as exc:
            assert "undecodable" in str(exc)
        else:
            assert isinstance(msg, cls)


@pytest.mark.parametrize("payload", [b"\xff" * 16, b"\x0a\xff\xff\xff\xff\x0f", b"\x0a\x02\xc3\x28"])
def test_known_undecodable_payloads(work, bases, payload):
    """Hand-picked bad payloads: truncated varint, huge length, invalid UTF-8 in a string field."""
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

    path = _write(work, bases[0], "decode2.mcap")
    with SessionReader(path) as r:
        class _O:
            pass

        schema, channel = _O(), _O()
        schema.name, schema.encoding, schema.data, schema.id = CompressedImage.DESCRIPTOR.full_name, "protobuf", b"", 1
        channel.id, channel.topic, channel.message_encoding, channel.schema_id = 99, "/x", "protobuf", 1
        with pytest.raises(SessionContentError, match="undecodable foxglove.CompressedImage message on /x"):
            r._decode(schema, channel, payload)
