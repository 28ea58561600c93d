"""A tiny hand-made session with one message of every type (tests, docs, ``data/sample.mcap``).

Regenerate the checked-in sample with ``python -m phonepose.testing.sample data/sample.mcap``.
A fixture: production code never imports phonepose.testing (tests/test_imports.py).
"""

from __future__ import annotations

import sys

import cv2
import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation
from google.protobuf.message import Message

from phonepose.geometry import Pose
from phonepose.schemas import phonepose_pb2 as pb
from phonepose.schemas.topics import Frame, Topic, tracker_pose_topic
from phonepose.session.codec import encode_pose, frame_transform, pose_in_frame
from phonepose.topics import tracker_frame
from phonepose.viewer.frames import FrameTree

T0_NS = 1_700_000_000_000_000_000


def _stamp(msg, t_ns: int) -> None:
    msg.timestamp.FromNanoseconds(t_ns)


def sample_messages(t0_ns: int = T0_NS) -> list[tuple[str, Message, int]]:
    """(topic, message, log_time_ns) for every topic type of a session."""
    p = Pose.from_xyzw([0.1, -0.2, 0.3], [0.0, 0.0, np.sin(0.25), np.cos(0.25)])
    img = np.full((48, 64), 200, np.uint8)
    img[10:30, 20:40] = 30
    ok, jpeg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    image = CompressedImage(frame_id=Frame.DISPLAY_CAMERA, format="jpeg", data=jpeg.tobytes())
    _stamp(image, t0_ns)
    calib = CameraCalibration(frame_id=Frame.DISPLAY_CAMERA, width=640, height=480, distortion_model="plumb_bob",
                              D=[0.1, -0.2, 0.0, 0.0, 0.05], K=[500, 0, 319.5, 0, 500, 239.5, 0, 0, 1],
                              R=[1, 0, 0, 0, 1, 0, 0, 0, 1], P=[500, 0, 319.5, 0, 0, 500, 239.5, 0, 0, 0, 1, 0])
    _stamp(calib, t0_ns)
    imu = pb.Imu(frame_id=Frame.CONTROLLER, gyro_x=0.1, gyro_y=-0.2, gyro_z=0.3, accel_x=0.0, accel_y=9.81, accel_z=0.1)
    _stamp(imu, t0_ns)
    spec = pb.MarkerSpec(dictionary="DICT_4X4_50", id=7, size_m=0.05)
    _stamp(spec, t0_ns)
    encode_pose(p, spec.pose_in_body)
    det = pb.MarkerDetections(frame_id=Frame.DISPLAY_CAMERA)
    _stamp(det, t0_ns)
    d = det.detections.add(id=7, corners_px=[1, 2, 3, 4, 5, 6, 7, 8], reprojection_error_px=0.1, chosen_solution=1,
                           ambiguity_ratio=3.5)
    encode_pose(p, d.pose_in_camera)
    encode_pose(p.inv(), d.controller_in_display_vio)
    ev = pb.CalibrationEvent(kind=pb.CalibrationEvent.CM1, frame_id=Frame.DISPLAY_VIO)
    _stamp(ev, t0_ns)
    ev.fix_timestamp.FromNanoseconds(t0_ns - 5)
    encode_pose(p, ev.pose_fix_vio)
    encode_pose(p.inv(), ev.pose_align_vio)
    targets = pb.Targets(frame_id=Frame.DISPLAY_VIO, cube_size_m=0.02, select_radius_m=0.02)
    _stamp(targets, t0_ns)
    tg = targets.targets.add(index=0, inside_view=True)
    tg.hold_start.FromNanoseconds(t0_ns + 1)
    tg.hold_end.FromNanoseconds(t0_ns + 5_000_000_000)
    encode_pose(p, tg.pose)
    path = pb.PathSpec(frame_id=Frame.DISPLAY_VIO, name="TRI2", trial=1, closed=True)
    _stamp(path, t0_ns)
    for x, y in [(0, 0), (0.1, 0), (0.05, 0.1)]:
        path.waypoints.add(x=x, y=y, z=0.3)
    info = pb.SessionInfo(source="sample", scenario="sample", seed=0, phonepose_version="sample",
                          description="one message of every type")
    info.task_start.FromNanoseconds(t0_ns)
    info.task_end.FromNanoseconds(t0_ns + 10_000_000_000)
    _stamp(info, t0_ns)
    log = Log(level=Log.INFO, message="sample session", name="phonepose")
    _stamp(log, t0_ns)
    out = [
        (Topic.SESSION_INFO, info, t0_ns),
        (Topic.CAMERA_CALIBRATION, calib, t0_ns),
        (Topic.CAMERA_EXTRINSICS, frame_transform(Pose.identity(), Frame.DISPLAY, Frame.DISPLAY_CAMERA, t0_ns), t0_ns),
        (Topic.CAMERA_IMAGE, image, t0_ns),
        (Topic.DISPLAY_VIO_POSE, pose_in_frame(p, Frame.DISPLAY_VIO, t0_ns), t0_ns),
        (Topic.DISPLAY_ANCHOR, pose_in_frame(p, Frame.DISPLAY_VIO, t0_ns), t0_ns),
        (Topic.CONTROLLER_VIO_POSE, pose_in_frame(p.inv(), Frame.CONTROLLER_VIO, t0_ns), t0_ns),
        (Topic.CONTROLLER_ANCHOR, pose_in_frame(p, Frame.CONTROLLER_VIO, t0_ns), t0_ns),
        (Topic.CONTROLLER_IMU, imu, t0_ns),
        (Topic.CONTROLLER_MARKER, spec, t0_ns),
        (Topic.GT_CONTROLLER_POSE, pose_in_frame(p, Frame.WORLD, t0_ns), t0_ns),
        (Topic.GT_DISPLAY_POSE, pose_in_frame(p, Frame.WORLD, t0_ns), t0_ns),
        (Topic.GT_BOARD_CONTROLLER_POSE, pose_in_frame(p, Frame.GT_WORLD, t0_ns), t0_ns),
        (Topic.GT_HEADSET_POSE, pose_in_frame(p.inv(), Frame.GT_WORLD, t0_ns), t0_ns),
        (Topic.GT_CALIBRATION, frame_transform(p, Frame.WORLD, Frame.DISPLAY_VIO, t0_ns), t0_ns),
        (Topic.CALIBRATION_EVENTS, ev, t0_ns),
        (Topic.EXPERIMENT_TARGETS, targets, t0_ns),
        (Topic.EXPERIMENT_PATH, path, t0_ns),
        (Topic.LOG, log, t0_ns),
        (Topic.PIPELINE_MARKERS, det, t0_ns),
        (tracker_pose_topic("T7"), pose_in_frame(p, Frame.DISPLAY_VIO, t0_ns), t0_ns),
        (Topic.TF_TRACKERS, frame_transform(p, Frame.DISPLAY_VIO, tracker_frame("T7"), t0_ns), t0_ns),
    ]
    # the frame tree the recorder writes beside these (/tf/..., the marker and camera point clouds)
    tree = FrameTree()
    out += [(topic, msg, t) for source, m, t in list(out) for topic, msg in tree.derive(source, m, t)]
    ann = ImageAnnotations()
    _stamp(ann, t0_ns)
    loop = ann.points.add(type=PointsAnnotation.LINE_LOOP, thickness=2.0)
    _stamp(loop, t0_ns)
    for x, y in zip(det.detections[0].corners_px[0::2], det.detections[0].corners_px[1::2], strict=True):
        loop.points.add(x=x, y=y)
    out.append((Topic.PIPELINE_MARKER_ANNOTATIONS, ann, t0_ns))
    return out


def write_sample(path) -> None:
    from phonepose.session import SessionWriter

    with SessionWriter(path) as w:
        for i, (topic, msg, t) in enumerate(sample_messages()):
            w.write(topic, msg, t + i * 1000)


if __name__ == "__main__":
    write_sample(sys.argv[1] if len(sys.argv) > 1 else "data/sample.mcap")
