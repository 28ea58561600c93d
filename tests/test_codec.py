"""phonepose.session.codec: protobuf <-> Pose, and the rules for a pose in a message (docs/format.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.Pose_pb2 import Pose as FgPose
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from hypothesis import given
from hypothesis import strategies as st

from phonepose.geometry import QUAT_NORM_TOL, Pose
from phonepose.schemas import phonepose_pb2 as pb
from phonepose.schemas.topics import Frame
from phonepose.session import codec

finite = st.floats(-10, 10, allow_nan=False)
quat = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1)
poses = st.builds(lambda t, q: Pose.from_xyzw(t, q), st.tuples(finite, finite, finite), quat)


def _fg(position=None, orientation=None) -> FgPose:
    msg = FgPose()
    if position is not None:
        msg.position.x, msg.position.y, msg.position.z = position
    if orientation is not None:
        msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = orientation
    return msg


@given(poses)
def test_pose_round_trips_through_every_message(p):
    assert codec.pose_of(codec.encode_pose(p)).allclose(p, atol=1e-12)
    assert Pose.from_raw(codec.raw_pose(codec.encode_pose(p))).allclose(p, atol=1e-12)
    msg = PoseInFrame.FromString(codec.pose_in_frame(p, Frame.DISPLAY_VIO, 123).SerializeToString())
    assert msg.frame_id == Frame.DISPLAY_VIO and msg.timestamp.ToNanoseconds() == 123
    assert codec.pose_of(msg.pose).allclose(p, atol=1e-12)
    ft = FrameTransform.FromString(codec.frame_transform(p, Frame.WORLD, Frame.DISPLAY_VIO, 7).SerializeToString())
    assert (ft.parent_frame_id, ft.child_frame_id) == (Frame.WORLD, Frame.DISPLAY_VIO)
    assert codec.transform_of(ft).allclose(p, atol=1e-12)


def test_quaternion_order_is_xyzw_in_messages():
    p = Pose.from_xyzw([1, 2, 3], [0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4)])   # 90 deg about z
    fg = codec.encode_pose(p)
    assert (fg.orientation.z, fg.orientation.w) == pytest.approx((np.sin(np.pi / 4), np.cos(np.pi / 4)))
    assert codec.raw_pose(fg) == pytest.approx((0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4), 1, 2, 3))


def test_an_all_zero_quaternion_reads_as_identity_everywhere():
    """The protobuf default of an orientation nobody set: a stream sample, a static pose, a transform."""
    msg = _fg(position=(0.1, 0.2, 0.3), orientation=(0, 0, 0, 0))
    assert codec.raw_pose(msg) == (0.0, 0.0, 0.0, 1.0, 0.1, 0.2, 0.3)
    assert codec.pose_of(msg).allclose(Pose.from_xyzw([0.1, 0.2, 0.3], [0, 0, 0, 1]), atol=0)
    only_position = _fg(position=(0.1, 0.2, 0.3))          # orientation not even present
    assert codec.raw_pose(only_position) == (0.0, 0.0, 0.0, 1.0, 0.1, 0.2, 0.3)
    ft = FrameTransform()
    ft.translation.x = 2.0
    assert codec.transform_of(ft).allclose(Pose.from_xyzw([2, 0, 0], [0, 0, 0, 1]), atol=0)
    assert codec.transform_of(FrameTransform()).allclose(Pose.identity(), atol=0)   # an unset identity transform


def test_a_quaternion_within_the_tolerance_is_normalised_and_beyond_it_is_broken():
    near = 1.0 + 0.9 * QUAT_NORM_TOL
    raw = codec.raw_pose(_fg(orientation=(0, 0, 0, near)))
    assert raw[:4] == (0.0, 0.0, 0.0, 1.0)
    with pytest.raises(codec.BrokenPose) as e:
        codec.raw_pose(_fg(orientation=(0, 0, 0, 1.0 + 1.1 * QUAT_NORM_TOL)))
    assert e.value.reason == codec.BAD_VALUE
    assert e.value.detail == "quaternion is not unit length (|q| = 1.0011)"


@pytest.mark.parametrize("position, orientation", [
    ((math.nan, 0, 0), (0, 0, 0, 1)), ((0, math.inf, 0), (0, 0, 0, 1)), ((0, 0, 0), (math.nan, 0, 0, 1)),
    ((0, 0, 0), (0, 0, -math.inf, 0)),
])
def test_nan_or_inf_anywhere_is_broken(position, orientation):
    msg = _fg(position, orientation)
    for decode in (codec.raw_pose, codec.pose_of):
        with pytest.raises(codec.BrokenPose) as e:
            decode(msg)
        assert (e.value.reason, e.value.detail) == (codec.BAD_VALUE, "has NaN/inf values")


def test_finite_values_whose_squares_overflow_are_a_non_unit_quaternion_not_nan():
    with pytest.raises(codec.BrokenPose) as e:
        codec.pose_of(_fg((0, 0, 0), (1e200, 0, 0, 0)))
    assert e.value.detail == "quaternion is not unit length (|q| = 1e+200)"


def test_a_pose_without_position_and_orientation_is_broken():
    """A PoseInFrame without its pose, an empty pose, an event without its pose: a broken sample."""
    for msg in (PoseInFrame().pose, _fg(), pb.CalibrationEvent(kind=pb.CalibrationEvent.CM1).pose_fix_vio):
        for decode in (codec.raw_pose, codec.pose_of):
            with pytest.raises(codec.BrokenPose) as e:
                decode(msg)
            assert e.value.reason == codec.NO_POSE
    # a static pose with a meaningful default may be left unset
    assert codec.pose_of(_fg(), required=False).allclose(Pose.identity(), atol=0)


@pytest.mark.parametrize("other", [
    pb.Imu(frame_id=Frame.CONTROLLER, gyro_x=0.1, accel_y=9.81),
    pb.CalibrationEvent(kind=pb.CalibrationEvent.CM2),
    Log(level=Log.INFO, name="phonepose", file="x.py", line=3),
])
def test_another_messages_bytes_under_the_pose_schema_are_broken_not_identity(other):
    other.timestamp.FromNanoseconds(5)
    decoded = PoseInFrame.FromString(other.SerializeToString())
    with pytest.raises(codec.BrokenPose) as e:
        codec.raw_pose(decoded.pose)
    assert e.value.reason == codec.NO_POSE


def test_stamps_and_imu_rows_fall_back_to_the_log_time():
    imu = pb.Imu(gyro_x=0.1, gyro_y=0.2, gyro_z=0.3, accel_x=1.0, accel_y=2.0, accel_z=3.0)
    assert codec.imu_row(imu, 2_500_000_000) == (2.5, 0.1, 0.2, 0.3, 1.0, 2.0, 3.0)
    imu.timestamp.FromNanoseconds(1_000_000_000)
    assert codec.stamp_ns(imu, 99) == 1_000_000_000
    assert codec.imu_row(imu, 2_500_000_000)[0] == 1.0
