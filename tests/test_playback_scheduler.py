"""The tick scheduler on hand-made streams: interpolation, frame choice, IMU/event partition, GT association."""

from __future__ import annotations

import numpy as np
import pytest
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from scipy.spatial.transform import Rotation

from phonepose.errors import SessionContentError
from phonepose.geometry import Pose
from phonepose.pipeline.types import CalibrationEvent, CalibrationKind
from phonepose.playback.scheduler import PoseStream, TickScheduler, calibration_event
from phonepose.schemas import phonepose_pb2 as pb
from phonepose.schemas.topics import Frame, Topic
from phonepose.session import SessionReader, SessionWriter
from phonepose.session.codec import encode_pose, frame_transform, pose_in_frame
from phonepose.session.context import read_context

T0 = 1_700_000_000_000_000_000
MS = 1_000_000
T_WORLD_DVIO = Pose.from_xyzw([1.0, -2.0, 0.3], Rotation.from_euler("z", 90, degrees=True).as_quat())


def ctrl_pose(t_s: float) -> Pose:
    """Linear in time: exactly what linear + slerp interpolation reproduces."""
    return Pose(Rotation.from_rotvec([0.0, 0.0, 0.2 * t_s]), np.array([t_s, 2.0 * t_s, -0.5 * t_s]))


def display_pose(t_s: float) -> Pose:
    return Pose(Rotation.from_rotvec([0.1 * t_s, 0.0, 0.0]), np.array([0.0, t_s, 0.0]))


def write_streams(path, *, duration_ms=1000, camera_ms=33, ctrl_ms=40, display_ms=30, gt_ms=10, imu_ms=5,
                  gt_gap_ms=None, ctrl_until_ms=None, events_ms=(100, 100, 457), camera=True, gt=True):
    msgs = []

    def add(t_ns, topic, msg):
        msgs.append((t_ns, topic, msg))

    info = pb.SessionInfo(source="test")
    info.task_start.FromNanoseconds(T0 + 200 * MS)
    info.task_end.FromNanoseconds(T0 + 800 * MS)
    add(T0, Topic.SESSION_INFO, info)
    if camera:
        add(T0, Topic.CAMERA_CALIBRATION, CameraCalibration(width=64, height=48, K=[50, 0, 32, 0, 50, 24, 0, 0, 1],
                                                            D=[0, 0, 0, 0, 0]))
        add(T0, Topic.CONTROLLER_MARKER, pb.MarkerSpec(dictionary="DICT_4X4_50", id=1, size_m=0.05))
        for t in range(5, duration_ms + 1, camera_ms):
            img = CompressedImage(frame_id=Frame.DISPLAY_CAMERA, format="jpeg", data=b"x%d" % t)
            add(T0 + t * MS, Topic.CAMERA_IMAGE, img)
        for t in range(0, duration_ms + 1, display_ms):
            add(T0 + t * MS, Topic.DISPLAY_VIO_POSE, pose_in_frame(display_pose(t / 1000), Frame.DISPLAY_VIO, T0 + t * MS))
    if gt:
        add(T0, Topic.GT_CALIBRATION, frame_transform(T_WORLD_DVIO, Frame.WORLD, Frame.DISPLAY_VIO, T0))
        for t in range(0, duration_ms + 1, gt_ms):
            if gt_gap_ms and gt_gap_ms[0] < t < gt_gap_ms[1]:
                continue
            add(T0 + t * MS, Topic.GT_CONTROLLER_POSE, pose_in_frame(T_WORLD_DVIO @ ctrl_pose(t / 1000), Frame.WORLD,
                                                                     T0 + t * MS))
    for t in range(2, duration_ms + 1, ctrl_ms):
        if ctrl_until_ms is not None and t > ctrl_until_ms:
            break
        add(T0 + t * MS, Topic.CONTROLLER_VIO_POSE, pose_in_frame(ctrl_pose(t / 1000), Frame.CONTROLLER_VIO, T0 + t * MS))
    add(T0 + 50 * MS, Topic.DISPLAY_ANCHOR, pose_in_frame(Pose.identity(), Frame.DISPLAY_VIO, T0 + 50 * MS))
    add(T0 + 60 * MS, Topic.CONTROLLER_ANCHOR, pose_in_frame(Pose.identity(), Frame.CONTROLLER_VIO, T0 + 60 * MS))
    add(T0 + 300 * MS, Topic.DISPLAY_ANCHOR,
        pose_in_frame(Pose.from_xyzw([1, 0, 0], [0, 0, 0, 1]), Frame.DISPLAY_VIO, T0 + 300 * MS))
    if imu_ms:
        for t in range(1, duration_ms + 1, imu_ms):
            m = pb.Imu(gyro_x=float(t))
            m.timestamp.FromNanoseconds(T0 + t * MS)
            add(T0 + t * MS, Topic.CONTROLLER_IMU, m)
    for i, t in enumerate(events_ms):
        ev = pb.CalibrationEvent(kind=pb.CalibrationEvent.CM1 if i % 2 == 0 else pb.CalibrationEvent.CM2)
        ev.timestamp.FromNanoseconds(T0 + t * MS)
        add(T0 + t * MS, Topic.CALIBRATION_EVENTS, ev)
    msgs.sort(key=lambda m: m[0])
    with SessionWriter(path) as w:
        for t, topic, msg in msgs:
            w.write(topic, msg, t)


def ticks_of(path, **kw):
    with SessionReader(path) as r:
        ctx = read_context(r)
        sched = TickScheduler(r, ctx, **kw)
        ticks = list(sched)
        assert len(ticks) == len(sched)
        return ticks, sched


def truth_of(path, **kw):
    with SessionReader(path) as r:
        return list(TickScheduler(r, read_context(r), **kw).with_truth())


@pytest.fixture
def session(tmp_path):
    p = tmp_path / "s.mcap"
    write_streams(p)
    return p


def test_grid_starts_at_first_camera_frame_and_covers_the_session(session):
    ticks, sched = ticks_of(session)
    assert ticks[0].t_ns == T0 + 5 * MS
    assert [t.index for t in ticks] == list(range(len(ticks)))
    assert all(b.t_ns - a.t_ns == 50 * MS for a, b in zip(ticks, ticks[1:], strict=False))
    assert ticks[-1].t_ns <= T0 + 1000 * MS < ticks[-1].t_ns + 50 * MS


def test_controller_vio_interpolated_exactly_at_the_tick(session):
    ticks, _ = ticks_of(session)
    for tick in ticks:
        t = (tick.t_ns - T0) / 1e9
        if t < 0.002 or t > 0.962:    # before the first / after the last controller sample
            continue
        assert tick.T_cvio_controller.allclose(ctrl_pose(t), atol=1e-9), t


def test_newest_frame_at_or_before_and_display_at_its_stamp(session):
    ticks, _ = ticks_of(session)
    frames = np.arange(5, 1001, 33)
    prev = None
    for tick in ticks:
        t_ms = (tick.t_ns - T0) / MS
        expect = frames[frames <= t_ms].max()
        assert tick.frame.t_ns == T0 + int(expect) * MS
        assert tick.frame.data == b"x%d" % expect and tick.frame.format == "jpeg"
        assert tick.frame.is_new == (tick.frame.t_ns != prev)
        prev = tick.frame.t_ns
        assert tick.T_dvio_display.allclose(display_pose(expect / 1000), atol=1e-9)
        assert tick.frame.T_dvio_display is tick.T_dvio_display


def test_imu_rows_partition_exactly_across_ticks(session):
    ticks, _ = ticks_of(session)
    all_rows = np.vstack([t.imu for t in ticks])
    stamps_ms = np.arange(1, 1001, 5)
    last = (ticks[-1].t_ns - T0) / MS
    np.testing.assert_array_equal(all_rows[:, 1], stamps_ms[stamps_ms <= last].astype(float))
    prev_ms = -np.inf
    for tick in ticks:
        t_ms = (tick.t_ns - T0) / MS
        g = tick.imu[:, 1]
        assert np.all((g > prev_ms) & (g <= t_ms))
        assert tick.imu.shape[1] == 7
        prev_ms = t_ms


def test_events_delivered_once_at_the_first_tick_at_or_after_them(session):
    ticks, _ = ticks_of(session)
    got = [((t.t_ns - T0) // MS, (e.t_ns - T0) // MS, (e.log_time_ns - T0) // MS, e.kind) for t in ticks for e in t.events]
    assert got == [(105, 100, 100, CalibrationKind.CM1), (105, 100, 100, CalibrationKind.CM2),
                   (505, 457, 457, CalibrationKind.CM1)]
    assert all(isinstance(e, CalibrationEvent) and e.pose_fix_vio is None for t in ticks for e in t.events)


def test_calibration_kinds_are_the_schemas_numbers():
    """A tracker that compares ``kind`` with the schema's enum (``pb.CalibrationEvent.CM1``) reads the same."""
    assert {k.name: int(k) for k in CalibrationKind} == \
        {name.removeprefix("KIND_"): number for name, number in pb.CalibrationEvent.Kind.items()}


@pytest.mark.parametrize("seed", range(6))
def test_a_calibration_event_is_decoded_into_plain_values(seed):
    """What a tracker reads of an event is the message's content as phonepose types, by the codec's rules."""
    rng = np.random.default_rng(seed)
    fix, align = (Pose.from_rotvec(rng.uniform(-3, 3, 3), rng.uniform(-5, 5, 3)) for _ in range(2))
    stamp, fixed, log_time = (int(v) for v in rng.integers(1, 2**62, 3))
    kind = int(rng.integers(0, 6))            # 3..5: kinds this version does not know, passed on as numbers
    msg = pb.CalibrationEvent(kind=kind, frame_id=Frame.DISPLAY_VIO)  # type: ignore[arg-type]
    msg.timestamp.FromNanoseconds(stamp)
    msg.fix_timestamp.FromNanoseconds(fixed)
    encode_pose(fix, msg.pose_fix_vio)
    encode_pose(align, msg.pose_align_vio)
    ev = calibration_event(msg, log_time)
    assert (ev.kind, type(ev.kind) is CalibrationKind) == (kind, kind < 3)
    assert (ev.t_ns, ev.log_time_ns, ev.fix_t_ns, ev.frame_id) == (stamp, log_time, fixed, Frame.DISPLAY_VIO)
    assert ev.pose_fix_vio.allclose(fix, atol=1e-12) and ev.pose_align_vio.allclose(align, atol=1e-12)
    # unset stamps: the log time, no fix time; an unset or broken pose: None
    bare = pb.CalibrationEvent(kind=pb.CalibrationEvent.CM1)
    bare.pose_align_vio.position.x = float(rng.choice([np.nan, np.inf]))
    ev = calibration_event(bare, log_time)
    assert (ev.t_ns, ev.fix_t_ns, ev.pose_fix_vio, ev.pose_align_vio) == (log_time, None, None, None)


def test_latest_anchor_at_or_before_the_tick(session):
    ticks, _ = ticks_of(session)
    for tick in ticks:
        t_ms = (tick.t_ns - T0) / MS
        if t_ms < 50:
            assert tick.T_dvio_anchor is None
        elif t_ms < 300:
            assert tick.T_dvio_anchor.allclose(Pose.identity())
        else:
            assert np.allclose(tick.T_dvio_anchor.translation, [1, 0, 0])
        assert (tick.T_cvio_anchor is None) == (t_ms < 60)


def test_gt_associated_within_tolerance_and_in_display_vio(tmp_path):
    p = tmp_path / "gap.mcap"
    write_streams(p, gt_gap_ms=(390, 460))   # samples at 390 and 460: ticks at 405 and 455 are > 20 ms away
    pairs = truth_of(p)
    assert pairs
    for tick, gt in pairs:
        assert not hasattr(tick, "gt_T_dvio_controller")   # trackers cannot reach the GT
        t_ms = (tick.t_ns - T0) / MS
        if t_ms in (405, 455):
            assert gt is None
        else:
            assert gt.allclose(ctrl_pose(t_ms / 1000), atol=1e-9)


def test_in_task_from_the_session_window(session):
    ticks, _ = ticks_of(session)
    for tick in ticks:
        t_ms = (tick.t_ns - T0) / MS
        assert tick.in_task == (200 <= t_ms <= 800)


def test_start_end_select_grid_ticks(session):
    ticks, _ = ticks_of(session, start_s=0.3, end_s=0.6)
    assert [(t.t_ns - T0) // MS for t in ticks] == [305, 355, 405, 455, 505, 555]
    # state from before the start is there: anchors, the newest frame, the events
    assert ticks[0].T_dvio_anchor is not None and ticks[0].frame is not None
    assert len(ticks[0].events) == 2


def test_rate_option(session):
    ticks, _ = ticks_of(session, rate_hz=10)
    assert all(b.t_ns - a.t_ns == 100 * MS for a, b in zip(ticks, ticks[1:], strict=False))


def test_no_camera_grid_from_controller_vio_and_no_gt(tmp_path):
    p = tmp_path / "nocam.mcap"
    write_streams(p, camera=False, gt=False, imu_ms=0)
    ticks, sched = ticks_of(p)
    assert ticks[0].t_ns == T0 + 2 * MS
    assert all(t.frame is None and t.imu.shape == (0, 7) for t in ticks)
    assert all(gt is None for _, gt in truth_of(p))


def test_controller_stream_ending_early_does_not_stall(tmp_path):
    p = tmp_path / "short.mcap"
    write_streams(p, ctrl_until_ms=300)
    ticks, _ = ticks_of(p)
    assert (ticks[-1].t_ns - T0) // MS == 955
    for tick in ticks:
        t_ms = (tick.t_ns - T0) / MS
        last = 282  # last controller sample
        if t_ms <= last:
            continue
        if t_ms - last <= 500:
            assert tick.T_cvio_controller.allclose(ctrl_pose(last / 1000))   # held
        else:
            assert tick.T_cvio_controller is None


def test_no_controller_vio_is_a_session_content_error(tmp_path):
    p = tmp_path / "none.mcap"
    with SessionWriter(p) as w:
        w.write(Topic.SESSION_INFO, pb.SessionInfo(source="x"), T0)
    with SessionReader(p) as r, pytest.raises(SessionContentError, match="controller VIO"):
        read_context(r)


def test_images_without_calibration_is_a_session_content_error(tmp_path):
    p = tmp_path / "nocal.mcap"
    with SessionWriter(p) as w:
        w.write(Topic.CAMERA_IMAGE, CompressedImage(format="jpeg", data=b"x"), T0)
        w.write(Topic.CONTROLLER_VIO_POSE, pose_in_frame(Pose.identity(), Frame.CONTROLLER_VIO, T0), T0)
    with SessionReader(p) as r, pytest.raises(SessionContentError, match="camera calibration"):
        read_context(r)


def test_pose_stream_rules():
    s = PoseStream()
    s.add(100, Pose.from_xyzw([0, 0, 0], [0, 0, 0, 1]))
    s.add(200, Pose.from_xyzw([1, 0, 0], [0, 0, 0, 1]))
    assert s.at(50, 1000) is None
    assert np.allclose(s.at(150, 1000).translation, [0.5, 0, 0])
    assert np.allclose(s.at(200, 1000).translation, [1, 0, 0])
    assert np.allclose(s.at(250, 1000).translation, [1, 0, 0])   # held
    assert s.at(250, 10) is None                                    # too old
    assert s.associate(150, 50) is not None and s.associate(150, 49) is None
    s.prune(210)
    assert list(s.times) == [200]


def test_start_past_the_end_is_a_config_error(session):
    from phonepose.errors import ConfigError

    with pytest.raises(ConfigError, match="select no tick"):
        ticks_of(session, start_s=5.0)


def test_buffers_stay_small_over_a_long_pass(tmp_path, monkeypatch):
    """One streaming pass: the pose buffers hold a few samples, never the whole stream."""
    p = tmp_path / "long.mcap"
    write_streams(p, duration_ms=6000)
    sizes = []
    original = PoseStream.add

    def add(self, t_ns, pose):
        original(self, t_ns, pose)
        sizes.append(len(self.times))

    monkeypatch.setattr(PoseStream, "add", add)
    ticks, _ = ticks_of(p)
    assert len(ticks) == 120 and len(sizes) > 900     # 600 GT + 150 controller + 200 display samples
    assert max(sizes) <= 12                             # about one tick period of the 100 Hz GT
