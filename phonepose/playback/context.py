"""Read the static part of a session into a :class:`~phonepose.pipeline.types.SessionContext`.

What does not change during a session (camera intrinsics and extrinsics, the marker, the
mocap calibration, the task window, the targets or path) is read once, before the first tick,
from the first message of each static topic.
"""

from __future__ import annotations

import numpy as np

from phonepose.errors import SessionContentError
from phonepose.geometry import Pose
from phonepose.pipeline.types import CameraModel, MarkerModel, SessionContext
from phonepose.schemas.topics import Topic
from phonepose.session import SessionReader

# Used when a session has no camera at all (controller VIO only): nothing looks at it.
_NO_CAMERA = CameraModel(K=np.eye(3), D=np.zeros(5), width=0, height=0, T_display_camera=Pose.identity())
_NO_MARKER = MarkerModel(dictionary="", id=-1, size_m=0.0, T_body_marker=Pose.identity())


def transform_to_pose(msg) -> Pose:
    """A foxglove FrameTransform as the pose of its child in its parent."""
    t, q = msg.translation, msg.rotation
    if q.x == 0.0 and q.y == 0.0 and q.z == 0.0 and q.w == 0.0:
        return Pose.from_xyzw([t.x, t.y, t.z], [0.0, 0.0, 0.0, 1.0])
    return Pose.from_xyzw([t.x, t.y, t.z], [q.x, q.y, q.z, q.w])


def fg_pose(pose) -> Pose:
    """A foxglove Pose; an unset orientation (all zeros, the protobuf default) reads as identity."""
    q = pose.orientation
    if q.x == 0.0 and q.y == 0.0 and q.z == 0.0 and q.w == 0.0:
        p = pose.position
        return Pose.from_xyzw([p.x, p.y, p.z], [0.0, 0.0, 0.0, 1.0])
    return Pose.from_foxglove(pose)


def _stamp_ns(ts) -> int | None:
    ns = ts.ToNanoseconds()
    return ns if ns != 0 else None


def read_context(reader: SessionReader) -> SessionContext:
    """The SessionContext of an open session; SessionContentError if it cannot be played back."""
    summary = reader.summary()
    path = reader.path
    if summary.message_count == 0:
        raise SessionContentError(f"{path}: empty session (no messages)")
    if not summary.has(Topic.CONTROLLER_VIO_POSE):
        raise SessionContentError(f"{path}: no controller VIO ({Topic.CONTROLLER_VIO_POSE}); nothing to play back")
    has_images = summary.has(Topic.CAMERA_IMAGE)

    camera = _NO_CAMERA
    marker = _NO_MARKER
    if has_images:
        calib = reader.first(Topic.CAMERA_CALIBRATION)
        if calib is None:
            raise SessionContentError(f"{path}: camera images but no camera calibration ({Topic.CAMERA_CALIBRATION})")
        if len(calib.K) != 9:
            raise SessionContentError(f"{path}: camera calibration has {len(calib.K)} K values, expected 9")
        D = np.zeros(5)
        d = np.asarray(calib.D, dtype=float)[:5]
        D[: len(d)] = d
        ext = reader.first(Topic.CAMERA_EXTRINSICS)
        T_display_camera = transform_to_pose(ext) if ext is not None else Pose.identity()
        camera = CameraModel(K=np.asarray(calib.K, dtype=float).reshape(3, 3), D=D, width=int(calib.width),
                             height=int(calib.height), T_display_camera=T_display_camera)
        spec = reader.first(Topic.CONTROLLER_MARKER)
        if spec is None:
            raise SessionContentError(f"{path}: camera images but no marker spec ({Topic.CONTROLLER_MARKER})")
        marker = MarkerModel(dictionary=spec.dictionary, id=int(spec.id), size_m=float(spec.size_m),
                             T_body_marker=fg_pose(spec.pose_in_body))
    else:
        spec = reader.first(Topic.CONTROLLER_MARKER)
        if spec is not None:
            marker = MarkerModel(dictionary=spec.dictionary, id=int(spec.id), size_m=float(spec.size_m),
                                 T_body_marker=fg_pose(spec.pose_in_body))

    gt_calib = reader.first(Topic.GT_CALIBRATION) if summary.has(Topic.GT_CALIBRATION) else None
    info = reader.first(Topic.SESSION_INFO) if summary.has(Topic.SESSION_INFO) else None
    targets = reader.first(Topic.EXPERIMENT_TARGETS) if summary.has(Topic.EXPERIMENT_TARGETS) else None
    path_spec = reader.first(Topic.EXPERIMENT_PATH) if summary.has(Topic.EXPERIMENT_PATH) else None
    task_start = task_end = None
    if info is not None:
        task_start = _stamp_ns(info.task_start)
        task_end = _stamp_ns(info.task_end)
    return SessionContext(
        camera=camera, marker=marker,
        T_world_display_vio=transform_to_pose(gt_calib) if gt_calib is not None else None,
        task_start_ns=task_start, task_end_ns=task_end,
        session_info=info, targets=targets, path=path_spec,
    )


def has_camera(context: SessionContext) -> bool:
    return context.camera.width > 0
