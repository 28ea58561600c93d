"""A small hand-made session for playback tests and the benchmark fallback.

Not the simulator (phonepose/record/sim): a fixed display looks along +z; the controller moves
in front of it with its marker in view for the first part of the task, then off to the side.
VIO and anchors carry a known rigid anchor error, GT is exact. Every stream is optional so the
tests can drop GT, IMU or the marker.
"""

from __future__ import annotations

import os

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from google.protobuf.message import Message
from scipy.spatial.transform import Rotation

from phonepose.geometry import Pose
from phonepose.pipeline.types import MarkerModel
from phonepose.schemas import phonepose_pb2 as pb
from phonepose.schemas.topics import Frame, Topic
from phonepose.session import SessionWriter
from phonepose.session.codec import encode_pose, frame_transform, pose_in_frame
from phonepose.testing.marker_images import encode_jpeg, looking_at, pinhole_camera, render_marker

T0_NS = 1_700_000_000_000_000_000
MARKER = MarkerModel(dictionary="DICT_4X4_50", id=7, size_m=0.05, T_body_marker=Pose.identity())
T_WORLD_DVIO = Pose.from_xyzw([1.0, 2.0, 0.5], Rotation.from_euler("z", 30, degrees=True).as_quat())
T_DVIO_ANCHOR = Pose.from_xyzw([0.2, 0.0, 1.0], [0, 0, 0, 1])
ANCHOR_ERROR = Pose.from_xyzw([0.03, -0.02, 0.01], Rotation.from_euler("y", 2, degrees=True).as_quat())


def T_camera_marker_at(t_s: float, in_view_until_s: float) -> Pose:
    """The marker in the camera: circling in view, then sliding out to the side at 1 m/s."""
    a = 2 * np.pi * 0.5 * min(t_s, in_view_until_s)
    slide = max(0.0, t_s - in_view_until_s)
    return looking_at(0.45, tilt_deg=15 * np.sin(a), tilt_axis_deg=30,
                      offset_xy_m=(0.05 * np.cos(a) + slide, 0.04 * np.sin(a)))


def write_test_session(path: str | os.PathLike, *, duration_s: float = 3.0, camera_hz: float = 30.0, vio_hz: float = 30.0,
                       gt_hz: float = 60.0, imu_hz: float = 100.0, gt: bool = True, imu: bool = True, marker: bool = True,
                       camera: bool = True, width: int = 320, height: int = 240, in_view_fraction: float = 0.5,
                       t0_ns: int = T0_NS) -> None:
    cam = pinhole_camera(f=250.0 * width / 320, width=width, height=height)
    T_display_camera = Pose.identity()
    T_dvio_display = Pose.from_xyzw([0.0, 0.0, 0.0], [0, 0, 0, 1])
    in_view_until = duration_s * in_view_fraction
    T_cvio_anchor = Pose.from_xyzw([-0.5, 0.3, 0.2], Rotation.from_euler("y", 40, degrees=True).as_quat())
    # controller VIO: T_cvio_ctrl = T_cvio_anchor · (T_dvio_anchor · error)^-1 · T_dvio_ctrl  (anchor error)
    map_c = T_cvio_anchor @ (T_DVIO_ANCHOR @ ANCHOR_ERROR).inv()

    def ctrl_true(t_s: float) -> Pose:
        return T_dvio_display @ T_display_camera @ T_camera_marker_at(t_s, in_view_until) @ MARKER.T_body_marker.inv()

    msgs: list[tuple[int, str, Message]] = []

    def ns(t_s: float) -> int:
        return t0_ns + int(round(t_s * 1e9))

    info = pb.SessionInfo(source="test", scenario="playback-test", seed=0, phonepose_version="test",
                          description="hand-made playback test session")
    info.task_start.FromNanoseconds(ns(0.3))
    info.task_end.FromNanoseconds(ns(duration_s - 0.2))
    info.timestamp.FromNanoseconds(t0_ns)
    msgs.append((t0_ns, Topic.SESSION_INFO, info))
    if camera:
        calib = CameraCalibration(frame_id=Frame.DISPLAY_CAMERA, width=width, height=height, distortion_model="plumb_bob",
                                  D=[0.0] * 5, K=[float(v) for v in cam.K.reshape(-1)])
        calib.timestamp.FromNanoseconds(t0_ns)
        msgs.append((t0_ns, Topic.CAMERA_CALIBRATION, calib))
        msgs.append((t0_ns, Topic.CAMERA_EXTRINSICS,
                     frame_transform(T_display_camera, Frame.DISPLAY, Frame.DISPLAY_CAMERA, t0_ns)))
    spec = pb.MarkerSpec(dictionary=MARKER.dictionary, id=MARKER.id, size_m=MARKER.size_m)
    encode_pose(MARKER.T_body_marker, spec.pose_in_body)
    spec.timestamp.FromNanoseconds(t0_ns)
    msgs.append((t0_ns, Topic.CONTROLLER_MARKER, spec))
    if gt:
        msgs.append((t0_ns, Topic.GT_CALIBRATION, frame_transform(T_WORLD_DVIO, Frame.WORLD, Frame.DISPLAY_VIO, t0_ns)))
    msgs.append((ns(0.05), Topic.DISPLAY_ANCHOR, pose_in_frame(T_DVIO_ANCHOR, Frame.DISPLAY_VIO, ns(0.05))))
    msgs.append((ns(0.07), Topic.CONTROLLER_ANCHOR, pose_in_frame(T_cvio_anchor, Frame.CONTROLLER_VIO, ns(0.07))))
    blank = encode_jpeg(np.full((height, width), 110, np.uint8))
    if camera:
        for k in range(int(duration_s * camera_hz) + 1):
            t = k / camera_hz
            T_cm = T_camera_marker_at(t, in_view_until)
            if marker and T_cm.translation[0] < 0.5:
                data = encode_jpeg(render_marker(cam, MARKER, T_cm, supersample=2))
            else:
                data = blank
            img = CompressedImage(frame_id=Frame.DISPLAY_CAMERA, format="jpeg", data=data)
            img.timestamp.FromNanoseconds(ns(t))
            msgs.append((ns(t), Topic.CAMERA_IMAGE, img))
    for k in range(int(duration_s * vio_hz) + 1):
        t = (k + 0.5) / vio_hz
        if t > duration_s:
            break
        msgs.append((ns(t), Topic.DISPLAY_VIO_POSE, pose_in_frame(T_dvio_display, Frame.DISPLAY_VIO, ns(t))))
        msgs.append((ns(t) + 3_000_000, Topic.CONTROLLER_VIO_POSE,
                     pose_in_frame(map_c @ ctrl_true(t), Frame.CONTROLLER_VIO, ns(t))))
    if gt:
        for k in range(int(duration_s * gt_hz) + 1):
            t = k / gt_hz
            msgs.append((ns(t), Topic.GT_CONTROLLER_POSE, pose_in_frame(T_WORLD_DVIO @ ctrl_true(t), Frame.WORLD, ns(t))))
    if imu:
        for k in range(int(duration_s * imu_hz) + 1):
            t = k / imu_hz
            m = pb.Imu(frame_id=Frame.CONTROLLER, gyro_x=0.01 * k, gyro_y=0.0, gyro_z=0.1, accel_x=0.0, accel_y=9.81,
                       accel_z=0.0)
            m.timestamp.FromNanoseconds(ns(t))
            msgs.append((ns(t) + 2_000_000, Topic.CONTROLLER_IMU, m))
    # CM1 at 0.2 s (the user aligned the phone with a fixed CG object), CM2 at 0.25 s
    t_cm1 = 0.2
    ev = pb.CalibrationEvent(kind=pb.CalibrationEvent.CM1, frame_id=Frame.DISPLAY_VIO)
    ev.timestamp.FromNanoseconds(ns(t_cm1))
    ev.fix_timestamp.FromNanoseconds(ns(t_cm1 - 0.1))
    encode_pose(ctrl_true(t_cm1), ev.pose_fix_vio)
    encode_pose(T_DVIO_ANCHOR @ T_cvio_anchor.inv() @ map_c @ ctrl_true(t_cm1), ev.pose_align_vio)
    msgs.append((ns(t_cm1), Topic.CALIBRATION_EVENTS, ev))
    ev2 = pb.CalibrationEvent(kind=pb.CalibrationEvent.CM2, frame_id=Frame.DISPLAY_VIO)
    ev2.timestamp.FromNanoseconds(ns(0.25))
    msgs.append((ns(0.25), Topic.CALIBRATION_EVENTS, ev2))
    msgs.sort(key=lambda m: m[0])
    with SessionWriter(path) as w:
        for t, topic, msg in msgs:
            w.write(topic, msg, t)
