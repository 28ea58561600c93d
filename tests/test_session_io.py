"""SessionWriter / SessionReader round trips and ordering."""

from __future__ import annotations

import pytest

from phonepose.errors import DamagedFileError, InputFileError
from phonepose.schemas import phonepose_pb2 as pb
from phonepose.schemas.topics import TOPIC_TYPES, message_type_for
from phonepose.session import SessionReader, SessionWriter
from phonepose.testing.sample import sample_messages


@pytest.fixture()
def sample_path(tmp_path):
    path = tmp_path / "s.mcap"
    with SessionWriter(path) as w:
        for i, (topic, msg, t) in enumerate(sample_messages()):
            w.write(topic, msg, t + i)
    return path


def test_every_topic_type_is_in_the_sample():
    topics = {t for t, _, _ in sample_messages()}
    assert set(TOPIC_TYPES) <= topics


@pytest.mark.parametrize("index", range(len(sample_messages())))
def test_each_message_type_reads_back_equal(sample_path, index):
    topic, msg, _ = sample_messages()[index]
    with SessionReader(sample_path) as r:
        got = [m for m in r.messages([topic])]
    assert len(got) == 1
    assert type(got[0].msg) is message_type_for(topic)
    assert got[0].msg == msg
    assert got[0].msg.SerializeToString() == msg.SerializeToString()


def test_summary_counts_and_times(sample_path):
    with SessionReader(sample_path) as r:
        s = r.summary()
    n = len(sample_messages())
    assert s.message_count == n
    assert s.end_ns - s.start_ns == n - 1
    assert all(c.count == 1 for c in s.channels)
    assert all(c.encoding == "protobuf" for c in s.channels)


def test_order_is_log_time_then_channel_then_sequence(tmp_path):
    path = tmp_path / "order.mcap"
    imu = pb.Imu()
    with SessionWriter(path) as w:
        # written out of order; two channels share log times
        for t in [30, 10, 20, 10, 30]:
            w.write("/controller/imu", imu, t)
        for t in [20, 10]:
            w.write("/session/info", pb.SessionInfo(), t)
    with SessionReader(path) as r:
        got = [(m.log_time_ns, m.channel_id, m.sequence) for m in r.messages()]
    assert got == sorted(got)
    assert [g[0] for g in got] == [10, 10, 10, 20, 20, 30, 30]


def test_topic_filter_and_time_range(tmp_path):
    path = tmp_path / "range.mcap"
    with SessionWriter(path) as w:
        for t in range(0, 100, 10):
            w.write("/controller/imu", pb.Imu(gyro_x=t), t)
            w.write("/session/info", pb.SessionInfo(seed=t), t)
    with SessionReader(path) as r:
        got = [m.msg.gyro_x for m in r.messages(["/controller/imu"], start_ns=20, end_ns=50)]
    assert got == [20, 30, 40]


def test_flush_about_once_a_second_keeps_a_killed_file_readable(tmp_path):
    """A file never finished (no summary) still holds every chunk flushed before the 'crash'."""
    from mcap.reader import NonSeekingReader

    path = tmp_path / "open.mcap"
    f = open(path, "wb")
    w = SessionWriter(f)
    for k in range(50):  # 5 s of log time at 10 Hz
        w.write("/controller/imu", pb.Imu(gyro_x=k), k * 100_000_000)
    f.flush()  # what the OS has; the writer's open chunk is lost, as with SIGKILL
    with open(path, "rb") as g:
        got = []
        try:
            for _, _, m in NonSeekingReader(g).iter_messages(log_time_order=False):
                got.append(m.log_time)
        except Exception:
            pass
    # flushed at every full second of log time: everything up to t = 4 s is there
    assert len(got) >= 41
    with pytest.raises(DamagedFileError):
        SessionReader(path)
    f.close()


def test_bad_inputs_raise_one_line_errors(tmp_path):
    with pytest.raises(InputFileError, match="no such file"):
        SessionReader(tmp_path / "missing.mcap")
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(InputFileError, match="empty file"):
        SessionReader(empty)
    text = tmp_path / "text.mcap"
    text.write_text("hello")
    with pytest.raises(InputFileError, match="not an MCAP file"):
        SessionReader(text)
