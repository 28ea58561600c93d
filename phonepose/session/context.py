"""Read the static part of a session into a :class:`~phonepose.pipeline.types.SessionContext`.

What does not change during a session (camera intrinsics and extrinsics, the marker, the
mocap calibration, the task window, the targets or path) is read once, before the first tick,
from the first message of each static topic, and decoded here: the context holds no message of
the session's format, so the pipeline that receives it depends on none.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

from phonepose.errors import SessionContentError
from phonepose.geometry import Pose
from phonepose.pipeline.markers import aruco_dictionary, aruco_dictionary_names
from phonepose.pipeline.types import (
    CameraModel,
    MarkerModel,
    SessionContext,
    TaskPath,
    TaskTarget,
    TaskTargets,
    check_camera,
    check_plumb_bob,
    has_camera,
)
from phonepose.schemas.topics import Topic
from phonepose.session import codec
from phonepose.session.reader import SessionReader

__all__ = ["MAX_MARKER_SIZE_M", "STATIC_TOPICS", "context_from_static", "has_camera", "read_context", "session_tag", "task_path",
           "task_targets"]

# Used when a session has no camera at all (controller VIO only): nothing looks at it.
_NO_CAMERA = CameraModel(K=np.eye(3), D=np.zeros(5), width=0, height=0, T_display_camera=Pose.identity())
# A marker is printed or shown on a screen: larger than this is a broken spec (1e200 m overflowed T8).
MAX_MARKER_SIZE_M = 10.0
_NO_MARKER = MarkerModel(dictionary="", id=-1, size_m=0.0, T_body_marker=Pose.identity())


def _static_pose(path: str, what: str, decode, msg) -> Pose:
    """A static pose (a FrameTransform or a foxglove Pose) by the codec's rules; broken is one clear error."""
    try:
        return decode(msg)
    except codec.BrokenPose as exc:
        raise SessionContentError(f"{path}: {what} {exc.detail}") from None


def _marker_model(path: str, spec) -> MarkerModel:
    known = aruco_dictionary_names()
    if spec.dictionary not in known:
        raise SessionContentError(f"{path}: marker dictionary {spec.dictionary!r} ({Topic.CONTROLLER_MARKER}) is not "
                                  f"one OpenCV knows (DICT_4X4_50, DICT_APRILTAG_36h11, ...: {len(known)} in all)")
    size = aruco_dictionary(spec.dictionary).bytesList.shape[0]
    if not 0 <= spec.id < size:
        raise SessionContentError(f"{path}: marker id {spec.id} ({Topic.CONTROLLER_MARKER}) is not in "
                                  f"{spec.dictionary} (ids 0-{size - 1})")
    if not (np.isfinite(spec.size_m) and spec.size_m > 0):
        raise SessionContentError(f"{path}: marker size {spec.size_m:g} m: expected a positive size")
    if spec.size_m > MAX_MARKER_SIZE_M:
        raise SessionContentError(f"{path}: marker size {spec.size_m:g} m: expected at most {MAX_MARKER_SIZE_M:g} m "
                                  "(the side of a printed or displayed marker)")
    T_body_marker = _static_pose(path, f"marker pose on the body ({Topic.CONTROLLER_MARKER})",
                                 lambda pose: codec.pose_of(pose, required=False), spec.pose_in_body)
    return MarkerModel(dictionary=spec.dictionary, id=int(spec.id), size_m=float(spec.size_m),
                       T_body_marker=T_body_marker)


def _stamp_ns(ts) -> int | None:
    ns = codec.timestamp_ns(ts)
    return ns if ns != 0 else None


STATIC_TOPICS = (Topic.SESSION_INFO, Topic.CAMERA_CALIBRATION, Topic.CAMERA_EXTRINSICS, Topic.CONTROLLER_MARKER,
                 Topic.GT_CALIBRATION, Topic.EXPERIMENT_TARGETS, Topic.EXPERIMENT_PATH)


def _first_messages(reader: SessionReader, summary) -> dict:
    """The first message of every static topic the session has, in one pass that stops when all are found
    (they come first in a session, so this reads the first chunk once instead of once per topic)."""
    wanted = [t for t in STATIC_TOPICS if summary.has(t)]
    found: dict = {}
    if wanted:
        for m in reader.messages(wanted):
            if m.topic not in found:
                found[m.topic] = m.msg
                if len(found) == len(wanted):
                    break
    return found


def read_context(reader: SessionReader) -> SessionContext:
    """The SessionContext of an open session; SessionContentError if it cannot be played back."""
    summary = reader.summary()
    path = reader.path
    if summary.message_count == 0:
        raise SessionContentError(f"{path}: empty session (no messages)")
    if not summary.has(Topic.CONTROLLER_VIO_POSE):
        raise SessionContentError(f"{path}: no controller VIO ({Topic.CONTROLLER_VIO_POSE}); nothing to play back")
    n_vio = sum(c.count for c in summary.channels if c.topic == Topic.CONTROLLER_VIO_POSE)
    if n_vio > 1 and summary.start_ns == summary.end_ns:
        # a writer that leaves log_time 0 (or one value): playback saw one tick, scored nothing and said nothing
        raise SessionContentError(f"{path}: all {summary.message_count} messages have the same log time "
                                  f"({summary.start_ns} ns): phonepose plays a session in log-time order (the capture "
                                  "time, docs/format.md), which this file's writer did not set")
    return context_from_static(path, summary.has(Topic.CAMERA_IMAGE), _first_messages(reader, summary))


def context_from_static(path: str, has_images: bool, static: dict) -> SessionContext:
    """The SessionContext from the first message of each static topic (``static``: topic -> message), by
    the same checks as a file's (a live feed builds its context from the records it sees)."""
    first = static.get
    camera = _NO_CAMERA
    marker = _NO_MARKER
    if has_images:
        calib = first(Topic.CAMERA_CALIBRATION)
        if calib is None:
            raise SessionContentError(f"{path}: camera images but no camera calibration ({Topic.CAMERA_CALIBRATION})")
        if len(calib.K) != 9:
            raise SessionContentError(f"{path}: camera calibration has {len(calib.K)} K values, expected 9")
        check_camera(f"{path}: camera calibration", np.asarray(calib.K, dtype=float), np.asarray(calib.D, dtype=float),
                     calib.width, calib.height, SessionContentError)
        check_plumb_bob(f"{path}: {Topic.CAMERA_CALIBRATION}", calib.distortion_model, np.asarray(calib.D, dtype=float),
                        SessionContentError)
        D = np.zeros(5)
        d = np.asarray(calib.D, dtype=float)[:5]
        D[: len(d)] = d
        ext = first(Topic.CAMERA_EXTRINSICS)
        T_display_camera = Pose.identity() if ext is None else \
            _static_pose(path, f"camera extrinsics ({Topic.CAMERA_EXTRINSICS})", codec.transform_of, ext)
        camera = CameraModel(K=np.asarray(calib.K, dtype=float).reshape(3, 3), D=D, width=int(calib.width),
                             height=int(calib.height), T_display_camera=T_display_camera)
        spec = first(Topic.CONTROLLER_MARKER)
        if spec is None:
            raise SessionContentError(f"{path}: camera images but no marker spec ({Topic.CONTROLLER_MARKER})")
        marker = _marker_model(path, spec)
    else:
        spec = first(Topic.CONTROLLER_MARKER)
        if spec is not None:
            marker = _marker_model(path, spec)

    gt_calib = first(Topic.GT_CALIBRATION)
    T_world_display_vio = None if gt_calib is None else \
        _static_pose(path, f"ground-truth calibration ({Topic.GT_CALIBRATION})", codec.transform_of, gt_calib)
    info = first(Topic.SESSION_INFO)
    targets = first(Topic.EXPERIMENT_TARGETS)
    path_spec = first(Topic.EXPERIMENT_PATH)
    task_start = task_end = None
    if info is not None:
        task_start = _stamp_ns(info.task_start)
        task_end = _stamp_ns(info.task_end)
    return SessionContext(
        camera=camera, marker=marker,
        T_world_display_vio=T_world_display_vio,
        task_start_ns=task_start, task_end_ns=task_end,
        session_id=None if info is None else _digest(info),
        targets=None if targets is None else task_targets(targets),
        path=None if path_spec is None else task_path(path_spec),
    )


def _digest(info) -> str:
    """16 hex digits naming a SessionInfo message: equal messages, equal digests."""
    return hashlib.sha256(info.SerializeToString(deterministic=True)).hexdigest()[:16]


def task_targets(msg) -> TaskTargets:
    """A ``phonepose.Targets`` message as the pipeline's TaskTargets."""
    return TaskTargets(
        frame_id=msg.frame_id, cube_size_m=msg.cube_size_m, select_radius_m=msg.select_radius_m,
        targets=tuple(TaskTarget(
            index=t.index, position=(t.pose.position.x, t.pose.position.y, t.pose.position.z),
            orientation_xyzw=(t.pose.orientation.x, t.pose.orientation.y, t.pose.orientation.z, t.pose.orientation.w),
            inside_view=t.inside_view) for t in msg.targets))


def task_path(msg) -> TaskPath:
    """A ``phonepose.PathSpec`` message as the pipeline's TaskPath."""
    return TaskPath(frame_id=msg.frame_id, name=msg.name, trial=msg.trial,
                    waypoints=tuple((w.x, w.y, w.z) for w in msg.waypoints), closed=msg.closed)


def session_tag(path: str | os.PathLike, context: SessionContext) -> str | None:
    """``NAME ID``: the session's file name and a 16-hex digest of its ``/session/info`` message.

    Playback writes it in the header of every trajectory it writes, so that ``evaluate`` can tell
    an estimate and a ground truth from two different recordings apart: simulated sessions all
    start at the same stamp, so their stamps alone match. Two sessions with the same SessionInfo
    (the same simulator config and seed, or a copy of one file) get the same ID, as they should.
    None for a session without SessionInfo.
    """
    if context.session_id is None:
        return None
    return f"{Path(path).name} {context.session_id}"
