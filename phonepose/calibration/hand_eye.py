"""Hand-eye calibration: the fixed pose of the motion-capture rigid body on the controller phone.

Motion capture measures the pose of its rigid body (T_world_mocap); the trackers estimate the
phone's own frame (T_dvio_controller). When the two frames are not the same, every orientation
error carries their fixed rotation: the paper's r_ATE of 10-13 deg for every tracker looks like
such an offset (docs/evaluation.md), and the simulator models it as ``mocap.hand_eye_*``.
Like evo and rpg_trajectory_evaluation, the metrics do not remove it themselves (evo issue #562:
calibration belongs before the evaluation); this module estimates it once per rig, and
``playback --gt-calibration FILE`` applies it to the ground truth.

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

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.calibration.gt_calibration import GtCalibration, load_gt_calibration, save_gt_calibration
from phonepose.errors import SessionContentError
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
    sigma_rotation_deg: float = float("nan")     # 1σ of the rotation (block bootstrap over the motions)
    sigma_time_offset_ms: float = float("nan")   # 1σ of the clock offset (the same resamples)
    warnings: tuple[str, ...] = ()               # the motion does not determine the result: with numbers

    @property
    def rotation_deg(self) -> float:
        return float(np.degrees(self.T_controller_mocap.rotation.magnitude()))


def _motions(t: np.ndarray, phone: Pose, t_mocap: np.ndarray, mocap: Pose, delta: float, step_s: float,
             min_angle_deg: float, with_times: bool = False):
    """Relative motions A (phone) and B (rigid body, read ``delta`` s later on its clock) over step_s
    (and, ``with_times``, each motion's start time)."""
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
    if with_times:
        return A[use], B[use], a[use], b[use], t[i][use]
    return A[use], B[use], a[use], b[use]


def _rotation_fit(a: np.ndarray, b: np.ndarray) -> tuple[Rotation, float]:
    """R_X with a = R_X b (Park & Martin 1994: a Wahba problem) and the RMS axis residual (rad)."""
    R_X, _ = Rotation.align_vectors(a, b)
    return R_X, float(np.sqrt(np.mean(np.sum((a - R_X.apply(b)) ** 2, axis=1))))


BOOTSTRAP = 100
BLOCK_S = 1.0            # motions overlap (each spans step_s): resampled in blocks of this long
TOLERANCE_DEG = 0.5      # 1σ above these is warned about
TOLERANCE_MS = 5.0


def _bootstrap_counts(n_blocks: int, n: int, seed: int) -> np.ndarray:
    """(n, n_blocks): how many times each block is drawn in each of ``n`` moving-block resamples."""
    rng = np.random.default_rng(seed)
    return np.stack([np.bincount(rng.integers(0, n_blocks, n_blocks), minlength=n_blocks) for _ in range(n)]
                    ).astype(float)


def _uncertainty(t_phone, phone, t_mocap, mocap, delta: float, R_X: Rotation, step_s: float, min_angle_deg: float,
                 n: int = BOOTSTRAP, seed: int = 0) -> tuple[float, float]:
    """1σ of the rotation (deg) and of the clock offset (ms): a moving-block bootstrap over the motions,
    each resample refitting the rotation at every offset of the 1 ms grid around ``delta``.

    A resample weighs each motion by how often its block was drawn. The weighted Wahba fit
    (``Rotation.align_vectors(a, b, weights)``) and its cost need only the weighted sums of the outer
    products a bᵀ and of |a|² + |b|², so these are summed per block once, and all resamples at all offsets
    are fitted in one batched SVD: the same rotations as align_vectors (to rounding; test_hand_eye compares the
    two) in one call instead of one per resample and offset."""
    grid = np.round(np.arange(delta - 0.01, delta + 0.01 + 1e-9, 0.001), 6)
    sets = []
    for d in grid:
        _, _, a, b, tm = _motions(t_phone, phone, t_mocap, mocap, float(d), step_s, min_angle_deg, with_times=True)
        block_s = min(BLOCK_S, max(t_phone[-1] - t_phone[0], 1e-3) / 5)   # at least 5 blocks
        sets.append((a, b, np.floor((tm - t_phone[0]) / block_s).astype(int)))
    n_blocks = int(max(s[2].max(initial=0) for s in sets)) + 1
    outer = np.zeros((len(grid), n_blocks, 3, 3))      # Σ a bᵀ per offset and block
    squares = np.zeros((len(grid), n_blocks))         # Σ |a|² + |b|²
    sizes = np.zeros((len(grid), n_blocks))           # motions
    for g, (a, b, blocks) in enumerate(sets):
        np.add.at(outer[g], blocks, a[:, :, None] * b[:, None, :])
        np.add.at(squares[g], blocks, np.sum(a * a, axis=1) + np.sum(b * b, axis=1))
        sizes[g] = np.bincount(blocks, minlength=n_blocks)
    counts = _bootstrap_counts(n_blocks, n, seed)
    H = np.einsum("rk,gkij->rgij", counts, outer)      # (resample, offset, 3, 3)
    U, _, Vt = np.linalg.svd(H)
    U[..., :, 2] *= np.where(np.linalg.det(U @ Vt) < 0, -1.0, 1.0)[..., None]     # a rotation, not a reflection
    R = U @ Vt
    weight = counts @ sizes.T
    with np.errstate(divide="ignore", invalid="ignore"):
        cost = (counts @ squares.T - 2.0 * np.sum(R * H, axis=(2, 3))) / weight      # Σ w |a - R b|² / Σ w
    cost[(counts > 0) @ sizes.T < 3] = np.inf                # fewer than 3 motions drawn
    best = np.argmin(cost, axis=1)
    found = np.isfinite(cost[np.arange(n), best])
    R_best = R[np.arange(n), best]
    angles = np.where(found, np.degrees((Rotation.from_matrix(R_best).inv() * R_X).magnitude()), 0.0)
    shifts = np.where(found, 1e3 * (grid[best] - delta), 0.0)
    return float(np.sqrt(np.mean(np.square(angles)))), float(np.sqrt(np.mean(np.square(shifts))))


def _warnings(pairs: int, sigma_deg: float, sigma_ms: float, spread: float) -> tuple[str, ...]:
    over = []
    if sigma_deg > TOLERANCE_DEG:
        over.append(f"rotation ±{sigma_deg:.2f} deg")
    if sigma_ms > TOLERANCE_MS:
        over.append(f"clock offset ±{sigma_ms:.1f} ms")
    if not over:
        return ()
    return (f"the motion does not determine the hand-eye calibration well: {', '.join(over)} (1σ; meant for "
            f"{TOLERANCE_DEG:g} deg, {TOLERANCE_MS:g} ms) from {pairs} motions, axis spread {spread:.2f}: record longer, "
            "turning the phone about every axis",)


def estimate_hand_eye(t_phone: np.ndarray, phone: Pose, t_mocap: np.ndarray, mocap: Pose,
                      step_s: float = STEP_S, min_angle_deg: float = MIN_ANGLE_DEG,
                      max_offset_s: float = MAX_OFFSET_S, translation=(0.0, 0.0, 0.0), bootstrap: int = BOOTSTRAP) -> HandEye:
    """X = T_controller_mocap, and the mocap clock's offset, from the phone's own poses and the rigid body's.

    Each stream is in its own world; ``t_phone``/``t_mocap`` are their capture stamps (s);
    ``translation`` is the measured lever arm (m, the body's origin in the phone frame). The clock
    offset (mocap minus phone stamps, within +-max_offset_s) is the one whose motions fit X best:
    a grid of 10 ms, then of 1 ms around the best. Raises SessionContentError when the motion
    cannot determine X; the 1σ of the rotation and of the offset come from ``bootstrap`` resamples
    of the motions, and a 1σ above 0.5 deg or 5 ms is a warning with the numbers.
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
    sigma_deg, sigma_ms = (_uncertainty(t_phone, phone, t_mocap, mocap, delta, R_X, step_s, min_angle_deg, bootstrap)
                           if bootstrap > 0 else (float("nan"), float("nan")))
    return HandEye(T_controller_mocap=X, time_offset_s=round(delta, 6), pairs=len(a),
                   residual_deg=float(np.sqrt(np.mean(np.degrees(residual.magnitude()) ** 2))), axis_spread=spread,
                   sigma_rotation_deg=sigma_deg, sigma_time_offset_ms=sigma_ms,
                   warnings=_warnings(len(a), sigma_deg, sigma_ms, spread))


def hand_eye_from_session(path: str | Path, **options) -> HandEye:
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
    from phonepose.calibration.ground_truth import unique_ascending

    (tp, pp), (tm, pm) = series[Topic.CONTROLLER_VIO_POSE], series[Topic.GT_CONTROLLER_POSE]
    if len(tp) < 2 or len(tm) < 2:
        raise SessionContentError(f"{path}: fewer than 2 finite poses on {Topic.CONTROLLER_VIO_POSE} or "
                                  f"{Topic.GT_CONTROLLER_POSE}")
    # sorted, and duplicated messages (the same stamp twice) kept once: interpolation needs rising stamps
    vio = unique_ascending(np.asarray(tp), Pose.concatenate(pp), Topic.CONTROLLER_VIO_POSE)
    gt = unique_ascending(np.asarray(tm), Pose.concatenate(pm), Topic.GT_CONTROLLER_POSE)
    if len(vio) < 2 or len(gt) < 2:
        raise SessionContentError(f"{path}: fewer than 2 distinct stamps on {Topic.CONTROLLER_VIO_POSE} or "
                                  f"{Topic.GT_CONTROLLER_POSE}")
    try:
        return estimate_hand_eye(vio.stamps_s, vio.poses, gt.stamps_s, gt.poses, **options)
    except SessionContentError as exc:
        raise SessionContentError(f"{path}: {exc}") from None


def to_gt_calibration(he: HandEye, session: str = "") -> GtCalibration:
    """The hand-eye result in the common ground-truth calibration format (gt_calibration.py)."""
    sigma = {k: v for k, v in (("sigma_body_rotation_deg", he.sigma_rotation_deg),
                               ("sigma_time_offset_ms", he.sigma_time_offset_ms)) if np.isfinite(v)}
    return GtCalibration(T_controller_gt=he.T_controller_mocap, time_offset_s=he.time_offset_s,
                         method="calibrate-hand-eye", samples=he.pairs, residual_deg=he.residual_deg, sigma=sigma,
                         session=session, warnings=he.warnings)


def save_hand_eye(path: str | Path, he: HandEye, inputs=(), session: str = "") -> None:
    """The common calibration file (gt_calibration.py), by the output rule (phonepose.files)."""
    save_gt_calibration(path, to_gt_calibration(he, session), inputs=inputs)


def load_hand_eye(path: str | Path) -> HandEye:
    """A calibration file's hand-eye part (this format or the older hand-eye one); a bad file is an InputFileError."""
    cal = load_gt_calibration(path, what="hand-eye")
    return HandEye(T_controller_mocap=cal.T_controller_gt, time_offset_s=cal.time_offset_s, pairs=cal.samples,
                   residual_deg=cal.residual_deg, sigma_rotation_deg=cal.sigma.get("sigma_body_rotation_deg", float("nan")),
                   sigma_time_offset_ms=cal.sigma.get("sigma_time_offset_ms", float("nan")))
