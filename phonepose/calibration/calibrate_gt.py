"""``calibrate-gt``: everything that ties a ground truth to the display, estimated from one session.

Unknowns: the ground-truth clock's offset ``δ`` (its stamps minus the recorder's of the same
instant), ``Z = T_dvio_world`` (the ground truth's world in the display's VIO world; with the
display camera's pose this is the world→camera transform) and ``X = T_body_grip`` (the tracked body,
a mocap rigid body or a controller's grip, in the phone's body frame). Data: the marker sightings
``A_i = T_dvio_body`` (phonepose.calibration.sightings) and the ground truth ``B_i = T_world_grip``
at ``t_i + δ``. Every sighting satisfies the robot-world/hand-eye equation ``A_i X = Z B_i``.

Method:

1. The clock: for each δ on a 10 ms grid over ±``max_offset_s``, then a 1 ms grid around the best,
   the closed form below is solved and scored by its median residual (rotation in deg + translation
   in mm; medians, so that the rare flipped IPPE solution does not decide).
   Then only the sightings that show the phone (or the display) moved count (DISTINCT_MM, DISTINCT_DEG:
   a phone held still is one view, however many frames it lasts), and the clock is searched again on them.
2. Closed form (Dornaika & Horaud 1998's linear formulation, as Shah 2013): the rotations solve
   ``R_A R_X = R_Z R_B``, linear in the 18 entries of (R_X, R_Z): the null vector of the stacked
   Kronecker system, each 3x3 half projected onto SO(3); the translations then solve the linear
   least squares ``R_A t_X − t_Z = R_Z t_B − t_A``. OpenCV's calibrateRobotWorldHandEye does the
   same but is not in the opencv-python 5.0 wheels (the calib module left the main build), hence these lines.
3. Gross outliers (residual above 5x the median: a flipped marker pose) are dropped, then
   ``scipy.optimize.least_squares`` refines X, Z and δ together on the residuals
   (rotation / σ_rot, translation / σ_trans, each σ the closed form's RMS).
4. Uncertainty: a moving-block bootstrap over the sightings (blocks of 3 s, or a fifth of the
   sightings' span if shorter, since consecutive frames' errors are correlated) re-solves step 3
   on each resample; each 1σ is the RMS deviation of a quantity (the magnitude of a rotation or
   translation error) over the resamples.

Refused (SessionContentError, one line): too few sightings overlapping the ground truth, a phone that
turned about one axis only. Warned with numbers: any 1σ above the tolerance the result is meant for
(5 ms, 0.5 deg, 5 mm).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from phonepose.calibration.ground_truth import GroundTruthSeries
from phonepose.calibration.gt_calibration import GtCalibration
from phonepose.calibration.sightings import Sightings
from phonepose.errors import SessionContentError
from phonepose.geometry import Pose

MAX_OFFSET_S = 0.5          # the clock offsets searched: ± this
COARSE_STEP_S = 0.01
FINE_STEP_S = 0.001
GT_MAX_GAP_S = 0.1          # a sighting between ground-truth samples farther apart is not used (tracking lost)
MIN_SIGHTINGS = 30
MIN_TURN_DEG = 1.0          # the phone's second-largest turn (1σ spread) below this: one axis only, refused
OUTLIER_FACTOR = 5.0
# A sighting counts only where the tracked body (the ground truth) or the display camera moved at least
# DISTINCT_MM or turned DISTINCT_DEG since the last one counted: a phone held still for a minute is one
# view of one pose, and 1800 copies of it would weigh its own marker error (a few mm in depth, ~1 deg
# of tilt, the same in every copy) as if it were 1800 views. The thresholds lie above a good ground truth's jitter (the
# simulator's mocap 0.3 mm / 0.05 deg per axis, a Quest controller's similar) and at the hand's own
# tremor (0.8 mm / 0.25 deg per axis), so a phone held still counts a few times a second, not 30;
# a hand moving at 6 cm/s or more moves 2 mm per 30 Hz frame, so a moving phone counts every frame.
DISTINCT_MM = 2.0
DISTINCT_DEG = 0.5
BOOTSTRAP = 200
BLOCK_S = 3.0
MIN_BLOCKS = 5
# 1σ above these is warned about: the accuracy the calibration is meant for (docs/calibration.md)
TOLERANCE = {"sigma_time_offset_ms": 5.0, "sigma_world_rotation_deg": 0.5, "sigma_world_translation_mm": 5.0,
             "sigma_body_rotation_deg": 0.5, "sigma_body_translation_mm": 5.0}
WHAT = {"sigma_time_offset_ms": ("clock offset", "ms"), "sigma_world_rotation_deg": ("world->camera rotation", "deg"),
        "sigma_world_translation_mm": ("world->camera translation", "mm"),
        "sigma_body_rotation_deg": ("grip->body rotation", "deg"),
        "sigma_body_translation_mm": ("grip->body translation", "mm")}


class _GtInterpolator:
    """The ground truth at any time inside its samples (slerp, linear translation), and where that is valid.

    Plain numpy on quaternion and matrix stacks: the refinement evaluates it thousands of times, and
    scipy's Rotation costs several times more per call on a few hundred poses."""

    def __init__(self, gt: GroundTruthSeries):
        self.t = gt.stamps_s
        q = gt.poses.rotation.as_quat(canonical=False)
        # neighbours on the same hemisphere, so that slerp takes the short way
        flip = np.concatenate([[1.0], np.sign(np.sum(q[1:] * q[:-1], axis=1))])
        flip[flip == 0] = 1.0
        self.q = q * np.cumprod(flip)[:, None]
        self.trans = np.atleast_2d(gt.poses.translation)

    def valid(self, query: np.ndarray) -> np.ndarray:
        j = np.searchsorted(self.t, query)
        jj = np.clip(j, 1, len(self.t) - 1)
        inside = (query >= self.t[0]) & (query <= self.t[-1])
        return inside & (self.t[jj] - self.t[jj - 1] <= GT_MAX_GAP_S)

    def __call__(self, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R (N,3,3), t (N,3)) at the query times (inside the samples)."""
        j = np.clip(np.searchsorted(self.t, query), 1, len(self.t) - 1)
        t0, t1 = self.t[j - 1], self.t[j]
        a = ((query - t0) / (t1 - t0))[:, None]
        q0, q1 = self.q[j - 1], self.q[j]
        dot = np.clip(np.sum(q0 * q1, axis=1, keepdims=True), -1.0, 1.0)
        theta = np.arccos(dot)
        s = np.sin(theta)
        small = s < 1e-9
        w0 = np.where(small, 1.0 - a, np.sin((1.0 - a) * theta) / np.where(small, 1.0, s))
        w1 = np.where(small, a, np.sin(a * theta) / np.where(small, 1.0, s))
        q = w0 * q0 + w1 * q1
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        return _quat_matrices(q), (1.0 - a) * self.trans[j - 1] + a * self.trans[j]


def _quat_matrices(q: np.ndarray) -> np.ndarray:
    x, y, z, w = q.T
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
                     np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
                     np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)


def _log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vectors of a stack of rotation matrices (angles below 180 deg)."""
    cos = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    vee = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    s = np.sin(theta)
    factor = np.where(s > 1e-9, theta / (2.0 * np.where(s > 1e-9, s, 1.0)), 0.5)
    return vee * factor[:, None]


Stack = tuple[np.ndarray, np.ndarray]   # (R (N,3,3), t (N,3))


def _stack(pose: Pose) -> Stack:
    return pose.rotation.as_matrix(), np.atleast_2d(pose.translation)


def _project_so3(M: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(M)
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt


def closed_form(A: Stack, B: Stack) -> tuple[Pose, Pose]:
    """(X, Z) with A_i X = Z B_i in the least-squares sense (the linear formulation, see the module doc)."""
    (RA, tA), (RB, tB) = A, B
    n = len(RA)
    # column-major vec: vec(R_A R_X) = (I ⊗ R_A) vec(R_X), vec(R_Z R_B) = (R_Bᵀ ⊗ I) vec(R_Z); each sighting's
    # row block is M = [I ⊗ R_A, -(R_Bᵀ ⊗ I)], and the normal matrix Σ MᵀM is summed block by block:
    # Σ I ⊗ R_AᵀR_A, Σ R_B R_Bᵀ ⊗ I and the cross term -Σ R_Bᵀ ⊗ R_Aᵀ (building the N x 9 x 18 stack of M and
    # multiplying it out took 10x as long: the clock search solves this ~250 times per calibration)
    eye3 = np.eye(3)
    cross = np.einsum("nba,nji->aibj", RB, RA).reshape(9, 9)
    normal = np.block([[np.kron(eye3, np.einsum("nki,nkj->ij", RA, RA)), -cross],
                       [-cross.T, np.kron(np.einsum("nik,njk->ij", RB, RB), eye3)]])
    v = np.linalg.eigh(normal)[1][:, 0]
    RX, RZ = v[:9].reshape(3, 3, order="F"), v[9:].reshape(3, 3, order="F")
    d = np.linalg.det(RX)
    scale = np.sign(d) * abs(d) ** (1 / 3)
    RX, RZ = _project_so3(RX / scale), _project_so3(RZ / scale)
    # translations: [R_A, -I] [t_X; t_Z] = R_Z t_B - t_A, by its 6x6 normal equations (written out:
    # numpy's lstsq on the 3N x 6 system goes through multi-threaded OpenBLAS, 100x slower on a busy machine)
    rhs = np.einsum("ij,nj->ni", RZ, tB) - tA
    sum_RA = RA.sum(axis=0)
    normal6 = np.block([[n * np.eye(3), -sum_RA.T], [-sum_RA, n * np.eye(3)]])
    t = np.linalg.solve(normal6, np.concatenate([np.einsum("nji,nj->i", RA, rhs), -rhs.sum(axis=0)]))
    return Pose(Rotation.from_matrix(RX), t[:3]), Pose(Rotation.from_matrix(RZ), t[3:])


def pose_errors(A: Stack, X: Pose, Z: Pose, B: Stack) -> tuple[np.ndarray, np.ndarray]:
    """Per sighting: rotation (rad, a rotation vector in the body frame) and translation (m) of A X vs Z B."""
    (RA, tA), (RB, tB) = A, B
    RX, RZ = X.rotation.as_matrix(), Z.rotation.as_matrix()
    R_ax = RA @ RX
    R_zb = RZ @ RB
    t_ax = np.einsum("nij,j->ni", RA, X.translation) + tA
    t_zb = np.einsum("ij,nj->ni", RZ, tB) + Z.translation
    return _log_so3(np.swapaxes(R_zb, 1, 2) @ R_ax), t_ax - t_zb


def _median_cost(A: Stack, B: Stack) -> float:
    X, Z = closed_form(A, B)
    rot, trans = pose_errors(A, X, Z, B)
    return float(np.degrees(np.median(np.linalg.norm(rot, axis=1))) + 1e3 * np.median(np.linalg.norm(trans, axis=1)))


def _take(A: Stack, idx: np.ndarray) -> Stack:
    return A[0][idx], A[1][idx]


def _distinct(B: Stack, camera: Stack) -> np.ndarray:
    """Indices of the sightings that count (DISTINCT_MM, DISTINCT_DEG): greedy in time, each compared with
    the last counted one, its ground truth ``B`` and its display camera pose ``camera``."""
    cos_min = np.cos(np.radians(DISTINCT_DEG))
    keep = [0]
    for i in range(1, len(B[1])):
        k = keep[-1]
        for R, tr in (B, camera):
            # cos of the angle between R_k and R_i: (trace(R_k^T R_i) - 1) / 2
            moved = np.linalg.norm(tr[i] - tr[k]) * 1e3 >= DISTINCT_MM or \
                (np.sum(R[k] * R[i]) - 1.0) / 2.0 <= cos_min
            if moved:
                keep.append(i)
                break
    return np.asarray(keep, dtype=int)


def _search_offset(t: np.ndarray, A: Stack, gt: _GtInterpolator, max_offset_s: float, source: str) -> float:
    """The clock offset (step 1 of the module doc); SessionContentError when no offset puts enough sightings inside."""
    def cost(delta: float) -> float:
        ok = gt.valid(t + delta)
        if np.count_nonzero(ok) < MIN_SIGHTINGS:
            return np.inf
        idx = np.flatnonzero(ok)
        return _median_cost(_take(A, idx), gt(t[idx] + delta))

    coarse = np.arange(-max_offset_s, max_offset_s + 1e-9, COARSE_STEP_S)
    costs = [cost(d) for d in coarse]
    if not np.isfinite(costs).any():
        raise SessionContentError(f"fewer than {MIN_SIGHTINGS} marker sightings lie inside the ground truth "
                                  f"({source}) at any clock offset within ±{max_offset_s:g} s")
    best = coarse[int(np.argmin(costs))]
    fine = np.arange(best - COARSE_STEP_S, best + COARSE_STEP_S + 1e-9, FINE_STEP_S)
    return float(fine[int(np.argmin([cost(d) for d in fine]))])


@dataclass(frozen=True)
class _Fit:
    X: Pose
    Z: Pose
    delta: float

    def params(self) -> np.ndarray:
        return np.concatenate([np.zeros(3), self.X.translation, np.zeros(3), self.Z.translation, [self.delta]])

    def at(self, p: np.ndarray) -> _Fit:
        return _Fit(Pose(self.X.rotation * Rotation.from_rotvec(p[0:3]), p[3:6]),
                    Pose(self.Z.rotation * Rotation.from_rotvec(p[6:9]), p[9:12]), float(p[12]))


def camera_frame_errors(A: Stack, X: Pose, Z: Pose, B: Stack, R_camera: np.ndarray) -> np.ndarray:
    """(N, 6): rotation (rad) and translation (m) of A X vs Z B, in the display camera's axes.

    The marker's pose is far better known across the view than along it (measured on simulated
    sessions: 0.1 mm across vs 0.5 mm in depth, 0.12 deg about the optical axis vs 0.6-0.9 deg about the
    others), so the residuals are weighted per camera axis, not as one isotropic error."""
    (RA, tA), (RB, tB) = A, B
    RX, RZ = X.rotation.as_matrix(), Z.rotation.as_matrix()
    R_ax, R_zb = RA @ RX, RZ @ RB
    t_ax = np.einsum("nij,j->ni", RA, X.translation) + tA
    t_zb = np.einsum("ij,nj->ni", RZ, tB) + Z.translation
    rot = _log_so3(R_ax @ np.swapaxes(R_zb, 1, 2))              # in display_vio
    Rc_T = np.swapaxes(R_camera, 1, 2)
    return np.concatenate([np.einsum("nij,nj->ni", Rc_T, rot), np.einsum("nij,nj->ni", Rc_T, t_ax - t_zb)], axis=1)


def _residual_fn(t: np.ndarray, A: Stack, gt: _GtInterpolator, start: _Fit, sigmas: np.ndarray, R_camera: np.ndarray):
    def residuals(p: np.ndarray) -> np.ndarray:
        f = start.at(p)
        return (camera_frame_errors(A, f.X, f.Z, gt(t + f.delta), R_camera) / sigmas).ravel()
    return residuals


# central-difference steps of the 13 parameters (rotation rad, translation m, clock s): absolute, since
# the rotation parameters are perturbations around 0, where relative steps vanish
JAC_STEP = np.array([1e-4] * 3 + [1e-5] * 3 + [1e-4] * 3 + [1e-5] * 3 + [1e-4])


def _refine(t: np.ndarray, A: Stack, gt: _GtInterpolator, start: _Fit, sigmas: np.ndarray, R_camera: np.ndarray):
    """The least-squares fit, and the solution (Jacobian and residuals at it, for the bootstrap)."""
    residuals = _residual_fn(t, A, gt, start, sigmas, R_camera)

    def jacobian(p: np.ndarray) -> np.ndarray:
        cols = []
        for k, h in enumerate(JAC_STEP):
            e = np.zeros(13)
            e[k] = h
            cols.append((residuals(p + e) - residuals(p - e)) / (2 * h))
        return np.column_stack(cols)

    sigma_rad, sigma_m = float(np.mean(sigmas[:3])), float(np.mean(sigmas[3:]))
    scale = np.concatenate([np.full(3, sigma_rad), np.full(3, sigma_m), np.full(3, sigma_rad), np.full(3, sigma_m), [1e-3]])
    # MINPACK's Levenberg-Marquardt: no multi-threaded BLAS call on the 6N x 13 Jacobian (see closed_form)
    sol = least_squares(residuals, start.params(), jac=jacobian, x_scale=scale, method="lm")
    sol.jac = jacobian(sol.x)
    return start.at(sol.x), sol


def _spread_deg(A: Pose) -> np.ndarray:
    """1σ of the phone's orientation about its three principal axes (deg, largest first)."""
    mean = A.rotation.mean()
    rv = (mean.inv() * A.rotation).as_rotvec()
    return np.degrees(np.linalg.svd(rv - rv.mean(axis=0), compute_uv=False) / np.sqrt(len(rv)))


def _camera_pose(fit: _Fit, T_dvio_camera: Pose) -> Pose:
    """T_world_camera at the median display-camera pose (the display is still for the paper's tripod)."""
    k = int(np.argsort(T_dvio_camera.translation[:, 0])[len(T_dvio_camera) // 2])
    return fit.Z.inv() @ T_dvio_camera[k]


def _deviation(reference: Pose, others: list[Pose]) -> tuple[float, float]:
    """RMS rotation (deg) and translation (mm) deviation of ``others`` from ``reference``."""
    rots = [float(np.degrees(reference.angle_to(o))) for o in others]
    trans = [float(1e3 * reference.distance_to(o)) for o in others]
    return float(np.sqrt(np.mean(np.square(rots)))), float(np.sqrt(np.mean(np.square(trans))))


def _bootstrap(t: np.ndarray, start: _Fit, sol, T_dvio_camera: Pose, n: int, seed: int) -> dict[str, float]:
    """Moving-block bootstrap, each resample's fit taken as one Gauss-Newton step from the full fit
    (its residuals are small and nearly linear in the parameters: re-running least_squares on every
    resample gave the same spreads at ~100x the cost)."""
    rng = np.random.default_rng(seed)
    block_s = min(BLOCK_S, max(t[-1] - t[0], 1e-3) / MIN_BLOCKS)     # a short session still has MIN_BLOCKS blocks
    blocks = np.floor((t - t[0]) / block_s).astype(int)
    ids = np.unique(blocks)
    members = [np.flatnonzero(blocks == b) for b in ids]
    J = sol.jac.reshape(len(t), 6, 13)
    r = sol.fun.reshape(len(t), 6)
    H = np.einsum("nki,nkj->nij", J, J)      # per sighting: the normal equations' share
    g = np.einsum("nki,nk->ni", J, r)
    fit = start.at(sol.x)
    fits = []
    for _ in range(n):
        pick = np.concatenate([members[k] for k in rng.integers(0, len(ids), len(ids))])
        counts = np.bincount(pick, minlength=len(t)).astype(float)
        step = np.linalg.solve(np.einsum("n,nij->ij", counts, H), -counts @ g)
        fits.append(start.at(sol.x + step))
    cam = _camera_pose(fit, T_dvio_camera)
    world_rot, world_trans = _deviation(cam, [_camera_pose(f, T_dvio_camera) for f in fits])
    body_rot, body_trans = _deviation(fit.X, [f.X for f in fits])
    dt = np.array([f.delta for f in fits]) - fit.delta
    return {"sigma_time_offset_ms": float(1e3 * np.sqrt(np.mean(dt ** 2))),
            "sigma_world_rotation_deg": world_rot, "sigma_world_translation_mm": world_trans,
            "sigma_body_rotation_deg": body_rot, "sigma_body_translation_mm": body_trans}


def _check_overlap(t: np.ndarray, gt: GroundTruthSeries, max_offset_s: float) -> None:
    lo, hi = gt.stamps_s[0] - max_offset_s, gt.stamps_s[-1] + max_offset_s
    if t[-1] < lo or t[0] > hi:
        raise SessionContentError(
            f"the ground truth ({gt.source}: {gt.stamps_s[0]:.2f}-{gt.stamps_s[-1]:.2f} s) does not overlap the "
            f"marker sightings ({t[0]:.2f}-{t[-1]:.2f} s on the recorder's clock), even {max_offset_s:g} s apart")


def _warnings(sigma: dict[str, float], spread: np.ndarray) -> tuple[str, ...]:
    """One line naming every quantity whose 1σ is above its tolerance, and how the phone moved."""
    over = [f"{WHAT[k][0]} ±{sigma[k]:.2f} {WHAT[k][1]}" for k, limit in TOLERANCE.items() if sigma.get(k, 0.0) > limit]
    if not over:
        return ()
    return (f"the motion does not determine the calibration well: {', '.join(over)} (1σ; meant for 5 ms, 0.5 deg, "
            f"5 mm); the phone turned {spread[0]:.1f}/{spread[1]:.1f}/{spread[2]:.1f} deg (1σ about its axes) in view: "
            "record longer, turning the phone about every axis while the camera sees its marker",)


def _inliers(A: Stack, B: Stack, X: Pose, Z: Pose) -> np.ndarray:
    rot, trans = pose_errors(A, X, Z, B)
    ang, dist = np.linalg.norm(rot, axis=1), np.linalg.norm(trans, axis=1)
    return np.flatnonzero((ang <= OUTLIER_FACTOR * np.median(ang)) & (dist <= OUTLIER_FACTOR * np.median(dist)))


def _rms_sigmas(A: Stack, B: Stack, X: Pose, Z: Pose, R_camera: np.ndarray) -> np.ndarray:
    """(6,): RMS of each camera-axis component of the residuals (rad, m): the weights of the refinement."""
    err = camera_frame_errors(A, X, Z, B, R_camera)
    return np.maximum(np.sqrt(np.mean(err ** 2, axis=0)), np.array([1e-6] * 3 + [1e-7] * 3))


def calibrate_gt(sightings: Sightings, gt: GroundTruthSeries, *, max_offset_s: float = MAX_OFFSET_S,
                 bootstrap: int = BOOTSTRAP, seed: int = 0) -> GtCalibration:
    """Clock offset, world→display and grip→body from marker sightings and a ground truth (module doc)."""
    t = sightings.stamps_s
    if len(t) < MIN_SIGHTINGS:
        raise SessionContentError(f"only {len(t)} camera frames show the phone's marker (need {MIN_SIGHTINGS}): "
                                  "keep the marker in the display camera's view longer")
    _check_overlap(t, gt, max_offset_s)
    interp = _GtInterpolator(gt)
    A = _stack(sightings.T_dvio_body)
    delta = _search_offset(t, A, interp, max_offset_s, gt.source)
    # the sightings that count, placed by that clock (a still stretch stays still at any offset near it);
    # then the clock again from them alone, so that a long hold does not flatten its search either
    inside = np.flatnonzero(interp.valid(t + delta))
    distinct = inside[_distinct(interp(t[inside] + delta), _stack(sightings.T_dvio_camera[inside]))]
    if len(distinct) < MIN_SIGHTINGS:
        raise SessionContentError(
            f"only {len(distinct)} of the {len(inside)} marker sightings show the phone moved (by {DISTINCT_MM:g} mm "
            f"or {DISTINCT_DEG:g} deg; need {MIN_SIGHTINGS}): the calibration needs the phone moved and turned in view")
    sightings, t, A = sightings[distinct], t[distinct], _take(A, distinct)
    delta = _search_offset(t, A, interp, max_offset_s, gt.source)
    keep = np.flatnonzero(interp.valid(t + delta - 0.02) & interp.valid(t + delta + 0.02))
    spread = _spread_deg(sightings.T_dvio_body[keep])
    if spread[1] < MIN_TURN_DEG:
        raise SessionContentError(
            f"the phone turned about one axis only while in view ({spread[0]:.1f}/{spread[1]:.1f}/{spread[2]:.1f} deg, "
            "1σ about its axes): the calibration is undetermined; turn it about two different axes")
    t, A = t[keep], _take(A, keep)
    X, Z = closed_form(A, interp(t + delta))
    inlier = _inliers(A, interp(t + delta), X, Z)
    t, A, T_dvio_camera = t[inlier], _take(A, inlier), sightings.T_dvio_camera[keep][inlier]
    R_camera = T_dvio_camera.rotation.as_matrix()
    sigmas = _rms_sigmas(A, interp(t + delta), X, Z, R_camera)
    start = _Fit(X, Z, delta)
    fit_sol = _refine(t, A, interp, start, sigmas, R_camera)
    fit = fit_sol[0]
    rot, trans = pose_errors(A, fit.X, fit.Z, interp(t + fit.delta))
    sigma = _bootstrap(t, start, fit_sol[1], T_dvio_camera, bootstrap, seed) if bootstrap > 0 else {}
    return GtCalibration(
        T_controller_gt=fit.X, time_offset_s=round(fit.delta, 6), T_world_display_vio=fit.Z.inv(),
        T_world_camera=_camera_pose(fit, T_dvio_camera), method="calibrate-gt", samples=len(t),
        residual_mm=float(1e3 * np.sqrt(np.mean(np.sum(trans ** 2, axis=1)))),
        residual_deg=float(np.degrees(np.sqrt(np.mean(np.sum(rot ** 2, axis=1))))),
        sigma=sigma, ground_truth=gt.source if gt.is_file else "", warnings=_warnings(sigma, spread))


def calibrate_gt_session(path: str | os.PathLike, gt_file: str | os.PathLike | None = None, *,
                         gt_format: str | None = None, max_offset_s: float = MAX_OFFSET_S,
                         bootstrap: int = BOOTSTRAP, seed: int = 0) -> GtCalibration:
    """:func:`calibrate_gt` on a session's marker sightings and its ground truth (``gt_file``, else /gt/controller/pose).

    Raises SessionContentError (one line naming the session) when the motion cannot determine the result."""
    from phonepose.calibration.ground_truth import load_ground_truth
    from phonepose.calibration.sightings import read_sightings

    gt = load_ground_truth(path, gt_file, gt_format)
    sightings = read_sightings(path)
    try:
        cal = calibrate_gt(sightings, gt, max_offset_s=max_offset_s, bootstrap=bootstrap, seed=seed)
    except SessionContentError as exc:
        raise SessionContentError(f"{path}: {exc}") from None
    name = os.path.basename(os.fspath(gt_file)) if gt_file is not None else ""
    return cal.with_(session=os.path.basename(os.fspath(path)), ground_truth=name)
