"""Every topic and frame name of a phonepose session, and the message type on each topic.

This is the only module that spells topic and frame names; everything else imports them.
See docs/format.md for what each topic carries.
"""

from __future__ import annotations

from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from google.protobuf.message import Message

from phonepose.schemas import phonepose_pb2 as pb


class Frame:
    """Coordinate frame ids (``frame_id`` fields, Rerun frame names)."""

    WORLD = "world"                    # motion capture
    GT_WORLD = "gt_world"              # a WebXR headset's stationary reference space, z up (phonepose/record/live/webxr.py)
    DISPLAY_VIO = "display_vio"        # the display device's VIO world; trackers report here
    CONTROLLER_VIO = "controller_vio"  # the controller's own VIO world
    DISPLAY = "display"                # display device body
    DISPLAY_CAMERA = "display_camera"  # OpenCV optical: x right, y down, z forward
    CONTROLLER = "controller"          # phone body of the controller
    MARKER = "marker"                  # the ArUco marker on the controller's screen
    ANCHOR = "anchor"                  # the shared (cloud) anchor


class Topic:
    """Topic names. ``TRACKER_POSE`` is a template: use :func:`tracker_pose_topic`."""

    CAMERA_IMAGE = "/display/camera/image"
    CAMERA_CALIBRATION = "/display/camera/calibration"
    CAMERA_EXTRINSICS = "/display/camera/extrinsics"   # display -> display_camera (static)
    DISPLAY_VIO_POSE = "/display/vio/pose"
    DISPLAY_ANCHOR = "/display/anchor"
    CONTROLLER_VIO_POSE = "/controller/vio/pose"
    CONTROLLER_ANCHOR = "/controller/anchor"
    CONTROLLER_IMU = "/controller/imu"
    CONTROLLER_MARKER = "/controller/marker"
    GT_CONTROLLER_POSE = "/gt/controller/pose"
    GT_DISPLAY_POSE = "/gt/display/pose"
    GT_BOARD_CONTROLLER_POSE = "/gt/board_controller/pose"   # a headset's other controller (the paper's R-sensor)
    GT_HEADSET_POSE = "/gt/headset/pose"                       # a headset's viewer
    GT_CALIBRATION = "/gt/calibration"                 # world -> display_vio
    CALIBRATION_EVENTS = "/events/calibration"
    EXPERIMENT_TARGETS = "/experiment/targets"
    EXPERIMENT_PATH = "/experiment/path"
    SESSION_INFO = "/session/info"
    LOG = "/log"
    # the frame tree (phonepose.viewer.frames): each topic places its child frame in its parent
    TF_DISPLAY = "/tf/display"                         # display_vio -> display (from /display/vio/pose)
    TF_CONTROLLER_VIO = "/tf/controller_vio"           # display_vio -> controller_vio (from the two anchors)
    TF_CONTROLLER = "/tf/controller"                   # controller_vio -> controller (from /controller/vio/pose)
    TF_MARKER = "/tf/marker"                           # controller -> marker (from /controller/marker, static)
    CONTROLLER_MARKER_OUTLINE = "/controller/marker/outline"   # the marker square as points, in frame marker
    CAMERA_FRUSTUM = "/display/camera/frustum"         # the camera's view as points, in frame display_camera
    # playback output
    PIPELINE_MARKERS = "/pipeline/markers"
    PIPELINE_MARKER_ANNOTATIONS = "/pipeline/markers/annotations"   # the same detections for Foxglove's Image panel
    TRACKER_POSE = "/trackers/{name}/pose"


def tracker_pose_topic(name: str) -> str:
    return Topic.TRACKER_POSE.format(name=name)


# Message type of every fixed topic. Tracker pose topics are PoseInFrame.
TOPIC_TYPES: dict[str, type[Message]] = {
    Topic.CAMERA_IMAGE: CompressedImage,
    Topic.CAMERA_CALIBRATION: CameraCalibration,
    Topic.CAMERA_EXTRINSICS: FrameTransform,
    Topic.DISPLAY_VIO_POSE: PoseInFrame,
    Topic.DISPLAY_ANCHOR: PoseInFrame,
    Topic.CONTROLLER_VIO_POSE: PoseInFrame,
    Topic.CONTROLLER_ANCHOR: PoseInFrame,
    Topic.CONTROLLER_IMU: pb.Imu,
    Topic.CONTROLLER_MARKER: pb.MarkerSpec,
    Topic.GT_CONTROLLER_POSE: PoseInFrame,
    Topic.GT_DISPLAY_POSE: PoseInFrame,
    Topic.GT_BOARD_CONTROLLER_POSE: PoseInFrame,
    Topic.GT_HEADSET_POSE: PoseInFrame,
    Topic.GT_CALIBRATION: FrameTransform,
    Topic.CALIBRATION_EVENTS: pb.CalibrationEvent,
    Topic.EXPERIMENT_TARGETS: pb.Targets,
    Topic.EXPERIMENT_PATH: pb.PathSpec,
    Topic.SESSION_INFO: pb.SessionInfo,
    Topic.LOG: Log,
    Topic.TF_DISPLAY: FrameTransform,
    Topic.TF_CONTROLLER_VIO: FrameTransform,
    Topic.TF_CONTROLLER: FrameTransform,
    Topic.TF_MARKER: FrameTransform,
    Topic.CONTROLLER_MARKER_OUTLINE: PointCloud,
    Topic.CAMERA_FRUSTUM: PointCloud,
    Topic.PIPELINE_MARKERS: pb.MarkerDetections,
    Topic.PIPELINE_MARKER_ANNOTATIONS: ImageAnnotations,
}


def message_type_for(topic: str) -> type[Message]:
    if topic in TOPIC_TYPES:
        return TOPIC_TYPES[topic]
    if topic.startswith("/trackers/") and topic.endswith("/pose"):
        return PoseInFrame
    raise KeyError(topic)
