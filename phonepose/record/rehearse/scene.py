"""The rehearsal's truth: one simulated session and what the live recorder and the browser get from it.

- :data:`SIM_OVERRIDES`: the simulator's parameters set to what the live path has (a video file plays
  at a constant rate, the recorder's display stands still, the phone's samples reach the recorder
  within a few ms on one machine, the ground truth is the true pose), so that the source session and
  the rehearsed one differ only by the live path itself.
- the video file (the source session's own frames, decoded, as MJPG at the camera rate, after a
  still lead-in: the browser starts during it) and the camera calibration file;
- the pose tables the emulated devices play (``phone``: the controller VIO with its drift;
  ``headset``: the true motion seen by a controller strapped to the phone, in the headset's own
  world, :data:`GT_DELAY_S` late), and the IMU table, all on sim time (seconds, 0 = first frame
  after the lead-in);
- the truth calibrate-gt should recover (:class:`Truth`).

WebXR conventions (what the pages read): right-handed, y up, -z forward of the viewer, quaternions
x, y, z, w. The simulator's worlds are z up (phonepose/record/sim/world.py), so every world pose is
turned by :data:`ZUP_TO_YUP` (x stays, z up becomes y up, y forward becomes -z). Its phone body
(x right, y up, z out of the screen) is already the WebXR viewer's axes (the back camera looks along
-z), and the marker frame has the same axes: the viewer is the marker frame here, which is what the
live recorder takes it to be (``pose_in_body`` = identity, phonepose/record/live/recording.py).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.calibration.camera_file import CameraCalibrationFile, calibration_text
from phonepose.geometry import Pose, interpolate_many
from phonepose.record.rehearse import LEAD_IN_S
from phonepose.record.sim import SimConfig, SimSession, load_config, record_sim

# The live path, as simulator parameters (docs/recording-real-sessions.md, "Rehearsal").
SIM_OVERRIDES: dict = {
    "camera": {"frame_jitter_s": 0.0, "drop_rate": 0.0},          # a video file: frame i at i / rate
    "display_vio": {"jitter_m": 0.0, "jitter_deg": 0.0, "drift_m_per_sqrt_s": 0.0,
                    "yaw_drift_deg_per_sqrt_s": 0.0},             # record live's display stands still
    "network": {"controller_latency_s": 0.003, "wifi_jitter_s": 0.001},   # page -> recorder on one machine
    "mocap": {"exact": True},                                     # the source's ground truth: the true pose
}

ZUP_TO_YUP = Pose(Rotation.from_matrix(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])), np.zeros(3))
# IWER's 'local' space is the viewer's pose when the page asks for it; the device waits there (IWER's
# default standing height, 1.6 m) until then, so local = this pose in IWER's global (= local-floor) space.
PHONE_HOME = Pose(Rotation.identity(), np.array([0.0, 1.6, 0.0]))
# The headset's world (its local-floor space, y up, floor at y = 0) against the simulator's (z up,
# floor at z = 0): turned 35 deg about the vertical and moved, a frame calibrate-gt has to find.
T_HEADSET_WORLD = Pose(Rotation.from_euler("y", 35.0, degrees=True), np.array([0.4, 0.0, -1.1])) @ ZUP_TO_YUP
# The controller's grip in the phone's body (= marker) frame: strapped behind the phone, turned.
T_BODY_GRIP = Pose(Rotation.from_rotvec(np.radians([12.0, -20.0, 8.0])), np.array([0.01, -0.04, -0.035]))
GT_DELAY_S = 0.040          # the headset's poses show the motion this late (its pose latency)
HEADSET_TABLE_HZ = 250.0    # the true motion is sampled this densely for the headset's controller
# the headset itself and the other controller (the paper's R-sensor, on the board) stand still
T_HEADSET_VIEWER = Pose(Rotation.from_euler("y", -20.0, degrees=True), np.array([0.3, 1.65, 0.4]))
T_HEADSET_BOARD = Pose(Rotation.from_euler("x", -60.0, degrees=True), np.array([-0.3, 1.0, -0.6]))


@dataclass(frozen=True)
class Truth:
    """What calibrate-gt should find on the rehearsed session."""

    time_offset_s: float      # ground-truth stamps minus recorder stamps of the same instant
    T_world_camera: Pose      # the display camera in the headset's world (its WebXR axes; the recorder's
                              # gt_world is webxr.T_GTWORLD_XR of it)
    T_body_grip: Pose         # the grip in the phone's body frame (calibrate-gt's T_controller_gt)


@dataclass
class Scene:
    session: SimSession
    config: SimConfig
    source_path: Path          # the source simulated session (.mcap)
    video_path: Path
    calibration_path: Path
    lead_in_s: float
    fps: float
    frames: int                # frames in the video, lead-in included

    @property
    def duration_s(self) -> float:
        return self.session.duration_s

    # ------------------------------------------------------------------ truth
    def true_marker_in_world(self, s: np.ndarray) -> Pose:
        """The marker frame (the rehearsal's phone body) in the simulator's world at sim times ``s``."""
        s = np.clip(np.asarray(s, dtype=float), 0.0, self.duration_s)
        return self.session.traj(s) @ self.session.world.T_controller_marker

    def truth(self) -> Truth:
        return Truth(GT_DELAY_S, T_HEADSET_WORLD @ self.session.world.T_world_camera, T_BODY_GRIP)

    def phone_vio_local(self, s: np.ndarray) -> Pose:
        """The phone's VIO estimate of its marker frame, in WebXR 'local' axes, at sim times ``s``
        (the simulator's samples interpolated; before the first and after the last: held)."""
        sim = self.session
        t = sim.t_cvio
        vio = sim.T_cvio_ctrl @ sim.world.T_controller_marker
        return ZUP_TO_YUP @ interpolate_many(t, vio, np.clip(np.asarray(s, dtype=float), t[0], t[-1]))

    def grip_in_headset_world(self, s: np.ndarray) -> Pose:
        return T_HEADSET_WORLD @ self.true_marker_in_world(np.asarray(s, dtype=float) - GT_DELAY_S) @ T_BODY_GRIP

    # ------------------------------------------------------------------ tables the pages play
    def phone_table(self) -> dict:
        """IWER device poses (its global space) at the VIO samples' times."""
        t = self.session.t_cvio
        return _table(t, PHONE_HOME @ self.phone_vio_local(t))

    def headset_tables(self, T_grip_offset: Pose) -> dict:
        """IWER's right controller (its target ray: the grip is ``T_grip_offset`` in it), the still viewer
        and the still left controller."""
        s = np.arange(-1.0, self.duration_s + 1.0, 1.0 / HEADSET_TABLE_HZ)
        return {"right": _table(s, self.grip_in_headset_world(s) @ T_grip_offset.inv()),
                "viewer": _table(np.zeros(1), T_HEADSET_VIEWER), "left": _table(np.zeros(1), T_HEADSET_BOARD)}

    def imu_table(self) -> dict:
        """The simulator's IMU samples (body frame = DeviceMotion's device frame: x right, y up, z out of
        the screen), gyro in rad/s, accel in m/s² with gravity."""
        sim = self.session
        return {"t": sim.t_imu.tolist(), "gyro": np.round(sim.gyro, 7).tolist(), "accel": np.round(sim.accel, 6).tolist()}


def _table(t: np.ndarray, poses: Pose) -> dict:
    q = poses.rotation.as_quat()
    q = q * np.where(q[:, 3:4] < 0, -1.0, 1.0) if q.ndim == 2 else q
    return {"t": np.round(np.atleast_1d(t), 6).tolist(), "p": np.round(np.atleast_2d(poses.translation), 7).tolist(),
            "q": np.round(np.atleast_2d(q), 8).tolist()}


def rehearsal_config(config: str | os.PathLike | None = None) -> SimConfig:
    """The simulator's defaults (or a user's file) with :data:`SIM_OVERRIDES` on top."""
    return load_config(config, overrides=SIM_OVERRIDES)


def build_scene(folder: Path, *, scenario: str, path: str | None, trial: int, seed: int,
                config: SimConfig, lead_in_s: float = LEAD_IN_S) -> Scene:
    """Record the source session into ``folder`` and make the video and calibration files beside it."""
    from phonepose.schemas.topics import Topic
    from phonepose.session import SessionReader

    source = folder / "source.mcap"
    record_sim(source, scenario=scenario, path=path, trial=trial, seed=seed, config=config)
    session = SimSession(scenario, path, trial, seed, config)     # the same seed: the same session, its arrays
    cam = session.world.camera
    fps = config.camera.rate_hz
    video = folder / "camera.avi"
    # OpenCV's own MJPEG writer (its FFmpeg one ignores the quality): 100, so the frames the recorder
    # reads differ from the source's by the least a JPEG round trip allows (measured in the docs)
    writer = cv2.VideoWriter(os.fspath(video), cv2.CAP_OPENCV_MJPEG, cv2.VideoWriter.fourcc(*"MJPG"), fps,
                             (cam.width, cam.height))
    writer.set(cv2.VIDEOWRITER_PROP_QUALITY, 100)
    frames = 0
    try:
        with SessionReader(source) as reader:
            for m in reader.messages([Topic.CAMERA_IMAGE]):
                image = cv2.imdecode(np.frombuffer(m.msg.data, np.uint8), cv2.IMREAD_COLOR)
                assert image is not None, "the simulator's own JPEG"
                for _ in range(int(round(lead_in_s * fps)) + 1 if frames == 0 else 1):
                    writer.write(image)
                    frames += 1
    finally:
        writer.release()
    calibration = folder / "camera.yaml"
    calibration.write_text(calibration_text(CameraCalibrationFile(cam.K, cam.D, cam.width, cam.height, 0.0,
                                                                  "the simulator's camera")), encoding="utf-8")
    lead = (int(round(lead_in_s * fps))) / fps
    return Scene(session, config, source, video, calibration, lead, fps, frames)
