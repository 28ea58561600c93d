"""A recorded 6DoF trajectory as the controller's motion (``record sim --motion FILE``).

The simulator's own hand is minimum-jerk moves plus a sum-of-sinusoids tremor, which a predictor
can learn. Here a window of real hand-held motion (a TUM or EuRoC ground-truth file, e.g. the TUM
RGB-D sequences ``freiburg1_xyz`` and ``fr2_desk``) drives the task instead; the calibration
phase (CM1, CM2) before it is the simulator's as usual, and the marker, VIO and IMU all follow the
recorded motion. Placement (docs/simulation.md, "Recorded motion"):

* positions: the window's displacement from its mean, expressed in the recorded camera's frame at
  the window start, times ``scale``, taken along the axes of the phone facing the display camera
  at ``centre`` (display-camera coordinates: x right, y down, z away from the camera);
* orientation: the recorded rotation since the window start, applied in the body frame to the
  pose facing the display camera at ``centre``;
* the phone moves from the CM2 hold to the window's first pose in ``MOVE_S`` and holds it
  ``HOLD_S``; the task is the window; the recorded motion has its own tremor (none is added);
* the recording is resampled to a uniform grid at its own median rate and low-passed at
  ``CUTOFF_HZ`` (zero-phase Butterworth, positions and sign-continuous quaternions), and positions
  between the samples follow a cubic spline: the IMU is the trajectory's derivative, so the motion
  capture's own jitter must not become the phone's angular rate, nor a piecewise-linear path an
  accelerometer that reads zero between samples and spikes at them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation

from phonepose.errors import ConfigError
from phonepose.geometry import Pose, interpolate_many
from phonepose.series import newer_than_before

MOVE_S = 1.2
HOLD_S = 0.3
MAX_GAP_S = 0.2          # a window with a longer gap between samples is refused (fr2_desk has a 12 s one)
DEFAULT_CENTRE = (0.0, 0.03, 0.32)
# What a hand does lies below this: voluntary motion below ~5 Hz, physiological tremor at 8-12 Hz. Above
# it a motion-capture recording holds its own jitter: fr2_desk's 300 Hz orientation turns at 25 deg/s RMS
# sample to sample, 12 deg/s once low-passed at 20 Hz and 11 deg/s at 10 Hz (freiburg1_xyz, 100 Hz: 25,
# 23 and 22 deg/s); fed to the simulator as motion, that jitter became the gyro's reading and the truth's
# (docs/simulation.md, "Recorded motion").
CUTOFF_HZ = 15.0
FILTER_ORDER = 4


@dataclass(frozen=True)
class MotionSpec:
    """``record sim --motion FILE --motion-start S --motion-duration S --motion-scale X --motion-centre x,y,z``."""

    file: str
    start_s: float = 0.0          # window start, seconds after the file's first pose
    duration_s: float = 20.0
    scale: float = 1.0
    centre: tuple[float, float, float] = DEFAULT_CENTRE
    fmt: str | None = None        # tum | euroc (None: euroc for .csv, else tum)

    @property
    def name(self) -> str:
        return os.path.splitext(os.path.basename(self.file))[0]


@dataclass
class RecordedWindow:
    t: np.ndarray                 # seconds from the window start
    poses: Pose                   # relative motion: position (m, recorded-camera frame), rotation since start


def load_window(spec: MotionSpec) -> RecordedWindow:
    from phonepose.evaluation.trajectory import load_trajectory

    fmt = spec.fmt or ("euroc" if spec.file.lower().endswith(".csv") else "tum")
    traj = load_trajectory(spec.file, fmt)
    if traj.stamps is None or traj.poses is None or len(traj.poses) < 2:
        raise ConfigError(f"{{motion}} {spec.file}: needs a timestamped trajectory with 2 or more poses",
                          parameter="motion", value=spec.file)
    t = np.asarray(traj.stamps, dtype=float)
    # a duplicate or out-of-order stamp (fr2_desk has one) is dropped: the motion needs increasing times
    keep = np.flatnonzero(newer_than_before(t))
    t, traj_poses = t[keep] - t[keep][0], traj.poses[keep]
    use = (t >= spec.start_s) & (t <= spec.start_s + spec.duration_s)
    if use.sum() < 2 or t[use][-1] - t[use][0] < 0.9 * spec.duration_s:
        raise ConfigError(f"{{motion}} {spec.file}: the window {spec.start_s:g}-{spec.start_s + spec.duration_s:g} s "
                          f"is not inside the file's {t[-1]:.1f} s", parameter="motion", value=spec.file)
    t, poses = t[use], traj_poses[np.flatnonzero(use)]
    gap = float(np.diff(t).max())
    if gap > MAX_GAP_S:
        raise ConfigError(f"{{motion}} {spec.file}: a {gap:.1f} s gap in the window (choose another {{motion_start}})",
                          parameter="motion", value=spec.file, also=["motion_start"])
    t, poses = low_passed(t - t[0], poses, CUTOFF_HZ)
    first = poses[0]
    p = first.rotation.inv().apply(poses.translation - poses.translation.mean(axis=0)) * spec.scale
    return RecordedWindow(t, Pose(first.rotation.inv() * poses.rotation, p))


def low_passed(t: np.ndarray, poses: Pose, cutoff_hz: float) -> tuple[np.ndarray, Pose]:
    """``poses`` resampled at their median rate from ``t[0]`` and low-passed at ``cutoff_hz`` (zero phase).

    Quaternions are filtered component-wise after flipping each onto its predecessor's hemisphere, then
    normalised: at 100 Hz and more a hand turns < 1 deg per sample, where that equals filtering on SO(3)."""
    rate = 1.0 / float(np.median(np.diff(t)))
    grid = np.minimum(t[0] + np.arange(int(np.floor((t[-1] - t[0]) * rate + 1e-6)) + 1) / rate, t[-1])  # (rounding)
    uniform = interpolate_many(t, poses, grid)
    # nothing above the cutoff (a recording at 2 x cutoff_hz or slower), or too short for sosfiltfilt's padding
    if cutoff_hz >= rate / 2 or len(grid) <= 3 * (FILTER_ORDER + 1):
        return grid, uniform
    from scipy.signal import butter, sosfiltfilt  # here: scipy.signal takes ~0.7 s to import

    sos = butter(FILTER_ORDER, cutoff_hz, fs=rate, output="sos")
    q = uniform.rotation.as_quat()
    q[1:] *= np.cumprod(np.where(np.sum(q[1:] * q[:-1], axis=1) < 0, -1.0, 1.0))[:, None]
    q = sosfiltfilt(sos, q, axis=0)
    return grid, Pose(Rotation.from_quat(q / np.linalg.norm(q, axis=1, keepdims=True)),
                      sosfiltfilt(sos, uniform.translation, axis=0))


class MotionTrajectory:
    """The keyed (simulated) trajectory until ``task_start``, then the placed recorded window."""

    def __init__(self, keyed, task_start: float, window: RecordedWindow, facing: Rotation, centre_world: np.ndarray,
                 end: float):
        self.keyed = keyed
        self.task_start = task_start
        self.t = window.t + task_start
        self.poses = placed(window, facing, centre_world)
        self._position = CubicSpline(self.t, self.poses.translation, axis=0)   # C2: the accelerometer's path
        self._end = end

    @property
    def start(self) -> float:
        return self.keyed.start

    @property
    def end(self) -> float:
        return self._end

    def _recorded(self, t: np.ndarray) -> Pose:
        t = np.clip(t, self.t[0], self.t[-1])
        return Pose(interpolate_many(self.t, self.poses, t).rotation, self._position(t))

    def _merge(self, t: np.ndarray, keyed_fn) -> Pose:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        rec = t >= self.task_start
        if not rec.any():
            return keyed_fn(t)
        if rec.all():
            return self._recorded(t)
        a, b = keyed_fn(t[~rec]), self._recorded(t[rec])
        rot = np.empty((t.size, 4))
        trans = np.empty((t.size, 3))
        rot[~rec], rot[rec] = a.rotation.as_quat(), b.rotation.as_quat()
        trans[~rec], trans[rec] = a.translation, b.translation
        return Pose(Rotation.from_quat(rot), trans)

    def base(self, t) -> Pose:
        return self._merge(t, self.keyed.base)

    def __call__(self, t) -> Pose:
        return self._merge(t, self.keyed)


def placed(window: RecordedWindow, facing: Rotation, centre_world: np.ndarray) -> Pose:
    """The window in the world: offsets from the centre in the facing pose's axes, rotations after it."""
    return Pose(facing * window.poses.rotation, centre_world + facing.apply(window.poses.translation))
