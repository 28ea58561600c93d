"""The message type on each topic of a phonepose session; the names themselves are phonepose.topics's.

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
from phonepose.topics import Frame, Topic, tracker_pose_topic

__all__ = ["TOPIC_TYPES", "Frame", "Topic", "message_type_for", "tracker_pose_topic"]


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
    Topic.TF_TRACKERS: FrameTransform,
}


def message_type_for(topic: str) -> type[Message]:
    if topic in TOPIC_TYPES:
        return TOPIC_TYPES[topic]
    if topic.startswith("/trackers/") and topic.endswith("/pose"):
        return PoseInFrame
    raise KeyError(topic)
