"""T8's error-state Kalman filter of the correction C and the VIO time offset d
(docs/pipeline.md#the-correction-filter)."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.geometry import Quat, quat_as_rotvec, quat_from_rotvec, quat_inv, quat_matrix, quat_mul, quat_normalised
from phonepose.pipeline.t8.config import FusionConfig
from phonepose.pipeline.t8.motion import RawPose, solve

_I7 = np.eye(7)   # a constant of the update, built once


def measurement_noise(cfg: FusionConfig, marker_position: np.ndarray, camera_position: np.ndarray | None,
                      rotation_scale: float = 1.0) -> np.ndarray:
    """A sighting's 6 x 6 noise (rotation, position): isotropic lateral noise, ``marker_depth_m`` along the
    camera's line of sight (when the camera position is known), the orientation's scaled by ``rotation_scale``."""
    rot = (math.radians(cfg.marker_rotation_deg) * rotation_scale) ** 2
    lateral = cfg.marker_lateral_m ** 2 + cfg.vio_position_m ** 2
    cov = [[lateral, 0.0, 0.0], [0.0, lateral, 0.0], [0.0, 0.0, lateral]]
    if camera_position is not None:
        u = marker_position - camera_position
        n = math.sqrt(u.dot(u))
        if n > 1e-6:
            # + outer(u, u) (depth^2 - lateral^2), u the unit line of sight, on Python floats
            k = cfg.marker_depth_m ** 2 - cfg.marker_lateral_m ** 2
            u0, u1, u2 = (u / n).tolist()
            cov = [[row[j] + ui * uj * k for j, uj in enumerate((u0, u1, u2))]
                   for row, ui in zip(cov, (u0, u1, u2), strict=True)]
    return np.array([[rot, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0, rot, 0.0, 0.0, 0.0, 0.0],
                     [0.0, 0.0, rot, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, *cov[0]], [0.0, 0.0, 0.0, *cov[1]],
                     [0.0, 0.0, 0.0, *cov[2]]])


class CorrectionFilter:
    """Error-state Kalman filter of the correction C = (R_C, t_C) and the VIO time offset d.

    Nominal state: ``q`` (R_C as a unit quaternion; ``rotation_matrix`` its matrix), ``t`` (t_C, 3),
    ``d`` (s; true capture time = VIO stamp + d). Error state (7): ``δθ`` (left-multiplied:
    R_C ← exp(δθ) R_C), ``δt``, ``δd``; ``P`` its covariance. A sighting at image time t measures the
    controller pose M = C · V(t - d), V the anchor-mapped VIO interpolated at stamp time t - d.
    """

    def __init__(self, cfg: FusionConfig):
        self.cfg = cfg
        self.reset()

    def reset(self) -> None:
        self.q: Quat | None = None          # None: not initialised (no sighting yet)
        self._matrix = np.eye(3)
        self.t = np.zeros(3)
        self.d = 0.0
        self.P = np.zeros((7, 7))
        self.rejections = 0                 # in a row, since the last accepted sighting
        self.since_init = 0
        self.accepted = 0
        self.rejected = 0

    @property
    def ready(self) -> bool:
        return self.q is not None

    @property
    def rotation_matrix(self) -> np.ndarray:
        """R_C as a 3 x 3 matrix (the identity before the first sighting); read-only by contract."""
        return self._matrix

    @property
    def R(self) -> Rotation | None:
        """The correction's rotation as a scipy Rotation (for inspection)."""
        return None if self.q is None else Rotation.from_quat(self.q)

    def _set_rotation(self, q: Quat) -> None:
        self.q = q
        self._matrix = np.array(quat_matrix(q))

    def initialise(self, M: RawPose, V: RawPose, d: float = 0.0) -> None:
        """C from one sighting M and the VIO V paired with it, the time offset set to ``d``."""
        c = self.cfg
        R = Rotation.from_quat(M[0]) * Rotation.from_quat(V[0]).inv()
        if c.tilt_deg < c.marker_rotation_deg:
            # both VIO worlds are gravity aligned: C is a heading change and a tilt of at most tilt_deg,
            # the sighting's tilt beyond that is its noise
            heading = Rotation.from_euler("z", R.as_euler("ZYX")[0])
            tilt = (R * heading.inv()).as_rotvec()
            limit = math.radians(c.tilt_deg)
            if np.linalg.norm(tilt) > limit:
                tilt = tilt * (limit / np.linalg.norm(tilt))
            R = Rotation.from_rotvec(tilt) * heading
        self._set_rotation(tuple(R.as_quat().tolist()))
        self.t = M[1] - self._matrix @ V[1]
        self.d = d
        self.since_init = 0
        rot = math.radians(c.marker_rotation_deg)
        tilt = math.radians(min(c.tilt_deg, c.marker_rotation_deg))
        pos = math.hypot(c.marker_depth_m, c.vio_position_m)
        # as uncertain as one sighting; d fixed (zero variance) until C has settled, as one sighting
        # cannot tell a time offset from a correction error
        self.P = np.diag([tilt ** 2, tilt ** 2, rot ** 2] + [pos ** 2] * 3 + [0.0])
        self.rejections = 0

    def predict(self, dt_s: float, path_m: float) -> None:
        """Random-walk process noise over ``dt_s`` in which the VIO travelled ``path_m``."""
        if not self.ready or dt_s <= 0:
            return
        c = self.cfg
        q_rot = math.radians(c.rotation_walk_deg_per_sqrt_s) ** 2 * dt_s
        q_tilt = math.radians(c.tilt_walk_deg_per_sqrt_s) ** 2 * dt_s
        q_pos = c.translation_walk_m_per_sqrt_s ** 2 * dt_s + (c.translation_per_path_length * path_m) ** 2
        q_d = c.time_offset_walk_s_per_sqrt_s ** 2 * dt_s
        self.P.reshape(-1)[::8] += (q_tilt, q_tilt, q_rot, q_pos, q_pos, q_pos, q_d)   # the diagonal, in place

    def apply(self, V: RawPose) -> RawPose:
        """C · V."""
        return quat_mul(self.q, V[0]), self._matrix @ V[1] + self.t

    def update(self, M: RawPose, V: RawPose, v_vio: np.ndarray, w_vio: np.ndarray, R_meas: np.ndarray) -> bool:
        """One sighting: M (marker, display_vio), V = VIO at stamp ``t - d``, its velocity and
        angular rate (world frame, per second). Returns False if it was not used (gated or unweighable)."""
        turned = self._matrix @ np.array([V[1], w_vio, v_vio]).T   # position, rate, velocity into display_vio
        p_world = turned[:, 0]
        y = np.empty(6)
        y[0:3] = quat_as_rotvec(quat_mul(M[0], quat_inv(quat_mul(self.q, V[0]))))
        y[3:6] = M[1] - (p_world + self.t)
        (px, wx, vx), (py, wy, vy), (pz, wz, vz) = turned.tolist()
        if not self.cfg.lever_arm:
            px = py = pz = 0.0
        # H: the rotation error's and the position's Jacobians (the lever arm -skew(p) on the position's
        # rotation columns), and d's: a later d pairs an earlier VIO sample, dV/dd = -velocity
        H = np.array([[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, -wx], [0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -wy],
                      [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -wz], [0.0, pz, -py, 1.0, 0.0, 0.0, -vx],
                      [-pz, 0.0, px, 0.0, 1.0, 0.0, -vy], [py, -px, 0.0, 0.0, 0.0, 1.0, -vz]])
        with np.errstate(over="ignore", invalid="ignore"):   # absurd inputs give inf/NaN: gated below
            HP = H @ self.P
            S = HP @ H.T + R_meas
            # one factorisation for both (P H^T S^-1)^T (S symmetric) and S^-1 y
            rhs = np.empty((6, 8))
            rhs[:, :7] = HP
            rhs[:, 7] = y
            try:
                both = solve(S, rhs)
            except np.linalg.LinAlgError:   # a singular S: no finite answer, decided below
                both = np.full((6, 8), np.nan)
            K_T, m2 = both[:, :7], float(y @ both[:, 7])
        if not math.isfinite(m2) and np.isfinite(S).all() and np.isfinite(y).all():
            return False                    # a sighting that cannot be weighed is skipped, not a rejection
        if not math.isfinite(m2) or m2 > self.cfg.gate_chi2:
            self.rejections += 1
            self.rejected += 1
            return False
        dx = K_T.T @ y
        self._set_rotation(quat_normalised(quat_mul(quat_from_rotvec(dx[0:3].tolist()), self.q)))
        self.t = self.t + dx[3:6]
        self.d = self.d + dx[6]
        I_KH = _I7 - K_T.T @ H
        self.P = I_KH @ self.P @ I_KH.T + K_T.T @ R_meas @ K_T     # Joseph form: stays symmetric PSD
        self.rejections = 0
        self.accepted += 1
        self.since_init += 1
        if self.since_init == self.cfg.time_offset_after:
            # C has settled: estimate d too, and let C move with it (it absorbed any offset so far)
            c = self.cfg
            self.P[6, 6] = c.init_time_offset_s ** 2
            self.P[2, 2] += math.radians(c.marker_rotation_deg) ** 2
            self.P[3:6, 3:6] += np.eye(3) * c.marker_depth_m ** 2
        return True
