"""Hand-eye calibration: the fixed pose of the motion-capture rigid body on the controller phone.

Motion capture measures the pose of its rigid body (T_world_mocap); the trackers estimate the
phone's own frame (T_dvio_controller). When the two frames are not the same, every orientation
error carries their fixed rotation: the paper's r_ATE of 10-13 deg for every tracker looks like
such an offset (docs/evaluation.md), and the simulator models it as ``mocap.hand_eye_*``.
Like evo and rpg_trajectory_evaluation, the metrics do not remove it themselves (evo issue #562:
calibration belongs before the evaluation); this module estimates it once per rig, and
``playback --hand-eye FILE`` applies it to the ground truth.

Method: the classic AX = XB hand-eye problem on the relative motions of the controller's own VIO
(A, phone frame) and of the ground truth (B, rigid body frame), X = T_controller_mocap. Rotation:
Park & Martin 1994 (the rotation axes of A and B are related by R_X, a Wahba problem, solved by
scipy's ``Rotation.align_vectors``). The mocap clock's offset is the one whose motions fit best.
OpenCV's calibrateHandEye solves the same problem, but it is not in the opencv-python 5.0 wheels
(the calib module moved out of the main build), hence these few lines.

The translation is not estimated: from phone VIO (1.5 % scale error, mm jitter) and the small
turns of a hand-held phone, the least-squares lever arm (R_A - I) t = R_X t_B - t_A came out 2-12 mm
off on simulated sessions whose true lever arm is 5 mm (docs/evaluation.md), so it would add error,
not remove it. Measure it with a ruler and pass it in (``--translation``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.calibration.camera_file import open_yaml
from phonepose.errors import InputFileError, SessionContentError
from phonepose.geometry import Pose, interpolate_many

STEP_S = 0.5          # the relative motions span this long (longer: VIO drift enters; shorter: small angles)
MIN_ANGLE_DEG = 3.0   # motions that turn less than this have an ill-defined axis and are left out
MIN_PAIRS = 10
MIN_AXIS_SPREAD = 0.02  # smallest / largest singular value of the motion axes below this: one axis only
MAX_OFFSET_S = 0.3      # the clock offsets searched: +- this


@dataclass(frozen=True)
class HandEye:
    T_controller_mocap: Pose      # the rigid body's frame in the phone's frame (translation: as given)
    time_offset_s: float          # mocap stamps minus phone stamps of the same instant
    pairs: int = 0                # relative motions used
    residual_deg: float = float("nan")   # RMS rotation residual of A X = X B over those motions
    axis_spread: float = float("nan")    # smallest / largest singular value of the motion axes (0: one axis only)

    @property
    def rotation_deg(self) -> float:
        return float(np.degrees(self.T_controller_mocap.rotation.magnitude()))


def _motions(t: np.ndarray, phone: Pose, t_mocap: np.ndarray, mocap: Pose, delta: float, step_s: float,
             min_angle_deg: float):
    """Relative motions A (phone) and B (rigid body, read ``delta`` s later on its clock) over step_s."""
    keep = (t + delta >= t_mocap[0]) & (t + step_s + delta <= t_mocap[-1])
    t, P = t[keep], phone[np.flatnonzero(keep)]
    B_abs = interpolate_many(t_mocap, mocap, t + delta)
    j = np.searchsorted(t, t + step_s)            # each sample paired with the first one step_s later
    i = np.flatnonzero(j < len(t))
    j = j[i]
    A = P[i].inv() @ P[j]                         # phone motion, in the phone frame at i
    B = B_abs[i].inv() @ B_abs[j]                 # rigid-body motion, in the body frame at i
    a, b = A.rotation.as_rotvec(), B.rotation.as_rotvec()
    use = np.flatnonzero((np.linalg.norm(a, axis=1) > np.radians(min_angle_deg))
                         & (np.linalg.norm(b, axis=1) > np.radians(min_angle_deg)))
    return A[use], B[use], a[use], b[use]


def _rotation_fit(a: np.ndarray, b: np.ndarray) -> tuple[Rotation, float]:
    """R_X with a = R_X b (Park & Martin 1994: a Wahba problem) and the RMS axis residual (rad)."""
    R_X, _ = Rotation.align_vectors(a, b)
    return R_X, float(np.sqrt(np.mean(np.sum((a - R_X.apply(b)) ** 2, axis=1))))


def estimate_hand_eye(t_phone: np.ndarray, phone: Pose, t_mocap: np.ndarray, mocap: Pose,
                      step_s: float = STEP_S, min_angle_deg: float = MIN_ANGLE_DEG,
                      max_offset_s: float = MAX_OFFSET_S, translation=(0.0, 0.0, 0.0)) -> HandEye:
    """X = T_controller_mocap, and the mocap clock's offset, from the phone's own poses and the rigid body's.

    Each stream is in its own world; ``t_phone``/``t_mocap`` are their capture stamps (s);
    ``translation`` is the measured lever arm (m, the body's origin in the phone frame). The clock
    offset (mocap minus phone stamps, within +-max_offset_s) is the one whose motions fit X best:
    a grid of 10 ms, then of 1 ms around the best. Raises SessionContentError when the motion
    cannot determine X.
    """
    t_phone = np.asarray(t_phone, dtype=float)
    t_mocap = np.asarray(t_mocap, dtype=float)
    if len(t_phone) < 2 or len(t_mocap) < 2 or t_phone[-1] < t_mocap[0] or t_phone[0] > t_mocap[-1]:
        raise SessionContentError("the controller's VIO and the ground truth do not overlap in time")
    _, _, a, b = _motions(t_phone, phone, t_mocap, mocap, 0.0, step_s, min_angle_deg)
    if len(a) < MIN_PAIRS:
        raise SessionContentError(f"only {len(a)} motions turn the phone by more than {min_angle_deg:g} deg "
                                  f"within {step_s:g} s (need {MIN_PAIRS}): turn the phone about while recording")
    sv = np.linalg.svd(b, compute_uv=False)
    spread = float(sv[-1] / sv[0])
    if spread < MIN_AXIS_SPREAD:
        raise SessionContentError("the phone turned about one axis only: the hand-eye rotation about it is "
                                  "undetermined (turn the phone about two different axes)")

    def cost(delta: float) -> float:
        _, _, a, b = _motions(t_phone, phone, t_mocap, mocap, delta, step_s, min_angle_deg)
        return _rotation_fit(a, b)[1] if len(a) >= MIN_PAIRS else np.inf

    coarse = np.arange(-max_offset_s, max_offset_s + 1e-9, 0.01)
    best = coarse[int(np.argmin([cost(d) for d in coarse]))]
    fine = np.arange(best - 0.01, best + 0.01 + 1e-9, 0.001)
    delta = float(fine[int(np.argmin([cost(d) for d in fine]))])

    A, B, a, b = _motions(t_phone, phone, t_mocap, mocap, delta, step_s, min_angle_deg)
    R_X, _ = _rotation_fit(a, b)
    X = Pose(R_X, np.asarray(translation, dtype=float).reshape(3))
    residual = (A.rotation * R_X).inv() * (R_X * B.rotation)      # A X vs X B, rotation part
    return HandEye(T_controller_mocap=X, time_offset_s=round(delta, 6), pairs=len(a),
                   residual_deg=float(np.sqrt(np.mean(np.degrees(residual.magnitude()) ** 2))), axis_spread=spread)


def hand_eye_from_session(path: "str | Path", **options) -> HandEye:
    """Estimate X from a session's controller VIO (/controller/vio/pose) and ground truth (/gt/controller/pose).

    ``options`` go to :func:`estimate_hand_eye`."""
    from phonepose.schemas.topics import Topic
    from phonepose.session import SessionReader, codec

    series: dict[str, tuple[list, list]] = {Topic.CONTROLLER_VIO_POSE: ([], []), Topic.GT_CONTROLLER_POSE: ([], [])}
    with SessionReader(path) as reader:
        missing = [tp for tp in series if not reader.summary().has(tp)]
        if missing:
            raise SessionContentError(f"{path}: no {' and no '.join(missing)}: the hand-eye calibration needs the "
                                      "controller's VIO and the motion-capture ground truth")
        for m in reader.messages(list(series)):
            try:
                pose = Pose.from_raw(codec.raw_pose(m.msg.pose))
            except codec.BrokenPose:
                continue     # skipped as playback skips it
            stamps, poses = series[m.topic]
            # the phone's pose at its capture time; the ground truth at the time playback associates it
            # by (its log time), so that the offset found is the one playback must shift by
            if m.topic == Topic.GT_CONTROLLER_POSE:
                stamps.append(m.log_time_ns / 1e9)
            else:
                stamps.append((m.msg.timestamp.ToNanoseconds() or m.log_time_ns) / 1e9)
            poses.append(pose)
    (tp, pp), (tm, pm) = series[Topic.CONTROLLER_VIO_POSE], series[Topic.GT_CONTROLLER_POSE]
    order_p, order_m = np.argsort(tp, kind="stable"), np.argsort(tm, kind="stable")
    if len(tp) < 2 or len(tm) < 2:
        raise SessionContentError(f"{path}: fewer than 2 finite poses on {Topic.CONTROLLER_VIO_POSE} or "
                                  f"{Topic.GT_CONTROLLER_POSE}")
    try:
        return estimate_hand_eye(np.asarray(tp)[order_p], Pose.concatenate([pp[k] for k in order_p]),
                                 np.asarray(tm)[order_m], Pose.concatenate([pm[k] for k in order_m]), **options)
    except SessionContentError as exc:
        raise SessionContentError(f"{path}: {exc}") from None


def save_hand_eye(path: "str | Path", he: HandEye) -> None:
    """OpenCV FileStorage YAML, like the camera calibration file (camera_file.py)."""
    fs = open_yaml(Path(path), "hand-eye", write=True)
    fs.write("T_controller_mocap", he.T_controller_mocap.as_matrix())
    fs.write("time_offset_s", float(he.time_offset_s))
    fs.write("rotation_deg", he.rotation_deg)
    fs.write("pairs", int(he.pairs))
    fs.write("residual_deg", he.residual_deg)
    fs.release()


def load_hand_eye(path: "str | os.PathLike") -> HandEye:
    """The calibration ``save_hand_eye`` wrote; a bad file is an InputFileError (one line, exit 2)."""
    path = Path(path)
    fs = open_yaml(path, "hand-eye")
    try:
        T = fs.getNode("T_controller_mocap").mat()
        offset_node, pairs_node, residual_node = fs.getNode("time_offset_s"), fs.getNode("pairs"), fs.getNode("residual_deg")
        offset = offset_node.real() if not offset_node.empty() else 0.0
        pairs = int(pairs_node.real()) if not pairs_node.empty() else 0
        residual = residual_node.real() if not residual_node.empty() else float("nan")
    finally:
        fs.release()
    if T is None or T.shape != (4, 4) or not np.isfinite(T).all():
        raise InputFileError(f"{path}: not a hand-eye file (expected a 4x4 matrix T_controller_mocap)")
    R = T[:3, :3]
    if abs(np.linalg.det(R) - 1) > 1e-6 or not np.allclose(R.T @ R, np.eye(3), atol=1e-6):
        raise InputFileError(f"{path}: T_controller_mocap's rotation part is not a rotation matrix")
    if not (np.isfinite(offset) and abs(offset) <= 10):
        raise InputFileError(f"{path}: time_offset_s {offset!r} is not a clock offset in seconds")
    return HandEye(T_controller_mocap=Pose.from_matrix(T), time_offset_s=float(offset), pairs=pairs,
                   residual_deg=float(residual))
