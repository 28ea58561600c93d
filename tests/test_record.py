"""Recording a simulated session: determinism, the session contract, the CLI, and stopping."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import textwrap
import tomllib

import numpy as np
import pytest
from conftest import DEADLINE_S, wait_until
from mcap.reader import NonSeekingReader

from phonepose.geometry import Pose
from phonepose.record.sim import T0_NS, default_config, record_sim
from phonepose.schemas import phonepose_pb2 as pb
from phonepose.schemas.topics import Frame, Topic
from phonepose.session import SessionReader, codec

PHONEPOSE = [sys.executable, "-m", "phonepose"]
# A cheap camera rate keeps these tests fast; everything else is the default world.
FAST = default_config().replace(camera=dict(rate_hz=5.0))


def _sha(path) -> str:
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec") / "tri2.mcap"
    result = record_sim(out, scenario="exp2", path="TRI2", trial=1, seed=0, config=FAST)
    return out, result


def test_same_seed_same_bytes_different_seed_different_bytes(tmp_path, session):
    out, _ = session
    again = tmp_path / "again.mcap"
    record_sim(again, scenario="exp2", path="TRI2", trial=1, seed=0, config=FAST)
    assert _sha(again) == _sha(out)
    other = tmp_path / "other.mcap"
    record_sim(other, scenario="exp2", path="TRI2", trial=1, seed=1, config=FAST)
    assert _sha(other) != _sha(out)


def test_session_follows_the_contract(session):
    out, result = session
    with SessionReader(out) as r:
        msgs = list(r.messages())
        summary = r.summary()
    assert msgs[0].topic == Topic.SESSION_INFO
    info = msgs[0].msg
    assert (info.source, info.scenario, info.path, info.trial, info.seed) == ("sim", "exp2", "TRI2", 1, 0)
    assert tomllib.loads(info.config_toml)["camera"]["rate_hz"] == 5.0
    t_start, t_end = info.task_start.ToNanoseconds(), info.task_end.ToNanoseconds()
    assert t_end - t_start == 112 * 50_000_000           # Table 4: TRI2 trial 1 = 112 frames at 20 Hz
    by_topic: dict[str, list] = {}
    for m in msgs:
        by_topic.setdefault(m.topic, []).append(m)
    expected = {Topic.SESSION_INFO, Topic.CAMERA_IMAGE, Topic.CAMERA_CALIBRATION, Topic.CAMERA_EXTRINSICS,
                Topic.DISPLAY_VIO_POSE, Topic.DISPLAY_ANCHOR, Topic.CONTROLLER_VIO_POSE, Topic.CONTROLLER_ANCHOR,
                Topic.CONTROLLER_IMU, Topic.CONTROLLER_MARKER, Topic.GT_CONTROLLER_POSE, Topic.GT_DISPLAY_POSE,
                Topic.GT_CALIBRATION, Topic.CALIBRATION_EVENTS, Topic.EXPERIMENT_PATH, Topic.LOG,
                # the frame tree for Rerun and Foxglove (phonepose/viewer/frames.py)
                Topic.TF_DISPLAY, Topic.TF_CONTROLLER_VIO, Topic.TF_CONTROLLER, Topic.TF_MARKER,
                Topic.CONTROLLER_MARKER_OUTLINE, Topic.CAMERA_FRUSTUM}
    assert set(by_topic) == expected
    assert len(by_topic[Topic.TF_DISPLAY]) == len(by_topic[Topic.DISPLAY_VIO_POSE])
    assert len(by_topic[Topic.TF_CONTROLLER]) == len(by_topic[Topic.CONTROLLER_VIO_POSE])
    for topic in (Topic.CAMERA_CALIBRATION, Topic.CAMERA_EXTRINSICS, Topic.CONTROLLER_MARKER, Topic.GT_CALIBRATION,
                  Topic.EXPERIMENT_PATH, Topic.SESSION_INFO):
        assert len(by_topic[topic]) == 1 and by_topic[topic][0].log_time_ns == T0_NS
    duration = summary.duration_s
    for topic, rate in ((Topic.CAMERA_IMAGE, 5), (Topic.DISPLAY_VIO_POSE, 30), (Topic.CONTROLLER_VIO_POSE, 30),
                        (Topic.CONTROLLER_IMU, 200), (Topic.GT_CONTROLLER_POSE, 60), (Topic.GT_DISPLAY_POSE, 60)):
        assert abs(len(by_topic[topic]) - rate * duration) <= 0.03 * rate * duration + 2, topic
    calib = by_topic[Topic.CAMERA_CALIBRATION][0].msg
    assert (calib.width, calib.height, calib.distortion_model, calib.frame_id) == (640, 480, "plumb_bob",
                                                                                    Frame.DISPLAY_CAMERA)
    assert 480 < calib.K[0] < 520 and len(calib.D) == 5
    ext = by_topic[Topic.CAMERA_EXTRINSICS][0].msg
    assert (ext.parent_frame_id, ext.child_frame_id) == (Frame.DISPLAY, Frame.DISPLAY_CAMERA)
    gtc = by_topic[Topic.GT_CALIBRATION][0].msg
    assert (gtc.parent_frame_id, gtc.child_frame_id) == (Frame.WORLD, Frame.DISPLAY_VIO)
    spec = by_topic[Topic.CONTROLLER_MARKER][0].msg
    assert (spec.dictionary, spec.id, spec.size_m) == ("DICT_4X4_50", 7, 0.05)
    frames = {Topic.DISPLAY_VIO_POSE: Frame.DISPLAY_VIO, Topic.DISPLAY_ANCHOR: Frame.DISPLAY_VIO,
              Topic.CONTROLLER_VIO_POSE: Frame.CONTROLLER_VIO, Topic.CONTROLLER_ANCHOR: Frame.CONTROLLER_VIO,
              Topic.GT_CONTROLLER_POSE: Frame.WORLD, Topic.GT_DISPLAY_POSE: Frame.WORLD}
    for topic, frame in frames.items():
        assert {m.msg.frame_id for m in by_topic[topic]} == {frame}
    # log times never go back within a channel
    for topic, ms in by_topic.items():
        times = [m.log_time_ns for m in ms]
        assert times == sorted(times), topic
    # controller streams: stamped at capture, logged on receipt (latency + Wi-Fi)
    lat = int(FAST.network.controller_latency_s * 1e9)
    for topic in (Topic.CONTROLLER_VIO_POSE, Topic.CONTROLLER_IMU, Topic.CONTROLLER_ANCHOR):
        delays = np.array([m.log_time_ns - m.msg.timestamp.ToNanoseconds() for m in by_topic[topic]])
        assert delays.min() >= lat and np.median(delays) < lat + 50_000_000
    # display-side streams: log time is the capture time
    for topic in (Topic.CAMERA_IMAGE, Topic.DISPLAY_VIO_POSE):
        assert all(m.log_time_ns == m.msg.timestamp.ToNanoseconds() for m in by_topic[topic])
    assert result.frames == len(by_topic[Topic.CAMERA_IMAGE])


def test_calibration_events_before_the_task(session):
    out, _ = session
    with SessionReader(out) as r:
        info = r.first(Topic.SESSION_INFO)
        events = [m for m in r.messages([Topic.CALIBRATION_EVENTS])]
    assert [e.msg.kind for e in events] == [pb.CalibrationEvent.CM1, pb.CalibrationEvent.CM2]
    cm1, cm2 = events[0].msg, events[1].msg
    assert cm1.frame_id == Frame.DISPLAY_VIO
    assert cm1.fix_timestamp.ToNanoseconds() < cm1.timestamp.ToNanoseconds() <= events[0].log_time_ns
    assert events[1].log_time_ns < info.task_start.ToNanoseconds()
    fix, align = codec.pose_of(cm1.pose_fix_vio), codec.pose_of(cm1.pose_align_vio)
    # the mapped VIO pose moved by about the anchor error while the real phone went onto the CG object
    assert 0.02 < fix.distance_to(align) < 0.15
    assert not cm2.HasField("pose_fix_vio")


def test_anchor_mapping_through_the_recorded_topics(session):
    """T_dvio_ctrl = T_dvio_anchor · T_cvio_anchor⁻¹ · T_cvio_ctrl from the file, against GT."""
    out, _ = session
    with SessionReader(out) as r:
        da = codec.pose_of(r.first(Topic.DISPLAY_ANCHOR).pose)
        ca = codec.pose_of(r.first(Topic.CONTROLLER_ANCHOR).pose)
        cal = r.first(Topic.GT_CALIBRATION)
        vio = [(m.msg.timestamp.ToNanoseconds(), codec.pose_of(m.msg.pose)) for m in r.messages([Topic.CONTROLLER_VIO_POSE])]
        gt = [(m.log_time_ns, codec.pose_of(m.msg.pose)) for m in r.messages([Topic.GT_CONTROLLER_POSE])]
    T_world_dvio = Pose.from_xyzw([cal.translation.x, cal.translation.y, cal.translation.z],
                                  [cal.rotation.x, cal.rotation.y, cal.rotation.z, cal.rotation.w])
    gt_t = np.array([t for t, _ in gt])
    errs = []
    for t, p in vio[::10]:
        j = int(np.argmin(np.abs(gt_t - t)))
        mapped = da @ ca.inv() @ p
        errs.append(mapped.distance_to(T_world_dvio.inv() @ gt[j][1]))
    rms = float(np.sqrt(np.mean(np.square(errs))))
    assert 0.02 < rms < 0.12          # the anchor error (plus hand-eye lever arm and drift)


# ---------------------------------------------------------------- CLI
def test_cli_help(cli):
    r = cli("record", "sim", "--help")
    assert r.returncode == 0
    for opt in ("--scenario", "--path", "--trial", "--seed", "--out", "--config", "--rerun", "--spawn"):
        assert opt in r.stdout


def test_cli_bad_config_is_one_line_and_exit_5(tmp_path, cli):
    bad = tmp_path / "bad.toml"
    bad.write_text("[network]\ncontroller_latency_s = 7\n")
    out = tmp_path / "x.mcap"
    r = cli("record", "sim", "--out", str(out), "--config", str(bad))
    assert r.returncode == 5
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "network.controller_latency_s" in lines[0] and "[0, 1]" in lines[0]
    assert not out.exists()


def test_cli_records_and_summarises(tmp_path, cli):
    cfg = tmp_path / "fast.toml"
    cfg.write_text("[camera]\nrate_hz = 5.0\n")
    out = tmp_path / "s.mcap"
    r = cli("record", "sim", "--scenario", "exp2", "--path", "rec1", "--trial", "2", "--seed", "3", "--out", str(out),
            "--config", str(cfg), "--quiet")
    assert r.returncode == 0, r.stderr
    assert "exp2 REC1 trial 2" in r.stdout and "done" in r.stdout
    with SessionReader(out) as reader:
        info = reader.first(Topic.SESSION_INFO)
    assert (info.path, info.trial, info.seed) == ("REC1", 2, 3)

    # the same --out again: refused in one line, the first recording kept byte for byte
    before = out.read_bytes()
    again = ["record", "sim", "--scenario", "exp2", "--path", "rec1", "--trial", "2",
             "--seed", "4", "--out", str(out), "--config", str(cfg), "--quiet"]
    r = cli(*again)
    assert r.returncode == 6 and r.stderr == f"phonepose: error: {out} already exists: choose another --out, " \
                                              "or add --force to replace it\n"
    assert out.read_bytes() == before
    # --force replaces it
    r = cli(*again, "--force")
    assert r.returncode == 0, r.stderr
    with SessionReader(out) as reader:
        assert reader.first(Topic.SESSION_INFO).seed == 4


# ---------------------------------------------------------------- stopping
def _wait_for_size(path, size, proc):
    def grown():
        assert proc.poll() is None, proc.communicate()
        return os.path.exists(path) and os.path.getsize(path) > size

    wait_until(grown, what=f"the recording to pass {size} bytes")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_sigint_and_sigterm_finish_a_valid_file(tmp_path, sig):
    out = tmp_path / "long.mcap"
    proc = subprocess.Popen([*PHONEPOSE, "record", "sim", "--scenario", "exp1", "--out", str(out), "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for_size(out, 2_000_000, proc)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=DEADLINE_S)
    assert proc.returncode == 0, stderr
    assert "interrupted, file is valid" in stdout
    with SessionReader(out) as r:          # has a summary: the file was finished
        s = r.summary()
        n = sum(1 for _ in r.messages([Topic.CAMERA_IMAGE]))
    assert s.message_count > 100 and n > 10
    assert s.duration_s < 100              # stopped early (exp1 runs ~110 s)


_KILL_SCRIPT = textwrap.dedent("""
    import sys
    from phonepose.record.sim import record_sim
    def progress(done_ns, total_ns):
        print(done_ns, flush=True)
    record_sim(sys.argv[1], scenario="exp1", seed=0, progress=progress)
""")


def test_sigkill_loses_at_most_about_one_second(tmp_path):
    out = tmp_path / "killed.mcap"
    proc = subprocess.Popen([sys.executable, "-c", _KILL_SCRIPT, str(out)], stdout=subprocess.PIPE, text=True)
    last = 0
    for line in proc.stdout:
        last = int(line)
        if last > 6e9:                     # 6 s of session handed to the writer
            break
    proc.kill()
    proc.wait(timeout=DEADLINE_S)
    count, max_t = 0, 0
    with open(out, "rb") as f:
        try:
            for _, _, message in NonSeekingReader(f).iter_messages(log_time_order=False):
                count += 1
                max_t = max(max_t, message.log_time)
        except Exception:                  # the truncated tail
            pass
    readable_s = (max_t - T0_NS) / 1e9
    assert count > 1000
    assert readable_s >= last / 1e9 - 1.3, (readable_s, last / 1e9)


# ---------------------------------------------------------------- the recorder on any Source
class _ListSource:
    """A minimal live-like source: what a phone bridge would implement."""

    def __init__(self, records, static=()):
        self._records, self._static = list(records), list(static)
        self.start_ns, self.duration_ns = T0_NS, 1_000_000_000
        self.closed = False

    def static(self):
        return self._static

    def __iter__(self):
        return iter(self._records)

    def close(self):
        self.closed = True


def _log_record(t_ns, text="x"):
    from foxglove_schemas_protobuf.Log_pb2 import Log

    from phonepose.record.source import Record
    return Record(Topic.LOG, Log(message=text), t_ns, t_ns)


def test_recorder_writes_any_source_and_refuses_out_of_order(tmp_path):
    from phonepose.errors import SessionContentError
    from phonepose.record.recorder import Recorder

    src = _ListSource([_log_record(T0_NS + k * 1000, str(k)) for k in range(5)])
    res = Recorder(src, tmp_path / "ok.mcap").run()
    assert res.messages == 5 and not res.interrupted and src.closed
    with SessionReader(tmp_path / "ok.mcap") as r:
        assert [m.msg.message for m in r.messages()] == ["0", "1", "2", "3", "4"]
    bad = _ListSource([_log_record(T0_NS + 10), _log_record(T0_NS + 5)])
    with pytest.raises(SessionContentError, match="out of log-time order"):
        Recorder(bad, tmp_path / "bad.mcap").run()


def test_recorder_stop_finishes_a_valid_file(tmp_path):
    from phonepose.record.recorder import Recorder

    class Stopping(_ListSource):
        def __iter__(self):
            for k, rec in enumerate(self._records):
                if k == 3:
                    recorder.stop()          # what the SIGINT/SIGTERM handler does
                yield rec

    src = Stopping([_log_record(T0_NS + k) for k in range(10)])
    recorder = Recorder(src, tmp_path / "stopped.mcap")
    res = recorder.run()
    assert res.interrupted and res.messages == 3
    with SessionReader(tmp_path / "stopped.mcap") as r:
        assert r.summary().message_count == 3


def test_unwritable_rerun_path_is_an_output_error(tmp_path):
    from phonepose.errors import OutputError
    from phonepose.record.recorder import Recorder

    with pytest.raises(OutputError, match="cannot write"):     # the sink's own failure
        Recorder(_ListSource([]), tmp_path / "x.mcap", rerun_path=tmp_path / "missing" / "x.rrd").run()
    (tmp_path / "x.mcap").unlink(missing_ok=True)
    with pytest.raises(OutputError) as e:       # record_sim checks first (phonepose.files) and creates nothing
        record_sim(tmp_path / "x.mcap", rerun_path=tmp_path / "missing" / "x.rrd")
    assert str(e.value) == f"rerun {tmp_path / 'missing' / 'x.rrd'}: directory {tmp_path / 'missing'} does not exist"
    assert list(tmp_path.iterdir()) == []


def test_rerun_file_is_written(tmp_path):
    rrd = tmp_path / "s.rrd"
    record_sim(tmp_path / "s.mcap", scenario="exp2", path="TRI1", seed=0,
               config=default_config().replace(camera=dict(rate_hz=2.0)), rerun_path=rrd)
    data = rrd.read_bytes()
    assert len(data) > 100_000 and data[:4] == b"RRF2"
