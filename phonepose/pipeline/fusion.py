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
  "Online temporal calibration for camera-IMU systems", IJRR 33(7)); that velocity is a line fit
  centred on the pair's time, so that it does not share the paired samples' noise (errors in
  variables: the slope at the newest sample biased ``d`` by +10 ms on 1.5 mm of VIO jitter).
* **Flipped or outlying marker poses** (IPPE's second solution, motion blur) are rejected by a
  chi-square gate on the innovation; a run of rejections re-initialises the filter (a VIO
  relocalisation jump or a re-resolved anchor).
* **The VIO is old at every tick**: it is predicted to the tick time, the position along a
  fit of the VIO positions less the **accelerometer**'s double integral (gravity removed through the
  VIO orientation; the fit's curvature takes up the accelerometer's bias), carried on by the
  integral up to the newest IMU sample (``accel_*``; without IMU, or with ``accel_prediction`` 0: a
  quadratic fit of the last ``velocity_window_s`` of VIO samples, a line's slope lags behind an
  acceleration), the orientation with the controller's **gyroscope** (the samples received after
  the newest VIO sample, then their recent mean rate).
* **The output jumps where the marker appears or disappears** (T4-T7 switch source). At a switch
  T8 moves its output by the estimated motion over the tick (leaving the view: the marker's own
  velocity; entering it: the VIO velocity carried to the tick by the acceleration, which decays
  with a hand's acceleration correlation time, ``entry_acceleration_time_s``) and carries
  the difference to the new source as an offset that decays with ``blend_time_s``: no step.

Output: inside the view, the newest sighting's position **moved from its image time to the tick**
along the corrected VIO velocity (the 30 Hz image is ~17 ms old at a 20 Hz tick; T4-T7 report it where
it was), and the predicted VIO orientation through ``C``, corrected by a share of the newest sighting's
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
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.errors import ConfigError
from phonepose.geometry import (
    Pose,
    Quat,
    is_finite,
    quat_apply_rows,
    quat_as_rotvec,
    quat_from_rotvec,
    quat_inv,
    quat_matrix,
    quat_mul,
    quat_normalised,
)
from phonepose.pipeline.types import Observation
from phonepose.series import interp_columns, interp_columns_inside, newer_than_before

# Per tick, T8 works on single poses as (quaternion tuple, translation array) pairs with the closed-form
# math of phonepose.geometry: scipy's Rotation costs tens of microseconds per single-rotation operation
# (its array-API layer), which made T8 cost 1.3 ms per tick; scipy stays for what is not per tick
# (initialise). The numbers agree with the scipy version to rounding (docs/performance.md, "T8").
RawPose = tuple[Quat, np.ndarray]


def _raw(pose: Pose) -> RawPose | None:
    """A single Pose as (quaternion, translation), or None if anything in it is not finite."""
    raw = pose.as_raw()    # the pose's own quaternion tuple: no scipy Rotation built (~50 us each on this VM)
    if not all(map(math.isfinite, raw)):
        return None
    return raw[:4], np.asarray(pose.translation, dtype=float)

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
    # the velocity in d's Jacobian: a line fit through the VIO samples of this window centred on the pair's
    # time (the pair waits half of it for the VIO to arrive; C changes slowly, so the delay costs nothing)
    offset_velocity_window_s: float = 0.2
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
    # past the newest gyro sample that mean rate decays as a first-order Markov (Singer) angular rate with
    # correlation time tau: the angle over h is rate tau (1 - e^(-h / tau)) (inf: held whole, 0: not carried).
    # tau is estimated online (> 0 s: _RateCorrelation): the regression of each gyro_window_s mean rate on the
    # one gyro_window_s before it, exponentially weighted over gyro_rate_adapt_s, is the rate's correlation rho
    # over that lag, and tau = -lag / ln(rho). Held whole over the ~0.15 s prediction, the rate overshoots a
    # hand's turns, which stop and reverse within a few tenths of a second: on fr2_desk's recorded motion T8's
    # exact r_ATE outside the view was 1.73 deg against T6's 1.65 (T6 holds the VIO's own, older orientation).
    # The estimate's median is 0.27 s on fr1_xyz, 0.37 s on fr2_desk, 0.36-1.12 s on the simulated hand (exp2
    # REC2/TRI2, exp1; tools/gyro_rate_time.py): one fixed tau would be tuned to one kind of motion
    # (docs/pipeline.md, "The gyro's held rate")
    gyro_rate_adapt_s: float = 5.0                   # 0: tau fixed at gyro_rate_time_s
    gyro_rate_adapt_min_s: float = 2.0               # of gyro history before the estimate is used
    gyro_rate_time_s: float = math.inf               # tau before that, or always when not adapted
    max_prediction_s: float = 0.5                    # never extrapolate further
    history_s: float = 1.0                           # VIO / IMU kept for pairing
    # output
    # inside: weight of a new sighting against the previous output moved by the VIO velocity (a complementary
    # filter; 1 = the sighting alone). Once the sighting is moved to the tick, its 2 mm lateral noise is less
    # than what the filter's memory carries (the VIO velocity's error over a tick, the offset after a re-entry):
    # 0.7 cost 2-8 % in p_ATE / p_RE inside (docs/pipeline.md, "T8 cell by cell")
    marker_gain: float = 1.0
    # inside: the sighting's orientation corrects the output by P / (P + pull_marker_rotation_deg^2), with
    # P = pull_vio_rotation_deg^2 + (pull_prediction_deg_per_s * h)^2 and h how far the image lies past the
    # newest gyro sample (the held rate's error grows ~13 deg/s: 1.9 deg RMS over 0.15 s on the simulator)
    pull_marker_rotation_deg: float = 1.0            # a sighting's orientation error in the output (notes: 0.4 deg median)
    pull_vio_rotation_deg: float = 0.3               # the corrected VIO orientation's error where it has data
    pull_prediction_deg_per_s: float = 12.0          # growth of the held-rate prediction's orientation error
    # a sighting's orientation error grows as the marker faces the camera, where IPPE's two solutions come close:
    # its RMS is ~4.3 deg / sqrt(ambiguity ratio) (measured on exp1 seed 7, exact ground truth, 1226 sightings,
    # ratios 1-50; docs/pipeline.md "The sighting's ambiguity"). The orientation noise of a sighting, in the filter
    # and in the pull, is scaled by sqrt(ref / ratio) (the ratio clipped to >= 1; 0: unknown, not scaled): ref 13,
    # that session's median ratio, keeps a typical sighting at the defaults above. 0: off
    rotation_ambiguity_ref: float = 13.0
    marker_velocity_window_s: float = 0.2            # the marker's velocity (used when it leaves the view)
    blend_time_s: float = 0.1                        # decay of the offset carried across a source switch
    # inside: the sighting is moved from its image time to the tick along the corrected VIO velocity (the
    # 30 Hz image is ~17 ms old at a 20 Hz tick: 5 mm at 0.3 m/s; T4-T7 report it at the image time)
    marker_to_tick: int = 1
    # entering the view: the motion over the switching tick is the VIO velocity carried from the newest VIO
    # sample to the tick (h ~0.15 s) by the quadratic fit's acceleration a, as a first-order Markov (Singer)
    # acceleration with this correlation time tau: v + a tau (1 - exp(-h / tau)). A hand's acceleration does
    # not last 0.15 s: carried whole (tau -> inf) it made fr1_xyz's real motion jump 1.78 cm; without it
    # (tau = 0) exp2 seed 4's REC2_01, speeding up into the view, jumped 1.09 cm. 0.05 s minimises the RMS
    # velocity error over the 44 entries of exp2 TRI2/REC2 seeds 0-5 and fr1_xyz (tools/entry_velocity.py;
    # alone, exp2 prefers 0.15 s, fr1_xyz 0.01 s): largest jump 0.90 cm on exp2, 0.70 cm on fr1_xyz
    # (docs/pipeline.md, "Real hand motion")
    entry_acceleration_time_s: float = 0.05
    # the accelerometer in the prediction (1; 0: off, the VIO fit alone). The VIO positions of the last
    # accel_window_s, less the double integral of the measured acceleration (the specific force turned into the
    # world by the VIO orientation, interpolated, past the newest VIO sample by the gyro; gravity added), are
    # fitted with a quadratic of degree accel_fit_degree (its curvature takes up the accelerometer's bias, ~0.1
    # m/s^2, which over the window would tilt the line); the prediction is that fit plus the integral up to the
    # newest IMU sample (fresher than the newest VIO sample), then the newest acceleration (mean of its last
    # accel_recent_s) decaying with correlation time accel_carry_time_s. 0: past the newest IMU sample the
    # velocity is held, as the fit's slope is without the accelerometer: carried with 0.05 s, every exp2 cell was
    # worse (outside p_RE 1.010x T7L against 0.928x; fr1_xyz exact p_ATE 1.05 against 1.14 cm). Entering the
    # view the motion over the tick still carries it with entry_acceleration_time_s (held, exp2 seeds 3-5 jumped
    # 1.02 cm). The acceleration is a centred moving
    # average over accel_smooth_s (one-sided at
    # the newest samples, there one period of the 8-12 Hz tremor): unsmoothed, the simulated tremor's ~3 m/s^2
    # put its ~5 cm/s into the velocity held for ~0.15 s (exp2 lost 2 of 12 cells at 0.1 s). Measured
    # (docs/pipeline.md, "Real hand motion"): exact p_ATE fr1_xyz 1.39 -> 1.05 cm, fr2_desk 0.54 -> 0.49 cm;
    # exp2 keeps 12/12 cells with both ground truths at seeds 0-2
    accel_prediction: int = 1
    accel_window_s: float = 1.0
    accel_fit_degree: int = 2
    accel_recent_s: float = 0.05
    accel_smooth_s: float = 0.2
    accel_carry_time_s: float = 0.0

    @classmethod
    def from_dict(cls, values: dict) -> FusionConfig:
        known = {f.name: f.type for f in fields(cls)}
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise ConfigError(f"unknown T8 parameter(s) {', '.join(unknown)}; valid: {', '.join(known)}")
        out: dict[str, Any] = {}
        for k, v in values.items():
            try:
                out[k] = int(v) if known[k] in ("int", int) else float(v)
            except (TypeError, ValueError):
                raise ConfigError(f"T8 parameter {k}={v!r} is not a number") from None
        return cls(**out)


def _polyfit(t: np.ndarray, values: np.ndarray, degree: int) -> np.ndarray:
    """Least-squares polynomial coefficients (constant first) of ``values`` over ``t``, one column per
    axis: the normal equations directly (np.polynomial.polyfit costs more than the rest of a tick)."""
    A = np.empty((len(t), degree + 1))
    A[:, 0] = 1.0
    for k in range(1, degree + 1):
        A[:, k] = A[:, k - 1] * t     # t ** k as the power's own products (exact for k <= 2: t * t, as pow)
    return _solve(A.T @ A, A.T @ values)


# np.linalg.solve's LAPACK gesv without its wrapper (the checks and an errstate context cost ~5 µs, 3x the
# solve on 3x3 normal equations, twice a tick): the same routine, so the same bits. T8's systems are never
# singular (samples on distinct stamps); should numpy drop the private module, the public call is used.
try:
    from numpy.linalg import _umath_linalg

    def _solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return _umath_linalg.solve(a, b, signature="dd->d")
except ImportError:   # pragma: no cover
    _solve = np.linalg.solve


def markov_carry_s(h, tau: float):
    """How long a first-order Markov (Singer) quantity with correlation time ``tau`` acts over ``h`` s when its
    value at the start is carried on: tau (1 - e^(-h / tau)); ``h`` for tau = inf, 0 for tau = 0. T8 carries
    so the acceleration entering the view (FusionConfig.entry_acceleration_time_s; tools/entry_velocity.py
    replays it), past the newest IMU sample (AccelMotion) and the gyro's mean rate (gyro_rate_*). ``h`` a
    float: a float (math, a tick's scalar); an array: an array."""
    if isinstance(h, float):
        return h if math.isinf(tau) else (tau * -math.expm1(-h / tau) if tau > 0 else 0.0)
    if math.isinf(tau):
        return h
    return 0.0 * h if tau <= 0 else tau * -np.expm1(-np.asarray(h) / tau)


_YZX, _ZXY = np.array([1, 2, 0]), np.array([2, 0, 1])   # (index arrays: a list is converted per call)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of rows (n, 3), the same products and differences, at half its cost on a few rows."""
    return a[:, _YZX] * b[:, _ZXY] - a[:, _ZXY] * b[:, _YZX]


def _steps(t_before: float, t: np.ndarray) -> np.ndarray:
    """``np.diff(t, prepend=t_before)``: the same differences, without np.diff's concatenation (~9 µs a call,
    twice a tick: 5 % of T8)."""
    out = np.empty(len(t))
    if len(t):
        out[0] = t[0] - t_before
        np.subtract(t[1:], t[:-1], out=out[1:])
    return out


def _turned_by_vio(ts: np.ndarray, q: np.ndarray, t: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Vectors ``f`` (n, 3) at stamps ``t`` within the VIO samples' (``ts``, quaternions ``q``) turned by the
    VIO orientation there, normalised-linearly interpolated (the short way round)."""
    # t <= ts[-1] (the samples are turned up to the newest VIO stamp), and the stamps rise strictly (_Ring):
    # the index needs no upper bound and the weight none above 1; before ts[0] it is 0 (the oldest sample)
    i = np.maximum(ts.searchsorted(t), 1)
    w = np.maximum((t - ts[i - 1]) / (ts[i] - ts[i - 1]), 0.0)[:, None]
    q0, q1 = q[i - 1], q[i]
    q1 = q1 * np.copysign(1.0, np.add.reduce(q0 * q1, axis=1, keepdims=True))   # the short way round
    return quat_apply_rows((1 - w) * q0 + w * q1, f)


GRAVITY = np.array([0.0, 0.0, -9.80665])   # display_vio and the controller's VIO world are gravity aligned, z up


class AccelMotion:
    """The VIO position's motion from its newest sample ``t0`` on, with the accelerometer (FusionConfig.accel_*).

    ``p0, v0, beta``: the fit of the VIO positions less the double integral ``D`` of the measured
    acceleration (zero with its rate at ``t0``): p0 + v0 s + beta s^2 / 2 + D(s), s = t - t0 (beta: what the
    integral misses over the window, the accelerometer's bias turned into the world). ``s_imu``: the newest
    IMU sample's s; ``D``, ``V`` the integral's position and velocity there; ``a``: the newest acceleration,
    carried past ``s_imu`` decaying with correlation time ``tau`` (a first-order Markov acceleration)."""

    def __init__(self, t0: float, p0: np.ndarray, v0: np.ndarray, beta: np.ndarray, s_k: np.ndarray,
                 P_k: np.ndarray, V_k: np.ndarray, a: np.ndarray, tau: float):
        self.t0, self.p0, self.v0, self.beta = t0, p0, v0, beta
        self.s_k, self.P_k, self.V_k = s_k, P_k, V_k      # the integral at the IMU samples from t0 on (s_k[0] = 0)
        self.a, self.tau = a, tau
        self._last: tuple[tuple, tuple[np.ndarray, np.ndarray]] | None = None   # (t, tau) -> the last result

    def at(self, t: float, tau: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(position, velocity) at stamp time ``t`` >= t0, the acceleration past the newest IMU sample decaying
        with correlation time ``tau`` (None: this motion's own). A tick asks for the same instant twice (the
        predicted VIO's position, then its velocity): the last answer is kept (callers never modify it)."""
        if self._last is not None and self._last[0] == (t, tau):
            return self._last[1]
        self._last = ((t, tau), self._at(t, tau))
        return self._last[1]

    def _at(self, t: float, tau: float | None) -> tuple[np.ndarray, np.ndarray]:
        s = max(t - self.t0, 0.0)
        s_imu = float(self.s_k[-1])
        u = min(s, s_imu)
        if u == s_imu:   # the usual case (the tick is past the newest IMU sample): np.interp's own end value
            D, V = self.P_k[-1].copy(), self.V_k[-1].copy()
        else:
            D, V = interp_columns(u, self.s_k, self.P_k), interp_columns(u, self.s_k, self.V_k)
        position = self.p0 + self.v0 * s + 0.5 * self.beta * u * u + self.beta * u * (s - u) + D
        velocity = self.v0 + self.beta * u + V
        h = s - u   # past the newest IMU sample: the integral's velocity held, the acceleration decaying
        if h > 0:
            position = position + V * h
            tau = self.tau if tau is None else tau
            if math.isinf(tau):
                position = position + 0.5 * self.a * h * h
                velocity = velocity + self.a * h
            elif tau > 0:
                carry = markov_carry_s(h, tau)
                position = position + self.a * (tau * h - tau * carry)
                velocity = velocity + self.a * carry
        return position, velocity


# a constant of the filter's update, built once (np.eye per call cost ~5 % of a tick)
_I7 = np.eye(7)


class CorrectionFilter:
    """Error-state Kalman filter of the correction C = (R_C, t_C) and the VIO time offset d.

    Nominal state: ``R_C`` (unit quaternion ``q``, and its matrix), ``t_C`` (3,), ``d`` (s; true
    capture time = VIO stamp + d).
    Error state (7): ``δθ`` (left-multiplied: R_C ← exp(δθ) R_C), ``δt``, ``δd``.
    A marker sighting at image time t measures the controller pose M; the model is
    ``M = C · V(t - d)`` with V the anchor-mapped VIO interpolated at stamp time ``t - d``.
    """

    def __init__(self, cfg: FusionConfig):
        self.cfg = cfg
        self.reset()

    def reset(self) -> None:
        self.q: Quat | None = None          # None: not initialised (no sighting yet)
        self._Rm = np.eye(3)
        self.t = np.zeros(3)
        self.d = 0.0
        self.P = np.zeros((7, 7))
        self.rejections = 0
        self.since_init = 0
        self.accepted = 0
        self.rejected = 0

    @property
    def ready(self) -> bool:
        return self.q is not None

    @property
    def R(self) -> Rotation | None:
        """The correction's rotation as a scipy Rotation (for inspection; the filter keeps ``q``)."""
        return None if self.q is None else Rotation.from_quat(self.q)

    def _set_rotation(self, q: Quat) -> None:
        self.q = q
        self._Rm = np.array(quat_matrix(q))        # numpy products below: cheaper per call

    def initialise(self, M: RawPose, V: RawPose, d: float = 0.0) -> None:
        """Once per (re-)initialisation, not per tick: scipy for the heading/tilt split."""
        c = self.cfg
        R = Rotation.from_quat(M[0]) * Rotation.from_quat(V[0]).inv()
        if c.tilt_deg < c.marker_rotation_deg:
            # both VIO worlds are gravity aligned (z up): C is a heading change and a tilt of at most
            # ~tilt_deg; the sighting's tilt beyond that is its noise, clipped here
            heading = Rotation.from_euler("z", R.as_euler("ZYX")[0])
            tilt = (R * heading.inv()).as_rotvec()
            limit = math.radians(c.tilt_deg)
            if np.linalg.norm(tilt) > limit:
                tilt = tilt * (limit / np.linalg.norm(tilt))
            R = Rotation.from_rotvec(tilt) * heading
        self._set_rotation(tuple(R.as_quat().tolist()))
        self.t = M[1] - self._Rm @ V[1]
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
        self.P.reshape(-1)[::8] += (q_tilt, q_tilt, q_rot, q_pos, q_pos, q_pos, q_d)   # the diagonal (a view)

    def apply(self, V: RawPose) -> RawPose:
        return quat_mul(self.q, V[0]), self._Rm @ V[1] + self.t

    def update(self, M: RawPose, V: RawPose, v_vio: np.ndarray, w_vio: np.ndarray, R_meas: np.ndarray) -> bool:
        """One sighting: M (marker, display_vio), V = VIO at stamp ``t - d``, its velocity and
        angular rate (world frame, per second). Returns False if the gate rejected it."""
        # the VIO position, angular rate and velocity turned into display_vio by one product
        turned = self._Rm @ np.array([V[1], w_vio, v_vio]).T
        p_world = turned[:, 0]
        y = np.empty(6)
        y[0:3] = quat_as_rotvec(quat_mul(M[0], quat_inv(quat_mul(self.q, V[0]))))
        y[3:6] = M[1] - (p_world + self.t)
        (px, wx, vx), (py, wy, vy), (pz, wz, vz) = turned.tolist()
        if not self.cfg.lever_arm:
            px = py = pz = 0.0
        # H, written out: the rotation error's and the position's Jacobians (the lever arm -skew(p) on the
        # position's rotation columns), and d's: d later means the pair looks at an earlier VIO sample,
        # dV/dd = -velocity (one array from floats, where a copy of a constant and six assignments took ~12 calls)
        H = np.array([[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, -wx], [0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -wy],
                      [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -wz], [0.0, pz, -py, 1.0, 0.0, 0.0, -vx],
                      [-pz, 0.0, px, 0.0, 1.0, 0.0, -vy], [py, -px, 0.0, 0.0, 0.0, 1.0, -vz]])
        with np.errstate(over="ignore", invalid="ignore"):   # absurd inputs give inf/NaN: gated below
            HP = H @ self.P
            S = HP @ H.T + R_meas
            # one factorisation for both: (P H^T S^-1)^T (S symmetric) and S^-1 y; np.linalg.solve's LAPACK
            # routine (_solve), which under this errstate returns NaN where np.linalg.solve raised for a
            # singular S: such a sighting is skipped without counting as a rejection, as before
            rhs = np.empty((6, 8))
            rhs[:, :7] = HP
            rhs[:, 7] = y
            try:
                both = _solve(S, rhs)
            except np.linalg.LinAlgError:   # (the public np.linalg.solve, should numpy drop the private module)
                return False
            K_T, m2 = both[:, :7], float(y @ both[:, 7])
        if not math.isfinite(m2) and np.isfinite(S).all() and np.isfinite(y).all():
            return False
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
            # now estimate the time offset too, and let C move with it (it absorbed any offset so far)
            c = self.cfg
            self.P[6, 6] = c.init_time_offset_s ** 2
            self.P[2, 2] += math.radians(c.marker_rotation_deg) ** 2
            self.P[3:6, 3:6] += np.eye(3) * c.marker_depth_m ** 2
        return True


class _RateCorrelation:
    """The correlation time of the gyro's mean rate, estimated online (FusionConfig.gyro_rate_*).

    ``update(t, rate)`` takes the mean rate of the window that ends at gyro stamp ``t``. Its partner is
    the newest earlier mean whose window ended at least ``lag`` (the window's length) before, so the two
    windows do not overlap. Sums of ``rate . partner`` and ``partner . partner`` decay with time constant
    ``memory_s``; their ratio rho is the least-squares coefficient of the rate on the rate ``lag``
    earlier, and for a first-order Markov rate rho = e^(-lag / tau). ``tau`` is then -lag / ln(rho) (inf:
    held, for rho >= 1; 0: not carried, for rho <= 0), and ``initial`` until ``min_history_s`` of means."""

    def __init__(self, lag_s: float, memory_s: float, min_history_s: float, initial: float) -> None:
        self.lag_s, self.memory_s, self.min_history_s = lag_s, memory_s, min_history_s
        self.tau = initial
        self._means: deque[tuple[float, np.ndarray]] = deque()
        self._sxy = self._sxx = 0.0
        self._first_t: float | None = None
        self._last_t: float | None = None

    def update(self, t: float, rate: np.ndarray) -> float:
        means = self._means
        means.append((t, rate))
        if self._first_t is None:
            self._first_t = t
        while len(means) >= 2 and means[1][0] <= t - self.lag_s:
            means.popleft()
        if means[0][0] > t - self.lag_s:
            return self.tau                     # no mean a whole window earlier yet
        partner = means[0][1]
        decay = math.exp(-max(t - self._last_t, 0.0) / self.memory_s) if self._last_t is not None else 0.0
        self._last_t = t
        self._sxy = self._sxy * decay + float(rate @ partner)
        self._sxx = self._sxx * decay + float(partner @ partner)
        if t - self._first_t >= self.min_history_s and self._sxx > 0:
            rho = self._sxy / self._sxx
            self.tau = math.inf if rho >= 1 else (0.0 if rho <= 0 else -self.lag_s / math.log(rho))
        return self.tau


class _Ring:
    """Recent samples of one controller stream on its own stamps (seconds, ascending), one row of
    ``width`` floats each, in preallocated numpy arrays: appending and dropping the oldest cost no
    array rebuild per tick (``t`` and ``v`` are views, valid until the next ``add``)."""

    def __init__(self, width: int, capacity: int = 256) -> None:
        self._t = np.empty(capacity)
        self._v = np.empty((capacity, width))
        self._lo = self._hi = 0
        self.last_t = -math.inf              # the newest stamp (a Python float: read every tick)

    def add(self, t: float, value) -> None:
        if t <= self.last_t:
            return
        if self._hi == len(self._t):
            self._make_room(1)
        self._t[self._hi] = t
        self._v[self._hi] = value
        self._hi += 1
        self.last_t = t

    def add_many(self, t: np.ndarray, values: np.ndarray) -> None:
        """``add`` for each row in order: a row is kept if its stamp is newer than every earlier one."""
        if not (len(t) and t[0] > self.last_t and (t[1:] > t[:-1]).all()):   # (in order: every row kept)
            keep = newer_than_before(t, self.last_t)
            t, values = t[keep], values[keep]
        if self._hi + len(t) > len(self._t):
            self._make_room(len(t))
        self._t[self._hi:self._hi + len(t)] = t
        self._v[self._hi:self._hi + len(t)] = values
        self._hi += len(t)
        if len(t):
            self.last_t = float(t[-1])

    def _make_room(self, extra: int) -> None:
        """Room for ``extra`` more rows at the end: the kept rows slid to the front, or the arrays grown
        (amortised) when the rows kept fill half of them or the new ones would not fit even after the slide
        (a batch larger than the free room once looped here for ever, sliding rows already at the front)."""
        n = self._hi - self._lo
        if 2 * n >= len(self._t) or n + extra > len(self._t):
            size = max(2 * len(self._t), n + extra)
            t, v = np.empty(size), np.empty((size, self._v.shape[1]))
        else:
            t, v = self._t, self._v
        t[:n] = self._t[self._lo:self._hi].copy()
        v[:n] = self._v[self._lo:self._hi].copy()
        self._t, self._v, self._lo, self._hi = t, v, 0, n

    def prune(self, horizon: float) -> None:
        """Drop the oldest samples while the second oldest is older than ``horizon`` (at least 2 stay)."""
        older = int(self._t[self._lo:self._hi].searchsorted(horizon, side="left"))
        self._lo += max(0, min(older - 1, self._hi - self._lo - 2))

    @property
    def t(self) -> np.ndarray:
        return self._t[self._lo:self._hi]

    @property
    def v(self) -> np.ndarray:
        return self._v[self._lo:self._hi]

    def __len__(self) -> int:
        return self._hi - self._lo


def _interpolate(t0: float, s0: list, t1: float, s1: list, t: float) -> RawPose:
    """As geometry.interpolate on raw rows (qx, qy, qz, qw, x, y, z): linear translation, slerp."""
    a = (t - t0) / (t1 - t0)
    q0, q1 = tuple(s0[:4]), tuple(s1[:4])
    r = quat_as_rotvec(quat_mul(quat_inv(q0), q1))
    q = quat_mul(q0, quat_from_rotvec((a * r[0], a * r[1], a * r[2])))
    b = 1.0 - a   # the translation as floats (numpy's element-wise products and sums), one array at the end
    return q, np.array([b * s0[4] + a * s1[4], b * s0[5] + a * s1[5], b * s0[6] + a * s1[6]])


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
        self._vio = _Ring(7)                       # (stamp s) -> qx qy qz qw x y z in display_vio (anchor-mapped)
        # (stamp s) -> gyro rad/s (0:3) and specific force m/s^2 (3:6), body frame: one ring, as the samples
        # come (one stamp for both; two rings were kept and pruned in step, twice the calls)
        self._imu = _Ring(6)
        self._accel_cache: tuple[tuple, AccelMotion | None] | None = None
        self._held_rate = [0.0, 0.0, 0.0]         # the gyro's mean rate over its newest gyro_window_s (_ingest)
        self._rate_correlation = _RateCorrelation(self.cfg.gyro_window_s, self.cfg.gyro_rate_adapt_s,
                                                  self.cfg.gyro_rate_adapt_min_s, self.cfg.gyro_rate_time_s)
        self._turned = (np.empty(0), np.empty((0, 3)))  # IMU stamps and their specific force in display_vio, final
        self._pending: deque = deque()             # (image s, marker RawPose, R_meas)
        self._last_filter_t: float | None = None
        self._path_since_predict = 0.0
        self._velocity_cache: tuple[tuple, tuple[np.ndarray, np.ndarray, float | None]] | None = None
        self._offset = np.zeros(3)                 # carried across source switches, decays
        self._source: str | None = None
        self._last_out: np.ndarray | None = None   # the last output's position
        self._last_t: float | None = None
        # the newest sighting: (image s, marker pose, its orientation noise factor from _rotation_scale)
        self._last_marker: tuple[float, RawPose, float] | None = None
        self._inside: np.ndarray | None = None     # the filtered marker position (marker_gain < 1)
        self._sightings: deque = deque()           # (image s, marker position) of the last marker_velocity_window_s
        self._had_corrected = False                # the last tick had a corrected VIO pose
        self._accel = np.zeros(3)                  # the newest quadratic VIO fit's acceleration (_velocity)

    # ------------------------------------------------------------------ time
    def _s(self, t_ns: int) -> float:
        if self._t0_ns is None:
            self._t0_ns = int(t_ns)
        return (int(t_ns) - self._t0_ns) * _NS

    # ------------------------------------------------------------------ VIO history
    def _add_vio(self, t: float, pose: RawPose) -> None:
        q, p = pose
        x, y, z = p.tolist()
        if len(self._vio) and t > self._vio.last_t:   # (the ring keeps only newer samples)
            px, py, pz = self._vio.v[-1, 4:7].tolist()
            dx, dy, dz = x - px, y - py, z - pz    # (products, not ** 2: a float power raises on overflow)
            self._path_since_predict += math.sqrt(dx * dx + dy * dy + dz * dz)
        self._vio.add(t, (*q, x, y, z))

    def _vio_at(self, t: float) -> RawPose | None:
        """Anchor-mapped VIO at stamp time ``t`` (None outside the kept samples)."""
        ts = self._vio.t
        n = len(ts)
        if n < 2 or t < ts[0] or t > ts[-1]:
            return None
        i = int(ts.searchsorted(t))
        i = min(max(i, 1), n - 1)
        v = self._vio.v
        return _interpolate(float(ts[i - 1]), v[i - 1].tolist(), float(ts[i]), v[i].tolist(), t)

    def _velocity(self, t_end: float | None = None) -> tuple[np.ndarray, np.ndarray, float | None]:
        """(velocity, fitted position at the newest used sample, its stamp) from a least-squares
        fit through the VIO samples of the last ``velocity_window_s`` up to ``t_end``."""
        n = len(self._vio)
        if n == 0:
            return np.zeros(3), np.zeros(3), None
        ts = self._vio.t
        key = (n, ts[-1], ts[0], t_end)
        if self._velocity_cache is not None and self._velocity_cache[0] == key:
            return self._velocity_cache[1]
        hi = n if t_end is None else int(ts.searchsorted(t_end, side="right"))
        hi = max(hi, 1)
        lo = int(ts.searchsorted(ts[hi - 1] - self.cfg.velocity_window_s, side="left"))
        if hi - lo < 2:
            out = (np.zeros(3), self._vio.v[hi - 1, 4:7].copy(), float(ts[hi - 1]))
            if t_end is None:
                self._accel = np.zeros(3)
        else:
            tt = ts[lo:hi] - ts[hi - 1]
            pp = self._vio.v[lo:hi, 4:7]
            # quadratic: its slope at the newest sample does not lag behind an acceleration as a line's does
            degree = self.cfg.velocity_fit_degree if hi - lo > self.cfg.velocity_fit_degree + 1 else 1
            c = _polyfit(tt, pp, degree)
            out = (c[1], c[0], float(ts[hi - 1]))
            if t_end is None:   # the fit up to the newest sample: its acceleration, for the entry into the view
                self._accel = 2 * c[2] if degree == 2 else np.zeros(3)
        self._velocity_cache = (key, out)
        return out

    def _accel_motion(self) -> AccelMotion | None:
        """The accelerometer-aided motion from the newest VIO sample (FusionConfig.accel_*), or None (off, or
        too few VIO or IMU samples)."""
        c = self.cfg
        if not c.accel_prediction or len(self._vio) < c.accel_fit_degree + 2 or len(self._imu) < 2:
            return None
        ts, tk = self._vio.t, self._imu.t
        t0 = float(ts[-1])
        key = (len(ts), t0, ts[0], len(tk), self._imu.last_t, self.filter.ready)
        if self._accel_cache is not None and self._accel_cache[0] == key:
            return self._accel_cache[1]
        self._accel_cache = (key, None)
        if tk[-1] <= t0:    # no IMU sample past the newest VIO one yet (about half the computations)
            return None
        lo = int(ts.searchsorted(t0 - c.accel_window_s, side="left"))
        k_lo = max(int(tk.searchsorted(ts[lo], side="right")) - 1, 0)   # the IMU sample at or before ts[lo]
        lo = int(ts.searchsorted(tk[k_lo], side="left"))                 # VIO samples the integral covers
        if len(ts) - lo < c.accel_fit_degree + 2 or len(tk) - k_lo < 2:
            return None
        t_k = tk[k_lo:]
        f_world = self._specific_force_world(ts, t_k, self._imu.v[k_lo:], t0)
        g = GRAVITY[2] * self.filter._Rm[2] if self.filter.ready else GRAVITY   # _Rm.T @ GRAVITY (x, y are 0)
        a_k = f_world + g
        if c.accel_smooth_s > 0:
            # a centred moving average (one-sided at the newest samples): the 8-12 Hz tremor's ~3 m/s^2 would
            # otherwise put its velocity (~5 cm/s) into the fit's slope, which the prediction holds for ~0.15 s
            cum = np.zeros((len(t_k) + 1, 3))
            np.cumsum(a_k, axis=0, out=cum[1:])
            a_lo = t_k.searchsorted(t_k - c.accel_smooth_s / 2, side="left")
            a_hi = t_k.searchsorted(t_k + c.accel_smooth_s / 2, side="right")
            a_k = (cum[a_hi] - cum[a_lo]) / (a_hi - a_lo)[:, None]
        # double integral (trapezoid velocity, exact for a linear acceleration per step), zero with its rate at t0;
        # V and P side by side (one interpolation for both), zero at the window's first sample
        dt = (t_k[1:] - t_k[:-1])[:, None]
        VP = np.zeros((len(t_k), 6))
        np.cumsum((a_k[:-1] + a_k[1:]) / 2 * dt, axis=0, out=VP[1:, 0:3])
        np.cumsum(VP[:-1, 0:3] * dt + (a_k[:-1] / 3 + a_k[1:] / 6) * dt * dt, axis=0, out=VP[1:, 3:6])
        # the integral at t0 (t_k[0] <= t0 < t_k[-1]), the reference of the one used below
        VP0 = interp_columns(t0, t_k, VP)
        j = int(t_k.searchsorted(t0, side="right")) - 1     # the IMU sample at or before t0
        # the fit of the VIO positions less the integral. The integral less a constant and a line in time
        # (zero with its rate at t0) moves only the fit's constant and slope: the fit takes the integral as
        # summed, and its constant and slope are moved after it (the same to rounding, on 3 rows, not ~200)
        tt = ts[lo:] - t0
        D_i = interp_columns_inside(ts[lo:], t_k, VP[:, 3:6])   # t_k[0] <= ts[lo], ts[-1] = t0 < t_k[-1]
        coef = _polyfit(tt, self._vio.v[lo:, 4:7] - D_i, c.accel_fit_degree)
        coef[0] += VP0[3:6]
        coef[1] += VP0[0:3]
        beta = 2 * coef[2] if c.accel_fit_degree >= 2 else np.zeros(3)
        # from t0 on: the integral at t0 (zero) and at the samples after it
        s_k = t_k[j:] - t0
        s_k[0] = 0.0
        VP_f = VP[j:] - VP0
        VP_f[0] = 0.0
        P_f, V_f = VP_f[:, 3:6], VP_f[:, 0:3]
        P_f -= VP0[0:3] * s_k[:, None]
        recent = int(t_k.searchsorted(t_k[-1] - c.accel_recent_s, side="left"))
        a_now = np.add.reduce(a_k[recent:], axis=0) / (len(a_k) - recent) + beta   # .mean(axis=0)'s sum and division
        out = AccelMotion(t0, coef[0], coef[1], beta, s_k, P_f, V_f, a_now, c.accel_carry_time_s)
        self._accel_cache = (key, out)
        return out

    def _specific_force_world(self, ts: np.ndarray, t_k: np.ndarray, imu_k: np.ndarray, t0: float) -> np.ndarray:
        """The specific force of the IMU samples ``imu_k`` (rows: gyro, specific force) at stamps ``t_k`` turned
        into display_vio: up to the newest VIO sample ``t0`` by the VIO orientation, normalised-linearly
        interpolated; past it by the newest VIO orientation turned on by the gyro. A sample's value up to t0 is
        final once the two VIO samples around it are in (they are kept in order and never change): those rows
        are kept from one tick to the next and each tick turns only the samples new since (turning the window's
        ~200 every tick was a fifth of T8)."""
        f_k = imu_k[:, 3:6]
        kt, kf = self._turned
        drop = int(kt.searchsorted(t_k[0], side="left"))       # kept rows older than the window
        kt, kf = kt[drop:], kf[drop:]
        upto = int(t_k.searchsorted(t0, side="right"))          # the samples at or before t0
        a = int(t_k.searchsorted(kt[0], side="left")) if len(kt) else 0
        n_kept = len(kt)
        if not (n_kept and a + n_kept <= upto and t_k[a] == kt[0] and t_k[a + n_kept - 1] == kt[-1]):
            a = n_kept = 0
        f_world = np.empty((len(t_k), 3))
        f_world[a:a + n_kept] = kf
        q = self._vio.v[:, 0:4]
        for lo, hi in ((0, a), (a + n_kept, upto)):
            if hi > lo:
                f_world[lo:hi] = _turned_by_vio(ts, q, t_k[lo:hi], f_k[lo:hi])
        first = int(t_k.searchsorted(ts[0], side="left"))       # rows before the oldest VIO sample can change
        self._turned = (t_k[first:upto].copy(), f_world[first:upto])
        if upto < len(t_k):
            steps = _steps(t0, t_k[upto:])
            rotvec = np.cumsum(imu_k[upto:, 0:3] * steps[:, None], axis=0)   # small angles over the <= ~0.05 s past t0
            f_after = f_k[upto:]
            turned = f_after + _cross(rotvec, f_after)
            f_world[upto:] = turned @ np.array(quat_matrix(quat_normalised(q[-1]))).T
        return f_world

    def _velocity_around(self, t_stamp: float) -> np.ndarray:
        """The VIO velocity at stamp time ``t_stamp`` for the time offset's Jacobian: the slope of a line fit
        through the samples within ``offset_velocity_window_s`` centred on it. Centred, the slope gives
        the two samples the pair interpolates (almost) no weight; the slope at the newest sample, which
        the prediction uses, shares their noise with the residual and biased ``d`` by +10 ms (1.5 mm
        VIO jitter, a simulated session without any offset; docs/pipeline.md)."""
        ts = self._vio.t
        half = self.cfg.offset_velocity_window_s / 2
        lo = int(ts.searchsorted(t_stamp - half, side="left"))
        hi = int(ts.searchsorted(t_stamp + half, side="right"))
        if hi - lo < 3:
            return self._velocity(t_stamp)[0]
        # the least-squares line's slope, sum (t - mean t) p / sum (t - mean t)^2: four array calls where
        # _polyfit's normal equations take seven (once per sighting; the same slope to rounding)
        tt = ts[lo:hi] - t_stamp
        d = tt - np.add.reduce(tt) / len(tt)
        return (d @ self._vio.v[lo:hi, 4:7]) / (d @ d)

    def _vio_predicted(self, t_stamp: float) -> RawPose | None:
        """Anchor-mapped VIO moved from its newest sample to stamp time ``t_stamp``: position at
        the fitted velocity, orientation by the gyroscope (the samples received after the VIO
        sample, then their recent mean rate)."""
        if not len(self._vio):
            return None
        t_last = self._vio.last_t
        dt = min(max(t_stamp - t_last, 0.0), self.cfg.max_prediction_s)
        motion = self._accel_motion()
        if motion is not None:
            position = motion.at(t_last + dt)[0]
        else:
            velocity, p_fit, _ = self._velocity()
            position = p_fit + velocity * dt
        return self._predicted_rotation(t_stamp), position

    def _predicted_rotation(self, t_stamp: float) -> Quat:
        """_vio_predicted's orientation alone (the pull of a sighting needs no position)."""
        t_last = self._vio.last_t
        q = tuple(self._vio.v[-1, 0:4].tolist())
        dt = min(max(t_stamp - t_last, 0.0), self.cfg.max_prediction_s)
        if dt <= 0 or not len(self._imu) or not self.cfg.use_gyro:
            return q
        tg, gyro = self._imu.t, self._imu.v[:, 0:3]
        # The body-frame increments are summed into one rotation vector: over <= 0.5 s of hand
        # motion the terms this drops (half the cross products of the increments) are < 0.01 deg.
        a, b = int(tg.searchsorted(t_last, side="right")), int(tg.searchsorted(t_last + dt, side="right"))
        rotvec = _steps(t_last, tg[a:b]) @ gyro[a:b]    # sum of rate x step (one product: 3 array calls less)
        t_prev = tg[b - 1] if b > a else t_last
        held = t_last + dt - t_prev              # past the newest gyro sample: the mean rate, decaying with tau
        held = markov_carry_s(held, self._rate_correlation.tau)
        return quat_mul(q, quat_from_rotvec([r + h * held for r, h in zip(rotvec.tolist(), self._held_rate,
                                                                           strict=True)]))

    def _new_gyro(self) -> None:
        """The gyro's recent mean rate, and its correlation time, once per new newest gyro sample (_ingest)."""
        tg, gyro = self._imu.t, self._imu.v[:, 0:3]
        recent = int(tg.searchsorted(tg[-1] - self.cfg.gyro_window_s, side="left"))
        mean_rate = np.add.reduce(gyro[recent:], axis=0) / (len(gyro) - recent)
        self._held_rate = mean_rate.tolist()
        if self.cfg.gyro_rate_adapt_s > 0:
            self._rate_correlation.update(float(tg[-1]), mean_rate)

    # ------------------------------------------------------------------ measurements
    def _rotation_scale(self, ambiguity: float) -> float:
        """The factor on a sighting's orientation noise for its IPPE ambiguity ratio (rotation_ambiguity_ref)."""
        ref = self.cfg.rotation_ambiguity_ref
        return math.sqrt(ref / max(ambiguity, 1.0)) if ref > 0 and ambiguity > 0 else 1.0

    def _measurement_noise(self, marker_position: np.ndarray, camera_position: np.ndarray | None,
                           rotation_scale: float = 1.0) -> np.ndarray:
        c = self.cfg
        rot = (math.radians(c.marker_rotation_deg) * rotation_scale) ** 2
        lateral = c.marker_lateral_m ** 2 + c.vio_position_m ** 2
        cov = [[lateral, 0.0, 0.0], [0.0, lateral, 0.0], [0.0, 0.0, lateral]]
        if camera_position is not None:
            u = marker_position - camera_position
            n = math.sqrt(u.dot(u))   # np.linalg.norm(u), its own dot product
            if n > 1e-6:
                # + outer(u, u) (depth^2 - lateral^2) with u the unit line of sight: Python floats, the same
                # products and sums as the arrays' (a 6 x 6 built from arrays cost ~20 µs a sighting)
                k = c.marker_depth_m ** 2 - c.marker_lateral_m ** 2
                u0, u1, u2 = (u / n).tolist()
                cov = [[row[j] + ui * uj * k for j, uj in enumerate((u0, u1, u2))]
                       for row, ui in zip(cov, (u0, u1, u2), strict=True)]
        return np.array([[rot, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0, rot, 0.0, 0.0, 0.0, 0.0],
                         [0.0, 0.0, rot, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, *cov[0]], [0.0, 0.0, 0.0, *cov[1]],
                         [0.0, 0.0, 0.0, *cov[2]]])

    def _ingest(self, obs: Observation) -> None:
        tick = obs.tick
        for capture_ns, pose in obs.controller_vio_samples_dvio:
            raw = _raw(pose)
            if raw is not None:
                self._add_vio(self._s(capture_ns), raw)
        imu = tick.imu
        if imu is not None and len(imu):
            rows = np.asarray(imu, dtype=float)
            finite = np.isfinite(rows)
            if not finite.all():
                rows = rows[finite.all(axis=1)]
            if len(rows):
                stamps_ns = np.rint(rows[:, 0] * 1e9).astype(np.int64)   # as round(): half to even
                self._s(int(stamps_ns[0]))                                # the time origin, if not set yet
                assert self._t0_ns is not None
                stamps = (stamps_ns - self._t0_ns) * _NS
                newest = self._imu.last_t
                self._imu.add_many(stamps, rows[:, 1:7])
                if self._imu.last_t != newest:
                    # once per new sample, not per call of _predicted_rotation: that ran again when pruning
                    # changed the ring without a new sample, and counted one mean twice in tau's sums
                    self._new_gyro()
        if len(self._vio):
            horizon = self._vio.last_t - max(self.cfg.history_s, self.cfg.accel_window_s if self.cfg.accel_prediction else 0.0)
            self._vio.prune(horizon)
            self._imu.prune(horizon)
        m = obs.marker
        frame = tick.new_frame   # a sighting counts once, on the tick that first carries its frame
        raw = _raw(m.T_dvio_controller) if m is not None and m.T_dvio_controller is not None else None
        if raw is not None and frame is not None:
            cam = tick.T_dvio_display.translation if tick.T_dvio_display is not None else None
            self._add_sighting(self._s(frame.t_ns), raw, cam, m.ambiguity_ratio if m is not None else 0.0)

    def _add_sighting(self, t_img: float, marker: RawPose, camera_position: np.ndarray | None,
                      ambiguity: float = 0.0) -> None:
        rotation_scale = self._rotation_scale(ambiguity)
        self._pending.append((t_img, marker, self._measurement_noise(marker[1], camera_position, rotation_scale)))
        self._last_marker = (t_img, marker, rotation_scale)
        self._sightings.append((t_img, marker[1]))
        while self._sightings and self._sightings[0][0] < t_img - self.cfg.marker_velocity_window_s:
            self._sightings.popleft()

    def _update_filter(self) -> None:
        """Pair every pending sighting whose image time the VIO stamps now cover, oldest first."""
        f = self.filter
        while self._pending and len(self._vio):
            t_img, M, R_meas = self._pending[0]
            t_stamp = t_img - f.d
            if t_stamp + self.cfg.offset_velocity_window_s / 2 > self._vio.last_t:
                break   # the VIO of that moment (and half the velocity window after it) has not arrived yet: wait
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
            v = self._velocity_around(t_stamp)
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
        i = int(ts.searchsorted(t_stamp))
        i = min(max(i, 1), len(ts) - 1)
        dt = ts[i] - ts[i - 1]
        if dt <= 0:
            return np.zeros(3)
        before, after = self._vio.v[i - 1:i + 1, 0:4].tolist()
        return np.array([r / dt for r in quat_as_rotvec(quat_mul(after, quat_inv(before)))])

    # ------------------------------------------------------------------ output
    def step(self, obs: Observation) -> Pose | None:
        t = self._s(obs.tick.t_ns)
        f = self.filter
        self._ingest(obs)
        self._update_filter()
        vio_now = self._vio_predicted(t - f.d)
        if vio_now is None and obs.T_dvio_controller_vio is not None:
            vio_now = _raw(obs.T_dvio_controller_vio)      # no stamped samples: the received pose
        corrected = f.apply(vio_now) if (vio_now is not None and f.ready) else vio_now
        motion = self._accel_motion()
        if motion is not None:   # the velocity at the tick, carried by the accelerometer
            h = min(max(t - f.d - self._vio.last_t, 0.0), self.cfg.max_prediction_s)
            v_vio = motion.at(self._vio.last_t + h)[1]
        else:
            v_vio = self._velocity()[0]
        velocity = f._Rm @ v_vio if f.ready else v_vio

        # the marker source: the newest sighting (at its image time, as T4-T7 report it)
        marker_now = None
        if self._last_marker is not None:
            t_img, M, _ = self._last_marker
            age = t - t_img
            if 0 <= age <= self.cfg.max_prediction_s:
                marker_now = M[1] + velocity * age if self.cfg.marker_to_tick else M[1]
        source = "marker" if obs.in_view and marker_now is not None else ("vio" if corrected is not None else None)
        if source is None:
            if obs.marker is not None and is_finite(obs.marker.T_dvio_controller):   # in view
                return obs.marker.T_dvio_controller
            return None
        position = self._position(source, corrected, marker_now, velocity, t)
        if corrected is not None:
            rotation = corrected[0]
        else:
            assert self._last_marker is not None   # the source is the marker: marker_now is its sighting
            rotation = self._last_marker[1][0]
        if source == "marker" and corrected is not None:
            rotation = self._pulled_by_sighting(rotation)
        self._carry_offset(source, corrected, position, velocity, t)
        self._source = source
        self._last_t = t
        out = position + self._offset
        if not all(map(math.isfinite, (*out.tolist(), *rotation))):
            return None
        self._last_out = out
        return Pose._of(quat_normalised(rotation), out)   # normalised as Rotation.from_quat does, bit for bit

    def _position(self, source: str, corrected: RawPose | None, marker_now: np.ndarray | None, velocity: np.ndarray,
                  t: float) -> np.ndarray:
        position = corrected[1] if source == "vio" and corrected is not None else marker_now
        assert position is not None   # each source is chosen only with its pose
        if source == "marker" and self.cfg.marker_gain < 1:
            # inside: a complementary filter — the newest sightings, moved by the VIO velocity, average the marker's noise
            if self._source == "marker" and self._inside is not None and self._last_t is not None:
                predicted = self._inside + velocity * (t - self._last_t)
                position = self.cfg.marker_gain * position + (1 - self.cfg.marker_gain) * predicted
            self._inside = position
        else:
            self._inside = None
        return position

    def _carry_offset(self, source: str, corrected: RawPose | None, position: np.ndarray, velocity: np.ndarray,
                      t: float) -> None:
        """Continuity: carry the difference across a switch, then let it decay."""
        if self._last_t is not None:
            self._offset = self._offset * math.exp(-max(t - self._last_t, 0.0) / self.cfg.blend_time_s)
        if self._source is not None and source != self._source and self._last_out is not None \
                and corrected is not None and self._had_corrected:
            # a switch: this tick's output = the last output moved by the estimated motion over the
            # tick, and the difference to the new source is carried and decays
            motion = velocity
            tau = self.cfg.entry_acceleration_time_s
            if self._source == "vio" and tau > 0 and self.filter.ready:
                # entering the view: the velocity moved from the newest VIO sample to the tick by the fit's
                # acceleration (with the accelerometer: the integral to the newest IMU sample, then the newest
                # acceleration), decaying with tau (FusionConfig.entry_acceleration_time_s)
                h = min(max(t - self.filter.d - self._vio.last_t, 0.0), self.cfg.max_prediction_s)
                accel_motion = self._accel_motion()
                if accel_motion is not None:
                    motion = self.filter._Rm @ accel_motion.at(self._vio.last_t + h, tau)[1]
                else:
                    motion = velocity + (self.filter._Rm @ self._accel) * markov_carry_s(h, tau)
            if self._source == "marker":
                # leaving the view: the marker's own velocity is fresher than the VIO's (~0.15 s old)
                marker_velocity = self._marker_velocity(t)
                if marker_velocity is not None:
                    motion = marker_velocity
            assert self._last_t is not None   # set with _last_out
            target = self._last_out + motion * (t - self._last_t)
            self._offset = target - position
        self._had_corrected = corrected is not None

    def _pulled_by_sighting(self, rotation: Quat) -> Quat:
        """Inside the view: the predicted orientation corrected by the newest sighting.

        The sighting is compared with the corrected VIO at its own image time (against the tick's,
        the pull would drag the output back by the image's age), and a Kalman share of the
        difference corrects the prediction: large when the VIO at the image time is itself a
        prediction (the controller's streams arrive ~0.15 s late), small when it has data there.
        """
        c, f = self.cfg, self.filter
        assert self._last_marker is not None   # called with the marker as the source
        t_img, M, rotation_scale = self._last_marker
        at_img = self._vio_at(t_img - f.d)
        if at_img is not None:
            q_vio = at_img[0]
        elif len(self._vio):                # the image is newer than the newest VIO sample (usual)
            q_vio = self._predicted_rotation(t_img - f.d)
        else:
            return rotation
        q_at = quat_mul(f.q, q_vio) if f.q is not None else q_vio     # f.apply's orientation (f.ready: q is set)
        px, py, pz = quat_as_rotvec(quat_mul(M[0], quat_inv(q_at)))
        if math.sqrt(px * px + py * py + pz * pz) > math.radians(3 * c.marker_rotation_deg):   # a flip does not pull
            return rotation
        t_data = max(self._vio.last_t, self._imu.last_t if len(self._imu) else -math.inf)   # where measurements end
        h = max(0.0, (t_img - f.d) - t_data)
        P = c.pull_vio_rotation_deg ** 2 + (c.pull_prediction_deg_per_s * h) ** 2
        gain = P / (P + (c.pull_marker_rotation_deg * rotation_scale) ** 2)
        return quat_mul(quat_from_rotvec((gain * px, gain * py, gain * pz)), rotation)

    def __repr__(self) -> str:
        return f"{self.name}(fused: ESKF correction + time offset, gyro prediction, continuous output)"
