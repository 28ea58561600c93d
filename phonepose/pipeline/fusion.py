"""T8 (ours): a fused tracker of the controller pose from IMU, anchor-mapped VIO and the marker.

What T1-T7 lack, and what T8 does about it (docs/pipeline.md, "T8: the fused tracker", has the
measurements behind every choice):

* **One sighting sets the correction** (T6/T7 take ``T_marker · T_VIO^-1`` from a single frame, so
  its noise stays in every later pose). T8 estimates the correction ``C`` (display_vio ←
  anchor-mapped controller VIO) with an **error-state Kalman filter** (Solà 2017, "Quaternion
  kinematics for the error-state Kalman filter", §6-7: nominal state on the manifold, 6+1-dim
  error state) from *every* sighting; its process noise follows the VIO drift model, so old
  sightings fade. ``C``'s rotation is a heading change plus at most ``tilt_deg`` of tilt: both VIO
  worlds are gravity aligned.
* **The marker and VIO streams are ~0.12-0.15 s apart** (the controller's streams reach the
  display late; T7's offset absorbs speed × latency). T8 pairs each sighting with VIO
  interpolated at the image's capture time, and estimates the residual time offset ``d`` of the
  VIO stream online as a filter state with the velocity as its Jacobian (Li & Mourikis 2014,
  "Online temporal calibration for camera-IMU systems", IJRR 33(7)).
* **Flipped or outlying marker poses** (IPPE's second solution, motion blur) are rejected by a
  chi-square gate on the innovation; a run of rejections re-initialises the filter (a VIO
  relocalisation jump or a re-resolved anchor).
* **The VIO is old at every tick**: it is predicted to the tick time, the position along a
  quadratic fit of the last ``velocity_window_s`` of samples (a line's slope lags behind an
  acceleration), the orientation with the controller's **gyroscope** (the samples received after
  the newest VIO sample, then their recent mean rate). The accelerometer is not used: the
  8-12 Hz tremor (~3 m/s²) made the prediction worse in every variant measured.
* **The output jumps where the marker appears or disappears** (T4-T7 switch source). At a switch
  T8 moves its output by the estimated motion over the tick (leaving the view: the marker's own
  velocity) and carries the difference to the new source as an offset that decays with
  ``blend_time_s``: no step.

Output: inside the view, the marker's position through a complementary filter (``marker_gain``)
and the predicted VIO orientation through ``C``, corrected by a share of the newest sighting's
difference to it at the image's own time (a Kalman gain: the prediction's error, growing with how
far past the newest gyro sample the image lies, against the sighting's; ``pull_*``); outside, the
corrected, predicted VIO.

Causal: a step sees only what this and earlier ticks carried. Every parameter is in
:class:`FusionConfig` (defaults for phone-class sensors; none tuned per sequence).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, fields

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.errors import ConfigError
from phonepose.geometry import Pose, interpolate, is_finite
from phonepose.pipeline.types import Observation

_NS = 1e-9


@dataclass(frozen=True)
class FusionConfig:
    """T8's parameters. Noise figures are 1-sigma."""

    # correction filter: the time offset (estimated once C has settled)
    init_time_offset_s: float = 0.10
    time_offset_after: int = 20                      # sightings that fix C (with d = 0) before d is estimated
    # correction filter: process noise, as the VIO drifts (random walks)
    rotation_walk_deg_per_sqrt_s: float = 0.1        # heading drift ~0.07 deg/sqrt(s) of phone VIO
    tilt_deg: float = 0.5                            # gravity-aligned VIO worlds: C tilts by at most ~this (anchor tilt)
    tilt_walk_deg_per_sqrt_s: float = 0.01
    translation_walk_m_per_sqrt_s: float = 0.002     # ~1 cm/min
    translation_per_path_length: float = 0.02        # drift proportional to distance travelled
    time_offset_walk_s_per_sqrt_s: float = 1e-4
    # marker measurement noise (camera frame: lateral, depth) and VIO noise
    marker_lateral_m: float = 0.002
    marker_depth_m: float = 0.006
    marker_rotation_deg: float = 3.0
    vio_position_m: float = 0.002
    lever_arm: int = 1                               # position residuals inform C's rotation through the lever arm
    # gating: chi-square, 6 dof, 99.9 %; re-initialise after this many rejections in a row
    gate_chi2: float = 22.46
    max_rejections: int = 10
    # prediction of the (old) VIO to the tick time
    velocity_fit_degree: int = 2                     # 1: line, 2: quadratic (slope at the newest sample)
    velocity_window_s: float = 0.3                   # the fit runs through the newest VIO samples of this window
    use_gyro: int = 1
    gyro_window_s: float = 0.15                      # held rate = mean of the newest gyro samples (averages tremor out)
    max_prediction_s: float = 0.5                    # never extrapolate further
    history_s: float = 1.0                           # VIO / IMU kept for pairing
    # output
    marker_gain: float = 0.7                         # inside: weight of a new sighting against the filtered position
    # inside: the sighting's orientation corrects the output by P / (P + pull_marker_rotation_deg^2), with
    # P = pull_vio_rotation_deg^2 + (pull_prediction_deg_per_s * h)^2 and h how far the image lies past the
    # newest gyro sample (the held rate's error grows ~13 deg/s: 1.9 deg RMS over 0.15 s on the simulator)
    pull_marker_rotation_deg: float = 1.0            # a sighting's orientation error in the output (notes: 0.4 deg median)
    pull_vio_rotation_deg: float = 0.3               # the corrected VIO orientation's error where it has data
    pull_prediction_deg_per_s: float = 12.0          # growth of the held-rate prediction's orientation error
    marker_velocity_window_s: float = 0.2            # the marker's velocity (used when it leaves the view)
    blend_time_s: float = 0.1                        # decay of the offset carried across a source switch

    @classmethod
    def from_dict(cls, values: dict) -> "FusionConfig":
        known = {f.name: f.type for f in fields(cls)}
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise ConfigError(f"unknown T8 parameter(s) {', '.join(unknown)}; valid: {', '.join(known)}")
        out = {}
        for k, v in values.items():
            try:
                out[k] = int(v) if known[k] in ("int", int) else float(v)
            except (TypeError, ValueError):
                raise ConfigError(f"T8 parameter {k}={v!r} is not a number") from None
        return cls(**out)


def _polyfit(t: np.ndarray, values: np.ndarray, degree: int) -> np.ndarray:
    """Least-squares polynomial coefficients (constant first) of ``values`` over ``t``, one column per
    axis: the normal equations directly (np.polynomial.polyfit costs more than the rest of a tick)."""
    A = np.vander(t, degree + 1, increasing=True)
    return np.linalg.solve(A.T @ A, A.T @ values)


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class CorrectionFilter:
    """Error-state Kalman filter of the correction C = (R_C, t_C) and the VIO time offset d.

    Nominal state: ``R_C`` (scipy Rotation), ``t_C`` (3,), ``d`` (s; true capture time = VIO stamp + d).
    Error state (7): ``δθ`` (left-multiplied: R_C ← exp(δθ) R_C), ``δt``, ``δd``.
    A marker sighting at image time t measures the controller pose M; the model is
    ``M = C · V(t - d)`` with V the anchor-mapped VIO interpolated at stamp time ``t - d``.
    """

    def __init__(self, cfg: FusionConfig):
        self.cfg = cfg
        self.reset()

    def reset(self) -> None:
        self.R = None                       # None: not initialised (no sighting yet)
        self.t = np.zeros(3)
        self.d = 0.0
        self.P = np.zeros((7, 7))
        self.rejections = 0
        self.since_init = 0
        self.accepted = 0
        self.rejected = 0

    @property
    def ready(self) -> bool:
        return self.R is not None

    def initialise(self, M: Pose, V: Pose, d: float = 0.0) -> None:
        c = self.cfg
        R = M.rotation * V.rotation.inv()
        if c.tilt_deg < c.marker_rotation_deg:
            # both VIO worlds are gravity aligned (z up): C is a heading change and a tilt of at most
            # ~tilt_deg; the sighting's tilt beyond that is its noise, clipped here
            heading = Rotation.from_euler("z", R.as_euler("ZYX")[0])
            tilt = (R * heading.inv()).as_rotvec()
            limit = math.radians(c.tilt_deg)
            if np.linalg.norm(tilt) > limit:
                tilt = tilt * (limit / np.linalg.norm(tilt))
            R = Rotation.from_rotvec(tilt) * heading
        self.R = R
        self.t = M.translation - self.R.apply(V.translation)
        self.d = d
        self.since_init = 0
        # after one sighting the correction is as uncertain as one sighting (plus what the caller guessed of d)
        rot = math.radians(c.marker_rotation_deg)
        tilt = math.radians(min(c.tilt_deg, c.marker_rotation_deg))
        pos = math.hypot(c.marker_depth_m, c.vio_position_m)
        # d stays fixed (zero variance) until C is settled: one sighting cannot tell a time
        # offset from a correction error, and a wrong early d misplaces every later pairing
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
        self.P[np.diag_indices(7)] += np.array([q_tilt, q_tilt, q_rot] + [q_pos] * 3 + [q_d])

    @property
    def R(self) -> Rotation | None:
        return self._R

    @R.setter
    def R(self, value: Rotation | None) -> None:
        self._R = value
        self._Rm = None if value is None else value.as_matrix()   # numpy products below: cheaper per call

    def apply(self, V: Pose) -> Pose:
        return Pose(self._R * V.rotation, self._Rm @ V.translation + self.t)

    def update(self, M: Pose, V: Pose, v_vio: np.ndarray, w_vio: np.ndarray, R_meas: np.ndarray) -> bool:
        """One sighting: M (marker, display_vio), V = VIO at stamp ``t - d``, its velocity and
        angular rate (world frame, per second). Returns False if the gate rejected it."""
        Rm = self._Rm
        pred_rm = Rm @ V.rotation.as_matrix()
        p_world = Rm @ V.translation
        r_rot = Rotation.from_matrix(M.rotation.as_matrix() @ pred_rm.T).as_rotvec()
        r_pos = M.translation - (p_world + self.t)
        y = np.concatenate([r_rot, r_pos])
        H = np.zeros((6, 7))
        H[0:3, 0:3] = np.eye(3)
        if self.cfg.lever_arm:
            H[3:6, 0:3] = -_skew(p_world)
        H[3:6, 3:6] = np.eye(3)
        # d later means the pair looks at an earlier VIO sample: dV/dd = -velocity
        H[0:3, 6] = -(Rm @ w_vio)
        H[3:6, 6] = -(Rm @ v_vio)
        with np.errstate(over="ignore", invalid="ignore"):   # absurd inputs give inf/NaN: gated below
            S = H @ self.P @ H.T + R_meas
            try:
                K_T = np.linalg.solve(S, H @ self.P)       # (P H^T S^-1)^T, S symmetric
                m2 = float(y @ np.linalg.solve(S, y))
            except np.linalg.LinAlgError:
                return False
        if not math.isfinite(m2) or m2 > self.cfg.gate_chi2:
            self.rejections += 1
            self.rejected += 1
            return False
        dx = K_T.T @ y
        self.R = Rotation.from_rotvec(dx[0:3]) * self.R
        self.t = self.t + dx[3:6]
        self.d = self.d + dx[6]
        I_KH = np.eye(7) - K_T.T @ H
        self.P = I_KH @ self.P @ I_KH.T + K_T.T @ R_meas @ K_T     # Joseph form: stays symmetric PSD
        self.rejections = 0
        self.accepted += 1
        self.since_init += 1
        if self.since_init == self.cfg.time_offset_after:
            # now estimate the time offset too, and let C move with it (it absorbed any offset so far)
            c = self.cfg
            self.P[6, 6] = c.init_time_offset_s ** 2
            self.P[2, 2] += math.radians(c.marker_rotation_deg) ** 2
            self.P[3:6, 3:6] += np.eye(3) * c.marker_depth_m ** 2
        return True


class _Stream:
    """Recent samples of one controller stream on its own stamps (seconds), ascending."""

    def __init__(self) -> None:
        self.t: deque[float] = deque()
        self.v: deque = deque()
        self._arrays: tuple[np.ndarray, np.ndarray] | None = None

    def add(self, t: float, value) -> None:
        if not self.t or t > self.t[-1]:
            self.t.append(t)
            self.v.append(value)
            self._arrays = None

    def prune(self, horizon: float) -> None:
        while len(self.t) > 2 and self.t[1] < horizon:
            self.t.popleft()
            self.v.popleft()
            self._arrays = None

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(stamps, values) as arrays, rebuilt only after the stream changed."""
        if self._arrays is None:
            self._arrays = (np.fromiter(self.t, float, len(self.t)), np.array(self.v, dtype=float))
        return self._arrays

    def __len__(self) -> int:
        return len(self.t)


class FusedTracker:
    """T8: see the module docstring. Same interface as every tracker (reset/step)."""

    needs_camera = True       # the correction comes from marker sightings
    uses_vio_samples = True   # reads obs.controller_vio_samples_dvio (stamped VIO samples)

    def __init__(self, name: str = "T8", config: FusionConfig | None = None):
        self.name = name
        self.cfg = config or FusionConfig()
        self.filter = CorrectionFilter(self.cfg)
        self.reset()

    def reset(self) -> None:
        self.filter.reset()
        self._t0_ns: int | None = None             # time origin (ns) for float seconds
        self._vio = _Stream()                      # (stamp s) -> Pose in display_vio (anchor-mapped)
        self._gyro = _Stream()                     # (stamp s) -> gyro rad/s, body frame
        self._pending: deque = deque()             # (image s, marker Pose, R_meas)
        self._last_filter_t: float | None = None
        self._last_vio_t_for_path: float | None = None
        self._path_since_predict = 0.0
        self._velocity_cache = None
        self._offset = np.zeros(3)                 # carried across source switches, decays
        self._source: str | None = None
        self._last_out: Pose | None = None
        self._last_corrected: np.ndarray | None = None
        self._last_t: float | None = None
        self._last_marker: tuple[float, Pose] | None = None   # (image s, marker pose) of the newest sighting
        self._inside: np.ndarray | None = None     # the filtered marker position (marker_gain < 1)
        self._sightings: deque = deque()           # (image s, marker position) of the last marker_velocity_window_s

    # ------------------------------------------------------------------ time
    def _s(self, t_ns: int) -> float:
        if self._t0_ns is None:
            self._t0_ns = int(t_ns)
        return (int(t_ns) - self._t0_ns) * _NS

    # ------------------------------------------------------------------ VIO history
    def _vio_at(self, t: float) -> Pose | None:
        """Anchor-mapped VIO at stamp time ``t`` (None outside the kept samples)."""
        ts = self._vio.t
        if len(ts) < 2 or t < ts[0] or t > ts[-1]:
            return None
        i = int(np.searchsorted(np.fromiter(ts, float, len(ts)), t))
        i = min(max(i, 1), len(ts) - 1)
        return interpolate(ts[i - 1], self._vio.v[i - 1], ts[i], self._vio.v[i], t)

    def _velocity(self, t_end: float | None = None) -> tuple[np.ndarray, np.ndarray, float | None]:
        """(velocity, fitted position at the newest used sample, its stamp) from a least-squares
        line through the VIO samples of the last ``velocity_window_s`` up to ``t_end``."""
        n = len(self._vio)
        if n == 0:
            return np.zeros(3), np.zeros(3), None
        key = (n, self._vio.t[-1], self._vio.t[0], t_end)
        if self._velocity_cache is not None and self._velocity_cache[0] == key:
            return self._velocity_cache[1]
        ts = np.fromiter(self._vio.t, float, n)
        hi = n if t_end is None else int(np.searchsorted(ts, t_end, side="right"))
        hi = max(hi, 1)
        lo = int(np.searchsorted(ts, ts[hi - 1] - self.cfg.velocity_window_s, side="left"))
        if hi - lo < 2:
            out = (np.zeros(3), self._vio.v[hi - 1].translation, ts[hi - 1])
        else:
            tt = ts[lo:hi] - ts[hi - 1]
            pp = np.array([self._vio.v[k].translation for k in range(lo, hi)])
            # quadratic: its slope at the newest sample does not lag behind an acceleration as a line's does
            degree = self.cfg.velocity_fit_degree if hi - lo > self.cfg.velocity_fit_degree + 1 else 1
            c = _polyfit(tt, pp, degree)
            out = (c[1], c[0], ts[hi - 1])
        self._velocity_cache = (key, out)
        return out

    def _vio_predicted(self, t_stamp: float) -> Pose | None:
        """Anchor-mapped VIO moved from its newest sample to stamp time ``t_stamp``: position at
        the fitted velocity, orientation by the gyroscope (the samples received after the VIO
        sample, then their recent mean rate)."""
        if not len(self._vio):
            return None
        t_last, last = self._vio.t[-1], self._vio.v[-1]
        velocity, p_fit, _ = self._velocity()
        dt = min(max(t_stamp - t_last, 0.0), self.cfg.max_prediction_s)
        rot = last.rotation
        position = p_fit + velocity * dt
        if dt <= 0 or not len(self._gyro):
            return Pose(rot, position)
        if self.cfg.use_gyro:
            tg, gyro = self._gyro.arrays()
            # The body-frame increments are summed into one rotation vector: over <= 0.5 s of hand
            # motion the terms this drops (half the cross products of the increments) are < 0.01 deg.
            after = (tg > t_last) & (tg <= t_last + dt)
            steps = np.diff(np.concatenate([[t_last], tg[after]]))
            rotvec = (gyro[after] * steps[:, None]).sum(axis=0)
            t_prev = tg[after][-1] if after.any() else t_last
            hold = gyro[tg >= tg[-1] - self.cfg.gyro_window_s].mean(axis=0)   # the recent mean rate
            rot = rot * Rotation.from_rotvec(rotvec + hold * (t_last + dt - t_prev))
        return Pose(rot, position)

    # ------------------------------------------------------------------ measurements
    def _measurement_noise(self, marker: Pose, camera_position: np.ndarray | None) -> np.ndarray:
        c = self.cfg
        R_meas = np.zeros((6, 6))
        R_meas[0:3, 0:3] = np.eye(3) * math.radians(c.marker_rotation_deg) ** 2
        cov = np.eye(3) * (c.marker_lateral_m ** 2 + c.vio_position_m ** 2)
        if camera_position is not None:
            u = marker.translation - camera_position
            n = np.linalg.norm(u)
            if n > 1e-6:
                u = u / n
                cov = cov + np.outer(u, u) * (c.marker_depth_m ** 2 - c.marker_lateral_m ** 2)
        R_meas[3:6, 3:6] = cov
        return R_meas

    def _ingest(self, obs: Observation) -> None:
        tick = obs.tick
        for capture_ns, pose in obs.controller_vio_samples_dvio:
            if is_finite(pose):
                t = self._s(capture_ns)
                if len(self._vio) and t > self._vio.t[-1]:
                    self._path_since_predict += float(np.linalg.norm(pose.translation - self._vio.v[-1].translation))
                self._vio.add(t, pose)
        imu = tick.imu
        if imu is not None and len(imu):
            for row in imu:
                if np.isfinite(row).all():
                    self._gyro.add(self._s(int(round(row[0] * 1e9))), np.asarray(row[1:4], dtype=float))
        if len(self._vio):
            horizon = self._vio.t[-1] - self.cfg.history_s
            self._vio.prune(horizon)
            self._gyro.prune(horizon)
        m = obs.marker
        frame = tick.new_frame   # a sighting counts once, on the tick that first carries its frame
        if m is not None and is_finite(m.T_dvio_controller) and frame is not None:
            image_ns = frame.t_ns
            cam = tick.T_dvio_display.translation if tick.T_dvio_display is not None else None
            t_img = self._s(image_ns)
            self._pending.append((t_img, m.T_dvio_controller, self._measurement_noise(m.T_dvio_controller, cam)))
            self._last_marker = (t_img, m.T_dvio_controller)
            self._sightings.append((t_img, m.T_dvio_controller.translation))
            while self._sightings and self._sightings[0][0] < t_img - self.cfg.marker_velocity_window_s:
                self._sightings.popleft()

    def _update_filter(self) -> None:
        """Pair every pending sighting whose image time the VIO stamps now cover, oldest first."""
        f = self.filter
        while self._pending and len(self._vio):
            t_img, M, R_meas = self._pending[0]
            t_stamp = t_img - f.d
            if t_stamp > self._vio.t[-1]:
                break   # the VIO of that moment has not arrived yet (latency): wait
            self._pending.popleft()
            V = self._vio_at(t_stamp)
            if V is None:
                continue   # older than the kept history
            if self._last_filter_t is not None:
                f.predict(t_img - self._last_filter_t, self._path_since_predict)
            self._path_since_predict = 0.0
            self._last_filter_t = t_img
            if not f.ready:
                f.initialise(M, V)
                continue
            v, _, _ = self._velocity(t_stamp)
            w = self._angular_rate_at(t_stamp)
            if not f.update(M, V, v, w, R_meas) and f.rejections >= self.cfg.max_rejections:
                f.initialise(M, V, f.d)   # persistent disagreement: the VIO or the anchor moved

    def _marker_velocity(self, t: float) -> np.ndarray | None:
        """Line fit through the sightings of the last ``marker_velocity_window_s`` (None: < 3 of them)."""
        s = [(ti, p) for ti, p in self._sightings if ti >= t - self.cfg.marker_velocity_window_s]
        if len(s) < 3:
            return None
        tt = np.array([ti for ti, _ in s])
        return _polyfit(tt - tt[-1], np.array([p for _, p in s]), 1)[1]

    def _angular_rate_at(self, t_stamp: float) -> np.ndarray:
        """World-frame angular rate of the VIO orientation at stamp time ``t`` (the two samples around it)."""
        ts = self._vio.t
        if len(ts) < 2:
            return np.zeros(3)
        i = int(np.searchsorted(np.fromiter(ts, float, len(ts)), t_stamp))
        i = min(max(i, 1), len(ts) - 1)
        dt = ts[i] - ts[i - 1]
        if dt <= 0:
            return np.zeros(3)
        return (self._vio.v[i].rotation * self._vio.v[i - 1].rotation.inv()).as_rotvec() / dt

    # ------------------------------------------------------------------ output
    def step(self, obs: Observation) -> Pose | None:
        t = self._s(obs.tick.t_ns)
        f = self.filter
        self._ingest(obs)
        self._update_filter()
        vio_now = self._vio_predicted(t - f.d)
        if vio_now is None and is_finite(obs.T_dvio_controller_vio):
            vio_now = obs.T_dvio_controller_vio      # no stamped samples: the received pose
        corrected = f.apply(vio_now) if (vio_now is not None and f.ready) else vio_now
        velocity = f.R.apply(self._velocity()[0]) if f.ready else self._velocity()[0]

        # the marker source: the newest sighting (at its image time, as T4-T7 report it)
        marker_now = None
        if self._last_marker is not None:
            t_img, M = self._last_marker
            age = t - t_img
            if 0 <= age <= self.cfg.max_prediction_s:
                marker_now = M.translation
        source = "marker" if obs.in_view and marker_now is not None else ("vio" if corrected is not None else None)
        if source is None:
            if obs.in_view and is_finite(obs.marker.T_dvio_controller):
                return obs.marker.T_dvio_controller
            return None
        position = corrected.translation if source == "vio" else marker_now
        if source == "marker" and self.cfg.marker_gain < 1:
            # inside: a complementary filter — the newest sightings, moved by the VIO velocity, average the marker's noise
            if self._source == "marker" and self._inside is not None and self._last_t is not None:
                predicted = self._inside + velocity * (t - self._last_t)
                position = self.cfg.marker_gain * position + (1 - self.cfg.marker_gain) * predicted
            self._inside = position
        else:
            self._inside = None
        rotation = corrected.rotation if corrected is not None else self._last_marker[1].rotation
        if source == "marker" and corrected is not None:
            rotation = self._pulled_by_sighting(rotation)

        # continuity: carry the difference across a switch, then let it decay
        if self._last_t is not None:
            self._offset = self._offset * math.exp(-max(t - self._last_t, 0.0) / self.cfg.blend_time_s)
        if self._source is not None and source != self._source and self._last_out is not None \
                and corrected is not None and self._last_corrected is not None:
            # a switch: this tick's output = the last output moved by the estimated motion over the
            # tick, and the difference to the new source is carried and decays
            motion = velocity
            if self._source == "marker":
                # leaving the view: the marker's own velocity is fresher than the VIO's (~0.15 s old)
                marker_velocity = self._marker_velocity(t)
                if marker_velocity is not None:
                    motion = marker_velocity
            target = self._last_out.translation + motion * (t - self._last_t)
            self._offset = target - position
        self._source = source
        self._last_corrected = None if corrected is None else corrected.translation
        self._last_t = t
        out = Pose(rotation, position + self._offset)
        if not is_finite(out):
            return None
        self._last_out = out
        return out

    def _pulled_by_sighting(self, rotation: Rotation) -> Rotation:
        """Inside the view: the predicted orientation corrected by the newest sighting.

        The sighting is compared with the corrected VIO at its own image time (against the tick's,
        the pull would drag the output back by the image's age), and a Kalman share of the
        difference corrects the prediction: large when the VIO at the image time is itself a
        prediction (the controller's streams arrive ~0.15 s late), small when it has data there.
        """
        c, f = self.cfg, self.filter
        t_img, M = self._last_marker
        at_img = self._vio_at(t_img - f.d)
        if at_img is None:                  # the image is newer than the newest VIO sample (usual)
            at_img = self._vio_predicted(t_img - f.d)
        if at_img is None:
            return rotation
        pull = (M.rotation * (f.apply(at_img) if f.ready else at_img).rotation.inv()).as_rotvec()
        if np.linalg.norm(pull) > math.radians(3 * c.marker_rotation_deg):   # a flip does not pull
            return rotation
        t_data = max(self._vio.t[-1], self._gyro.t[-1] if len(self._gyro) else -math.inf)   # where measurements end
        h = max(0.0, (t_img - f.d) - t_data)
        P = c.pull_vio_rotation_deg ** 2 + (c.pull_prediction_deg_per_s * h) ** 2
        gain = P / (P + c.pull_marker_rotation_deg ** 2)
        return Rotation.from_rotvec(gain * pull) * rotation

    def __repr__(self) -> str:
        return f"{self.name}(fused: ESKF correction + time offset, gyro prediction, continuous output)"

