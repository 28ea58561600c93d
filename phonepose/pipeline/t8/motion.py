"""T8's motion models: sample rings, VIO interpolation, polynomial fits, the accelerometer-aided motion
and the gyro rate's correlation time (docs/pipeline.md#predicting-the-vio-to-the-tick)."""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from phonepose.geometry import (
    Pose,
    Quat,
    quat_apply_rows,
    quat_as_rotvec,
    quat_from_rotvec,
    quat_inv,
    quat_mul,
)
from phonepose.pipeline.t8.config import FusionConfig
from phonepose.series import interp_columns, interp_columns_inside, newer_than_before

# A single pose as (unit quaternion xyzw, translation): T8's per-tick math works on these with
# phonepose.geometry's closed forms, as scipy's Rotation costs tens of microseconds per single rotation.
RawPose = tuple[Quat, np.ndarray]

# display_vio and the controller's VIO world are gravity aligned, z up
GRAVITY = np.array([0.0, 0.0, -9.80665])


def raw_pose(pose: Pose) -> RawPose | None:
    """A single Pose as (quaternion, translation), or None if anything in it is not finite."""
    raw = pose.as_raw()
    if not all(map(math.isfinite, raw)):
        return None
    return raw[:4], np.asarray(pose.translation, dtype=float)


def solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x = b`` for a square ``a`` and a matrix ``b`` (LAPACK gesv, as np.linalg.solve)."""
    return np.linalg.solve(a, b)


def polyfit(t: np.ndarray, values: np.ndarray, degree: int) -> np.ndarray:
    """Least-squares polynomial coefficients (constant first) of ``values`` over ``t``, one column per
    axis, from the normal equations (cheaper than np.polynomial.polyfit on a few samples)."""
    A = np.empty((len(t), degree + 1))
    A[:, 0] = 1.0
    for k in range(1, degree + 1):
        A[:, k] = A[:, k - 1] * t     # t ** k as products, so the columns are exact for k <= 2
    return solve(A.T @ A, A.T @ values)


def markov_carry_s(h, tau: float):
    """How long a first-order Markov (Singer) quantity with correlation time ``tau`` acts over ``h`` s when its
    value at the start is carried on: tau (1 - e^(-h / tau)); ``h`` for tau = inf, 0 for tau = 0. A float
    ``h`` gives a float, an array an array."""
    if isinstance(h, float):
        return h if math.isinf(tau) else (tau * -math.expm1(-h / tau) if tau > 0 else 0.0)
    if math.isinf(tau):
        return h
    return 0.0 * h if tau <= 0 else tau * -np.expm1(-np.asarray(h) / tau)


_YZX, _ZXY = np.array([1, 2, 0]), np.array([2, 0, 1])   # index arrays, built once


def cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of rows (n, 3): the same products and differences, without its argument handling."""
    return a[:, _YZX] * b[:, _ZXY] - a[:, _ZXY] * b[:, _YZX]


def steps(t_before: float, t: np.ndarray) -> np.ndarray:
    """``np.diff(t, prepend=t_before)``: the same differences, without the concatenation."""
    out = np.empty(len(t))
    if len(t):
        out[0] = t[0] - t_before
        np.subtract(t[1:], t[:-1], out=out[1:])
    return out


def turned_by_vio(ts: np.ndarray, q: np.ndarray, t: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Vectors ``f`` (n, 3) at stamps ``t`` within the VIO samples' (``ts``, quaternions ``q``) turned by the
    VIO orientation there, normalised-linearly interpolated (the short way round)."""
    # t <= ts[-1] and the stamps rise strictly (Ring): the index needs no upper bound and the weight
    # none above 1; before ts[0] it is 0 (the oldest sample)
    i = np.maximum(ts.searchsorted(t), 1)
    w = np.maximum((t - ts[i - 1]) / (ts[i] - ts[i - 1]), 0.0)[:, None]
    q0, q1 = q[i - 1], q[i]
    q1 = q1 * np.copysign(1.0, np.add.reduce(q0 * q1, axis=1, keepdims=True))   # the short way round
    return quat_apply_rows((1 - w) * q0 + w * q1, f)


def interpolate_raw(t0: float, s0: list, t1: float, s1: list, t: float) -> RawPose:
    """As geometry.interpolate on raw rows (qx, qy, qz, qw, x, y, z): linear translation, slerp."""
    a = (t - t0) / (t1 - t0)
    q0, q1 = tuple(s0[:4]), tuple(s1[:4])
    r = quat_as_rotvec(quat_mul(quat_inv(q0), q1))
    q = quat_mul(q0, quat_from_rotvec((a * r[0], a * r[1], a * r[2])))
    b = 1.0 - a   # the translation from floats, one array at the end
    return q, np.array([b * s0[4] + a * s1[4], b * s0[5] + a * s1[5], b * s0[6] + a * s1[6]])


class AccelMotion:
    """The VIO position's motion from its newest sample ``t0`` on, with the accelerometer (FusionConfig.accel_*).

    ``p0, v0, beta``: the fit of the VIO positions less the double integral ``D`` of the measured
    acceleration (zero with its rate at ``t0``): p0 + v0 s + beta s^2 / 2 + D(s), s = t - t0 (beta: what the
    integral misses over the window, the accelerometer's bias turned into the world). ``s_k``, ``P_k``, ``V_k``:
    the integral's position and velocity at the IMU samples from t0 on (``s_k[0] = 0``); ``a``: the newest
    acceleration, carried past the newest IMU sample decaying with correlation time ``tau``."""

    def __init__(self, t0: float, p0: np.ndarray, v0: np.ndarray, beta: np.ndarray, s_k: np.ndarray,
                 P_k: np.ndarray, V_k: np.ndarray, a: np.ndarray, tau: float):
        self.t0, self.p0, self.v0, self.beta = t0, p0, v0, beta
        self.s_k, self.P_k, self.V_k = s_k, P_k, V_k
        self.a, self.tau = a, tau
        self._last: tuple[tuple, tuple[np.ndarray, np.ndarray]] | None = None   # (t, tau) -> the last result

    def at(self, t: float, tau: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(position, velocity) at stamp time ``t`` >= t0, the acceleration past the newest IMU sample decaying
        with correlation time ``tau`` (None: this motion's own). The last answer is kept: a tick asks for the
        same instant twice, and callers never modify it."""
        if self._last is not None and self._last[0] == (t, tau):
            return self._last[1]
        self._last = ((t, tau), self._at(t, tau))
        return self._last[1]

    def _at(self, t: float, tau: float | None) -> tuple[np.ndarray, np.ndarray]:
        s = max(t - self.t0, 0.0)
        s_imu = float(self.s_k[-1])
        u = min(s, s_imu)
        if u == s_imu:   # the tick is past the newest IMU sample: np.interp's own end value
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


def fit_accel_motion(cfg: FusionConfig, ts: np.ndarray, positions: np.ndarray, t_k: np.ndarray,
                     a_k: np.ndarray) -> AccelMotion:
    """The motion from the newest VIO sample on: the VIO ``positions`` at stamps ``ts`` (the window, newest
    last) less the double integral of the world accelerations ``a_k`` at IMU stamps ``t_k``
    (``t_k[0] <= ts[0]``, ``ts[-1] < t_k[-1]``), fitted with a polynomial of degree ``cfg.accel_fit_degree``."""
    c = cfg
    t0 = float(ts[-1])
    if c.accel_smooth_s > 0:
        # a centred moving average (one-sided at the newest samples) keeps hand tremor out of the velocity
        cum = np.zeros((len(t_k) + 1, 3))
        np.cumsum(a_k, axis=0, out=cum[1:])
        a_lo = t_k.searchsorted(t_k - c.accel_smooth_s / 2, side="left")
        a_hi = t_k.searchsorted(t_k + c.accel_smooth_s / 2, side="right")
        a_k = (cum[a_hi] - cum[a_lo]) / (a_hi - a_lo)[:, None]
    # double integral (trapezoid velocity, exact for a linear acceleration per step), V and P side by
    # side, zero at the window's first sample
    dt = (t_k[1:] - t_k[:-1])[:, None]
    VP = np.zeros((len(t_k), 6))
    np.cumsum((a_k[:-1] + a_k[1:]) / 2 * dt, axis=0, out=VP[1:, 0:3])
    np.cumsum(VP[:-1, 0:3] * dt + (a_k[:-1] / 3 + a_k[1:] / 6) * dt * dt, axis=0, out=VP[1:, 3:6])
    VP0 = interp_columns(t0, t_k, VP)                    # the integral at t0
    j = int(t_k.searchsorted(t0, side="right")) - 1     # the IMU sample at or before t0
    # the fit of the VIO positions less the integral; re-referencing the integral to zero with its rate
    # at t0 moves only the fit's constant and slope, so they are moved after the fit
    D_i = interp_columns_inside(ts, t_k, VP[:, 3:6])
    coef = polyfit(ts - t0, positions - D_i, c.accel_fit_degree)
    coef[0] += VP0[3:6]
    coef[1] += VP0[0:3]
    beta = 2 * coef[2] if c.accel_fit_degree >= 2 else np.zeros(3)
    s_k = t_k[j:] - t0                                   # from t0 on: the integral at t0 (zero) and after it
    s_k[0] = 0.0
    VP_f = VP[j:] - VP0
    VP_f[0] = 0.0
    P_f, V_f = VP_f[:, 3:6], VP_f[:, 0:3]
    P_f -= VP0[0:3] * s_k[:, None]
    recent = int(t_k.searchsorted(t_k[-1] - c.accel_recent_s, side="left"))
    a_now = np.add.reduce(a_k[recent:], axis=0) / (len(a_k) - recent) + beta
    return AccelMotion(t0, coef[0], coef[1], beta, s_k, P_f, V_f, a_now, c.accel_carry_time_s)


class RateCorrelation:
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


class Ring:
    """Recent samples of one controller stream on its own stamps (seconds, strictly ascending), one row of
    ``width`` floats each, in preallocated arrays (``t`` and ``v`` are views, valid until the next ``add``)."""

    def __init__(self, width: int, capacity: int = 256) -> None:
        self._t = np.empty(capacity)
        self._v = np.empty((capacity, width))
        self._lo = self._hi = 0
        self.last_t = -math.inf              # the newest stamp, as a Python float

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
        if not (len(t) and t[0] > self.last_t and (t[1:] > t[:-1]).all()):   # in order: every row kept
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
        (amortised) when the kept rows fill half of them or the new ones would not fit after the slide."""
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
