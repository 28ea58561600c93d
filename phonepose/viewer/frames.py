"""The frame tree of a session as Foxglove ``FrameTransform`` messages, so that Rerun's MCAP
importer and Foxglove's 3D panel place the display camera, the display and the phone as the
session is, without phonepose.

Tree (every frame has one parent; ``world`` only when the session has ``/gt/calibration``):

    world
    └── display_vio                    /gt/calibration (exists: motion capture to the display's VIO)
        ├── display                    /tf/display           from /display/vio/pose
        │   └── display_camera         /display/camera/extrinsics (exists, static)
        └── controller_vio             /tf/controller_vio    T_dvio_anchor · T_cvio_anchor⁻¹, from the two anchors
            └── controller             /tf/controller        from /controller/vio/pose
                └── marker             /tf/marker            from /controller/marker (static)

The bodies are placed by what the devices themselves knew (their VIO and the shared anchor), so
the tree exists in every session, with or without motion capture; the ground truth stays in the
``/gt/...`` PoseInFrame topics (frame ``world``), which Foxglove draws as poses in the same scene.
``/controller/marker/outline`` (a ``foxglove.PointCloud`` in frame ``marker``) draws the marker
square on the phone's screen and ``/display/camera/frustum`` (frame ``display_camera``) the
camera's view: Rerun's importer shows frames only through something drawn in them (a transform
alone draws nothing), and a point cloud is the one Foxglove geometry it maps.

The existing topics are kept as they are; these are written beside them (docs/format.md).
"""

from __future__ import annotations

import numpy as np
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from google.protobuf.message import Message

from phonepose.pipeline.types import camera_problem
from phonepose.schemas.topics import Frame, Topic
from phonepose.session import codec
from phonepose.session.codec import frame_transform

OUTLINE_STEP_M = 0.001         # point spacing along the marker square's outline
FRUSTUM_DEPTH_M = 0.1          # depth of the display camera's drawn frustum
# every topic FrameTree writes (derived from the session's own records, never from a source)
FRAME_TREE_TOPICS = frozenset({Topic.TF_DISPLAY, Topic.TF_CONTROLLER_VIO, Topic.TF_CONTROLLER, Topic.TF_MARKER,
                               Topic.CONTROLLER_MARKER_OUTLINE, Topic.CAMERA_FRUSTUM})


def _point_cloud(frame: str, pts: np.ndarray, t_ns: int) -> PointCloud:
    pts = np.asarray(pts, dtype=np.float32).reshape(-1, 3)
    msg = PointCloud(frame_id=frame, point_stride=12, data=pts.tobytes())
    msg.timestamp.FromNanoseconds(int(t_ns))
    msg.pose.orientation.w = 1.0
    msg.fields.extend(PackedElementField(name=name, offset=4 * i, type=PackedElementField.FLOAT32)
                      for i, name in enumerate("xyz"))
    return msg


def marker_outline(size_m: float, t_ns: int) -> PointCloud:
    """The marker's black square (side ``size_m``) as points every 1 mm, in frame ``marker``."""
    h = size_m / 2
    n = max(2, round(size_m / OUTLINE_STEP_M))
    s = np.linspace(-h, h, n, endpoint=False)
    edges = [np.column_stack([s, np.full(n, h)]), np.column_stack([np.full(n, h), -s]),
             np.column_stack([-s, np.full(n, -h)]), np.column_stack([np.full(n, -h), s])]
    xy = np.vstack(edges)
    return _point_cloud(Frame.MARKER, np.column_stack([xy, np.zeros(len(xy))]), t_ns)


def camera_frustum(K, width: int, height: int, t_ns: int) -> PointCloud:
    """The display camera's view as points every 2 mm along the edges of its frustum, out to
    ``FRUSTUM_DEPTH_M``, in frame ``display_camera``: Rerun's automatic framing fits what is
    drawn, so the camera is in view next to the phone (Foxglove draws its own from the calibration)."""
    K = np.asarray(K, dtype=float).reshape(3, 3)
    u = np.array([0.0, width, width, 0.0])
    v = np.array([0.0, 0.0, height, height])
    d = FRUSTUM_DEPTH_M
    corners = np.column_stack([(u - K[0, 2]) / K[0, 0] * d, (v - K[1, 2]) / K[1, 1] * d, np.full(4, d)])
    segments = [(np.zeros(3), c) for c in corners] + [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    pts = [a + (b - a) * f for a, b in segments
           for f in np.linspace(0.0, 1.0, max(2, int(np.linalg.norm(b - a) / (2 * OUTLINE_STEP_M))))]
    return _point_cloud(Frame.DISPLAY_CAMERA, np.asarray(pts), t_ns)


class FrameTree:
    """Derives the frame-tree messages from the session's own records, one record at a time.

    ``derive(topic, msg, log_time_ns)`` returns the ``(topic, message)`` pairs to write beside the
    record, at its log time (empty for every other topic). The recorder calls it for every record
    it writes; a conversion of an old file would call it for every message it copies.
    """

    def __init__(self) -> None:
        self._anchors: dict = {}

    def derive(self, topic: str, msg, log_time_ns: int) -> list[tuple[str, Message]]:
        """The frame-tree messages for this record; none for a broken pose (codec.BrokenPose)."""
        try:
            return self._derive(topic, msg, log_time_ns)
        except codec.BrokenPose:
            return []

    def _derive(self, topic: str, msg, log_time_ns: int) -> list[tuple[str, Message]]:
        if topic == Topic.DISPLAY_VIO_POSE:
            return [(Topic.TF_DISPLAY, frame_transform(codec.pose_of(msg.pose), Frame.DISPLAY_VIO, Frame.DISPLAY,
                                                       codec.stamp_ns(msg, log_time_ns)))]
        if topic == Topic.CONTROLLER_VIO_POSE:
            return [(Topic.TF_CONTROLLER, frame_transform(codec.pose_of(msg.pose), Frame.CONTROLLER_VIO,
                                                          Frame.CONTROLLER, codec.stamp_ns(msg, log_time_ns)))]
        if topic in (Topic.DISPLAY_ANCHOR, Topic.CONTROLLER_ANCHOR):
            self._anchors[topic] = codec.pose_of(msg.pose)
            if len(self._anchors) < 2:
                return []
            T = self._anchors[Topic.DISPLAY_ANCHOR] @ self._anchors[Topic.CONTROLLER_ANCHOR].inv()
            return [(Topic.TF_CONTROLLER_VIO, frame_transform(T, Frame.DISPLAY_VIO, Frame.CONTROLLER_VIO,
                                                              codec.stamp_ns(msg, log_time_ns)))]
        if topic == Topic.CAMERA_CALIBRATION and len(msg.K) == 9 and camera_problem(msg.K, msg.D, msg.width,
                                                                                    msg.height) is None:
            return [(Topic.CAMERA_FRUSTUM, camera_frustum(msg.K, msg.width, msg.height, codec.stamp_ns(msg, log_time_ns)))]
        if topic == Topic.CONTROLLER_MARKER:
            t = codec.stamp_ns(msg, log_time_ns)
            out: list[tuple[str, Message]] = [
                (Topic.TF_MARKER, frame_transform(codec.pose_of(msg.pose_in_body, required=False), Frame.CONTROLLER,
                                                  Frame.MARKER, t))]
            if msg.size_m > 0:
                out.append((Topic.CONTROLLER_MARKER_OUTLINE, marker_outline(float(msg.size_m), t)))
            return out
        return []
