"""Marker sightings of a session: where the camera saw the phone's body, frame by frame.

The pipeline's own marker recognition (phonepose.pipeline.markers.MarkerRecognizer, the shared
stages' detector and solvePnP) runs on every camera frame, in order; each recognised frame gives
``T_camera_body``, and with the display's VIO pose at that frame (interpolated as playback does)
``T_dvio_body = T_dvio_display · T_display_camera · T_camera_body``. Stamps are the frames' log
times: the clock playback associates the ground truth on.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.errors import SessionContentError
from phonepose.geometry import Pose, interpolate_many

MAX_DISPLAY_GAP_S = 0.5   # as playback (scheduler.MAX_GAP_S): a frame farther from display VIO is not placed
STILL_M = 0.003           # a display whose VIO moves less than this (1σ per axis) and turns less than
STILL_DEG = 0.2           # this stood still (a tripod): its mean pose is used for every sighting


@dataclass(frozen=True)
class Sightings:
    stamps_s: np.ndarray      # (N,) frame log times, ascending
    T_dvio_body: Pose         # N poses of the phone's body in display_vio
    T_camera_body: Pose       # the same, in the display camera
    T_dvio_camera: Pose       # N poses of the display camera in display_vio at those frames
    frames: int               # camera frames read
    reprojection_px: np.ndarray   # (N,) RMS reprojection error of each sighting

    def __len__(self) -> int:
        return len(self.stamps_s)

    def __getitem__(self, index) -> Sightings:
        return Sightings(self.stamps_s[index], self.T_dvio_body[index], self.T_camera_body[index],
                         self.T_dvio_camera[index], self.frames, self.reprojection_px[index])


def _still(display: Pose) -> bool:
    """The display did not move: its VIO positions within STILL_M (1σ per axis), orientations within STILL_DEG."""
    rv = (display.rotation.mean().inv() * display.rotation).as_rotvec()
    return bool(np.std(display.translation, axis=0).max() < STILL_M and np.degrees(np.std(rv, axis=0)).max() < STILL_DEG)


def _none(frames: int) -> Sightings:
    empty = Pose.identity(0)
    return Sightings(np.zeros(0), empty, empty, empty, frames, np.zeros(0))


def _display_vio(reader) -> tuple[np.ndarray, Pose]:
    from phonepose.schemas.topics import Topic
    from phonepose.session import codec

    stamps, raws = [], []
    for m in reader.messages([Topic.DISPLAY_VIO_POSE]):
        try:
            raws.append(codec.raw_pose(m.msg.pose))
        except codec.BrokenPose:
            continue
        stamps.append(m.log_time_ns / 1e9)
    t = np.asarray(stamps, dtype=float)
    keep = np.ones(len(t), dtype=bool)
    keep[1:] = np.diff(t) > 0          # duplicated or backwards samples: skipped as playback does
    arr = np.asarray(raws, dtype=float).reshape(-1, 7)[keep]
    return t[keep], Pose.from_xyzw(arr[:, 4:], arr[:, :4])


def read_sightings(path: str | os.PathLike) -> Sightings:
    """Every marker sighting of the session; SessionContentError when it has no camera or no display VIO."""
    from phonepose.pipeline.markers import MarkerRecognizer
    from phonepose.pipeline.shared import decode_gray, warn_damaged, warn_wrong_size
    from phonepose.schemas.topics import Topic
    from phonepose.session import SessionReader
    from phonepose.session.context import has_camera, read_context

    with SessionReader(path) as reader:
        context = read_context(reader)
        if not has_camera(context):
            raise SessionContentError(f"{path}: no camera images ({Topic.CAMERA_IMAGE}): the calibration needs "
                                      "the display camera's sightings of the phone's marker")
        if not reader.summary().has(Topic.DISPLAY_VIO_POSE):
            raise SessionContentError(f"{path}: no display VIO ({Topic.DISPLAY_VIO_POSE}): the marker sightings "
                                      "cannot be placed in display_vio")
        recognizer = MarkerRecognizer(context.camera, context.marker)
        T_marker_body = context.marker.T_body_marker.inv()
        stamps, cam_body, rms = [], [], []
        frames = wrong_size = damaged = 0
        first_wrong = first_damaged = ""
        last_ns = None
        for m in reader.messages([Topic.CAMERA_IMAGE]):
            if last_ns is not None and m.log_time_ns <= last_ns:
                continue        # a duplicated frame: the same sighting twice would weigh it double
            last_ns = m.log_time_ns
            frames += 1
            image = decode_gray(m.msg.data, (context.camera.width, context.camera.height))
            if image.damaged:
                damaged += 1
                first_damaged = first_damaged or image.damaged
            if image.wrong_size:
                wrong_size += 1
                first_wrong = first_wrong or image.problem
            if image.gray is None:
                continue
            seen = recognizer.recognize(image.gray, None, m.log_time_ns)
            if seen is None:
                continue
            stamps.append(m.log_time_ns / 1e9)
            cam_body.append(seen.T_camera_marker @ T_marker_body)
            rms.append(seen.reprojection_error_px)
        t_d, display = _display_vio(reader)
    warn_wrong_size(wrong_size, first_wrong)
    warn_damaged(damaged, first_damaged)
    t = np.asarray(stamps, dtype=float)
    if len(t) == 0 or len(t_d) < 2:
        return _none(frames)
    # placed only where display VIO brackets the frame within the gap playback allows
    j = np.searchsorted(t_d, t)
    ok = (j > 0) & (j < len(t_d))
    jj = np.clip(j, 1, len(t_d) - 1)
    ok &= (t_d[jj] - t_d[jj - 1] <= MAX_DISPLAY_GAP_S)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return _none(frames)
    T_cb = Pose.concatenate([cam_body[k] for k in idx])
    T_dvio_display = interpolate_many(t_d, display, t[idx])
    if _still(display):
        # a display on a tripod: its VIO's per-pose jitter (0.5 mm in the simulator, as large as the marker's own
        # noise across the view) is noise, not motion; its mean pose is the better estimate of where it stood
        mean = Pose(display.rotation.mean(), np.mean(display.translation, axis=0))
        T_dvio_display = Pose(Rotation.concatenate([mean.rotation] * len(idx)), np.tile(mean.translation, (len(idx), 1)))
    T_dvio_camera = T_dvio_display @ context.camera.T_display_camera
    return Sightings(t[idx], T_dvio_camera @ T_cb, T_cb, T_dvio_camera, frames, np.asarray(rms)[idx])
