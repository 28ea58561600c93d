"""T8 (ours): the controller pose fused from IMU, anchor-mapped VIO and the marker
(docs/pipeline.md#t8-the-fused-tracker-ours).

An error-state Kalman filter (:mod:`.filter`) estimates the correction C (display_vio ← anchor-mapped
controller VIO) and the VIO stream's time offset d from every gated sighting, each paired with the VIO
interpolated at the image's capture time. At every tick the VIO is predicted from its newest sample to
the tick (:mod:`.motion`: position with the accelerometer, orientation with the gyro) and corrected by C.
Inside the view the output is the newest sighting moved to the tick, its orientation the prediction
pulled towards the sighting; outside, the corrected prediction. At a switch of source the difference is
carried as a decaying offset, so the output does not step. Causal: a step sees only what this and earlier
ticks carried.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from phonepose.geometry import (
    Pose,
    Quat,
    is_finite,
    quat_as_rotvec,
    quat_from_rotvec,
    quat_inv,
    quat_matrix,
    quat_mul,
    quat_normalised,
)
from phonepose.pipeline.t8.config import FusionConfig
from phonepose.pipeline.t8.filter import CorrectionFilter, measurement_noise
from phonepose.pipeline.t8.inputs import ObservationInput as Observation
from phonepose.pipeline.t8.motion import (
    GRAVITY,
    AccelMotion,
    RateCorrelation,
    RawPose,
    Ring,
    cross_rows,
    fit_accel_motion,
    interpolate_raw,
    markov_carry_s,
    polyfit,
    raw_pose,
    steps,
    turned_by_vio,
)

_NS = 1e-9


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
        self._vio = Ring(7)                       # (stamp s) -> qx qy qz qw x y z in display_vio (anchor-mapped)
        self._imu = Ring(6)                       # (stamp s) -> gyro rad/s, specific force m/s^2 (body frame)
        self._accel_cache: tuple[tuple, AccelMotion | None] | None = None
        self._held_rate = [0.0, 0.0, 0.0]         # the gyro's mean rate over its newest gyro_window_s
        self._rate_correlation = RateCorrelation(self.cfg.gyro_window_s, self.cfg.gyro_rate_adapt_s,
                                                  self.cfg.gyro_rate_adapt_min_s, self.cfg.gyro_rate_time_s)
        self._turned = (np.empty(0), np.empty((0, 3)))  # IMU stamps and their final specific force in display_vio
        self._pending: deque = deque()             # (image s, marker RawPose, R_meas)
        self._last_filter_t: float | None = None
        self._path_since_predict = 0.0
        self._velocity_cache: tuple[tuple, tuple[np.ndarray, np.ndarray, float | None]] | None = None
        self._offset = np.zeros(3)                 # carried across source switches, decays
        self._source: str | None = None
        self._last_out: np.ndarray | None = None   # the last output's position
        self._last_t: float | None = None
        self._last_marker: tuple[float, RawPose, float] | None = None   # newest sighting: image s, pose, noise factor
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
        if len(self._vio) and t > self._vio.last_t:   # the ring keeps only newer samples
            px, py, pz = self._vio.v[-1, 4:7].tolist()
            dx, dy, dz = x - px, y - py, z - pz    # products, not ** 2: a float power raises on overflow
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
        return interpolate_raw(float(ts[i - 1]), v[i - 1].tolist(), float(ts[i]), v[i].tolist(), t)

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
            # a quadratic's slope at the newest sample does not lag behind an acceleration as a line's does
            degree = self.cfg.velocity_fit_degree if hi - lo > self.cfg.velocity_fit_degree + 1 else 1
            c = polyfit(tt, pp, degree)
            out = (c[1], c[0], float(ts[hi - 1]))
            if t_end is None:   # the fit up to the newest sample: its acceleration, for the entry into the view
                self._accel = 2 * c[2] if degree == 2 else np.zeros(3)
        self._velocity_cache = (key, out)
        return out

    def _accel_motion(self) -> AccelMotion | None:
        """The accelerometer-aided motion from the newest VIO sample (FusionConfig.accel_*), or None (off, or
        too few VIO or IMU samples, or none past the newest VIO sample)."""
        c = self.cfg
        if not c.accel_prediction or len(self._vio) < c.accel_fit_degree + 2 or len(self._imu) < 2:
            return None
        ts, tk = self._vio.t, self._imu.t
        t0 = float(ts[-1])
        key = (len(ts), t0, ts[0], len(tk), self._imu.last_t, self.filter.ready)
        if self._accel_cache is not None and self._accel_cache[0] == key:
            return self._accel_cache[1]
        self._accel_cache = (key, None)
        if tk[-1] <= t0:
            return None
        lo = int(ts.searchsorted(t0 - c.accel_window_s, side="left"))
        k_lo = max(int(tk.searchsorted(ts[lo], side="right")) - 1, 0)   # the IMU sample at or before ts[lo]
        lo = int(ts.searchsorted(tk[k_lo], side="left"))                 # VIO samples the integral covers
        if len(ts) - lo < c.accel_fit_degree + 2 or len(tk) - k_lo < 2:
            return None
        t_k = tk[k_lo:]
        f_world = self._specific_force_world(ts, t_k, self._imu.v[k_lo:], t0)
        R = self.filter.rotation_matrix
        g = GRAVITY[2] * R[2] if self.filter.ready else GRAVITY   # R.T @ GRAVITY (its x, y are 0)
        out = fit_accel_motion(c, ts[lo:], self._vio.v[lo:, 4:7], t_k, f_world + g)
        self._accel_cache = (key, out)
        return out

    def _specific_force_world(self, ts: np.ndarray, t_k: np.ndarray, imu_k: np.ndarray, t0: float) -> np.ndarray:
        """The specific force of the IMU samples ``imu_k`` (rows: gyro, specific force) at stamps ``t_k`` turned
        into display_vio: up to the newest VIO sample ``t0`` by the interpolated VIO orientation, past it by the
        newest VIO orientation turned on by the gyro. Rows up to t0 are final once the two VIO samples around
        them are in, so they are kept between ticks and each tick turns only the new ones."""
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
                f_world[lo:hi] = turned_by_vio(ts, q, t_k[lo:hi], f_k[lo:hi])
        first = int(t_k.searchsorted(ts[0], side="left"))       # rows before the oldest VIO sample can change
        self._turned = (t_k[first:upto].copy(), f_world[first:upto])
        if upto < len(t_k):
            rotvec = np.cumsum(imu_k[upto:, 0:3] * steps(t0, t_k[upto:])[:, None], axis=0)   # small angles
            f_after = f_k[upto:]
            turned = f_after + cross_rows(rotvec, f_after)
            f_world[upto:] = turned @ np.array(quat_matrix(quat_normalised(q[-1]))).T
        return f_world

    def _velocity_around(self, t_stamp: float) -> np.ndarray:
        """The VIO velocity at stamp time ``t_stamp`` for the time offset's Jacobian: the slope of a line fit
        through the samples within ``offset_velocity_window_s`` centred on it, which gives the two samples the
        pair interpolates (almost) no weight, so the velocity does not share the pair's noise."""
        ts = self._vio.t
        half = self.cfg.offset_velocity_window_s / 2
        lo = int(ts.searchsorted(t_stamp - half, side="left"))
        hi = int(ts.searchsorted(t_stamp + half, side="right"))
        if hi - lo < 3:
            return self._velocity(t_stamp)[0]
        tt = ts[lo:hi] - t_stamp          # the least-squares slope, sum (t - mean t) p / sum (t - mean t)^2
        d = tt - np.add.reduce(tt) / len(tt)
        return (d @ self._vio.v[lo:hi, 4:7]) / (d @ d)

    def _vio_predicted(self, t_stamp: float) -> RawPose | None:
        """Anchor-mapped VIO moved from its newest sample to stamp time ``t_stamp``: the position by the
        accelerometer-aided motion (or the fitted velocity), the orientation by the gyroscope."""
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
        """The newest VIO orientation turned by the gyro samples after it, then by their recent mean rate
        decaying with its correlation time."""
        t_last = self._vio.last_t
        q = tuple(self._vio.v[-1, 0:4].tolist())
        dt = min(max(t_stamp - t_last, 0.0), self.cfg.max_prediction_s)
        if dt <= 0 or not len(self._imu) or not self.cfg.use_gyro:
            return q
        tg, gyro = self._imu.t, self._imu.v[:, 0:3]
        # the body-frame increments summed into one rotation vector: over <= 0.5 s of hand motion the
        # dropped terms (half the increments' cross products) are < 0.01 deg
        a, b = int(tg.searchsorted(t_last, side="right")), int(tg.searchsorted(t_last + dt, side="right"))
        rotvec = steps(t_last, tg[a:b]) @ gyro[a:b]
        t_prev = tg[b - 1] if b > a else t_last
        held = markov_carry_s(t_last + dt - t_prev, self._rate_correlation.tau)
        return quat_mul(q, quat_from_rotvec([r + h * held for r, h in zip(rotvec.tolist(), self._held_rate,
                                                                           strict=True)]))

    def _new_gyro(self) -> None:
        """The gyro's recent mean rate, and its correlation time, once per new newest gyro sample."""
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
        return measurement_noise(self.cfg, marker_position, camera_position, rotation_scale)

    def _ingest(self, obs: Observation) -> None:
        tick = obs.tick
        for capture_ns, pose in obs.controller_vio_samples_dvio:
            raw = raw_pose(pose)
            if raw is not None:
                self._add_vio(self._s(capture_ns), raw)
        if tick.imu is not None and len(tick.imu):
            self._ingest_imu(tick.imu)
        if len(self._vio):
            kept = max(self.cfg.history_s, self.cfg.accel_window_s if self.cfg.accel_prediction else 0.0)
            horizon = self._vio.last_t - kept
            self._vio.prune(horizon)
            self._imu.prune(horizon)
        m = obs.marker
        frame = tick.new_frame   # a sighting counts once, on the tick that first carries its frame
        raw = raw_pose(m.T_dvio_controller) if m is not None and m.T_dvio_controller is not None else None
        if raw is not None and frame is not None:
            cam = tick.T_dvio_display.translation if tick.T_dvio_display is not None else None
            self._add_sighting(self._s(frame.t_ns), raw, cam, m.ambiguity_ratio if m is not None else 0.0)

    def _ingest_imu(self, imu) -> None:
        """A tick's IMU rows (stamp s, gyro, specific force); rows with a non-finite value are dropped."""
        rows = np.asarray(imu, dtype=float)
        finite = np.isfinite(rows)
        if not finite.all():
            rows = rows[finite.all(axis=1)]
        if not len(rows):
            return
        stamps_ns = np.rint(rows[:, 0] * 1e9).astype(np.int64)   # as round(): half to even
        self._s(int(stamps_ns[0]))                                # the time origin, if not set yet
        assert self._t0_ns is not None
        stamps = (stamps_ns - self._t0_ns) * _NS
        newest = self._imu.last_t
        self._imu.add_many(stamps, rows[:, 1:7])
        if self._imu.last_t != newest:   # once per new sample, so no mean rate counts twice
            self._new_gyro()

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
                break   # the VIO of that moment (and half the velocity window after it) has not arrived yet
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
        return polyfit(tt - tt[-1], np.array([p for _, p in s]), 1)[1]

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
            vio_now = raw_pose(obs.T_dvio_controller_vio)      # no stamped samples: the received pose
        corrected = f.apply(vio_now) if (vio_now is not None and f.ready) else vio_now
        velocity = self._velocity_at_tick(t)
        marker_now = self._marker_at_tick(t, velocity)
        source = "marker" if obs.in_view and marker_now is not None else ("vio" if corrected is not None else None)
        if source is None:
            if obs.marker is not None and is_finite(obs.marker.T_dvio_controller):   # in view
                return obs.marker.T_dvio_controller
            return None
        position = self._position(source, corrected, marker_now, velocity, t)
        rotation = self._rotation(source, corrected)
        self._carry_offset(source, corrected, position, velocity, t)
        self._source = source
        self._last_t = t
        out = position + self._offset
        if not all(map(math.isfinite, (*out.tolist(), *rotation))):
            return None
        self._last_out = out
        return Pose.from_raw((*rotation, *out.tolist()))   # normalised as Rotation.from_quat does

    def _velocity_at_tick(self, t: float) -> np.ndarray:
        """The corrected VIO velocity at the tick (carried by the accelerometer where it can be)."""
        f = self.filter
        motion = self._accel_motion()
        if motion is not None:
            h = min(max(t - f.d - self._vio.last_t, 0.0), self.cfg.max_prediction_s)
            v_vio = motion.at(self._vio.last_t + h)[1]
        else:
            v_vio = self._velocity()[0]
        return f.rotation_matrix @ v_vio if f.ready else v_vio

    def _marker_at_tick(self, t: float, velocity: np.ndarray) -> np.ndarray | None:
        """The newest sighting's position, moved from its image time to the tick (marker_to_tick)."""
        if self._last_marker is None:
            return None
        t_img, M, _ = self._last_marker
        age = t - t_img
        if not 0 <= age <= self.cfg.max_prediction_s:
            return None
        return M[1] + velocity * age if self.cfg.marker_to_tick else M[1]

    def _rotation(self, source: str, corrected: RawPose | None) -> Quat:
        if corrected is None:
            assert self._last_marker is not None   # the source is the marker: there is a sighting
            return self._last_marker[1][0]
        if source == "marker":
            return self._pulled_by_sighting(corrected[0])
        return corrected[0]

    def _position(self, source: str, corrected: RawPose | None, marker_now: np.ndarray | None, velocity: np.ndarray,
                  t: float) -> np.ndarray:
        position = corrected[1] if source == "vio" and corrected is not None else marker_now
        assert position is not None   # each source is chosen only with its pose
        if source == "marker" and self.cfg.marker_gain < 1:
            # a complementary filter: the newest sightings, moved by the VIO velocity, average the marker's noise
            if self._source == "marker" and self._inside is not None and self._last_t is not None:
                predicted = self._inside + velocity * (t - self._last_t)
                position = self.cfg.marker_gain * position + (1 - self.cfg.marker_gain) * predicted
            self._inside = position
        else:
            self._inside = None
        return position

    def _carry_offset(self, source: str, corrected: RawPose | None, position: np.ndarray, velocity: np.ndarray,
                      t: float) -> None:
        """Continuity: at a switch of source, carry the difference to the new source, then let it decay."""
        if self._last_t is not None:
            self._offset = self._offset * math.exp(-max(t - self._last_t, 0.0) / self.cfg.blend_time_s)
        if self._source is not None and source != self._source and self._last_out is not None \
                and corrected is not None and self._had_corrected:
            assert self._last_t is not None   # set with _last_out
            target = self._last_out + self._switch_motion(velocity, t) * (t - self._last_t)
            self._offset = target - position
        self._had_corrected = corrected is not None

    def _switch_motion(self, velocity: np.ndarray, t: float) -> np.ndarray:
        """The estimated velocity over a tick that switches source (docs/pipeline.md#entering-and-leaving-the-view)."""
        tau = self.cfg.entry_acceleration_time_s
        f = self.filter
        if self._source == "vio" and tau > 0 and f.ready:
            # entering the view: the velocity carried from the newest VIO sample to the tick by the
            # acceleration, decaying with tau
            h = min(max(t - f.d - self._vio.last_t, 0.0), self.cfg.max_prediction_s)
            accel_motion = self._accel_motion()
            if accel_motion is not None:
                return f.rotation_matrix @ accel_motion.at(self._vio.last_t + h, tau)[1]
            return velocity + (f.rotation_matrix @ self._accel) * markov_carry_s(h, tau)
        if self._source == "marker":
            # leaving the view: the marker's own velocity is fresher than the VIO's
            marker_velocity = self._marker_velocity(t)
            if marker_velocity is not None:
                return marker_velocity
        return velocity

    def _pulled_by_sighting(self, rotation: Quat) -> Quat:
        """Inside the view: the predicted orientation corrected by the newest sighting.

        The sighting is compared with the corrected VIO at its own image time, and a Kalman share of the
        difference corrects the prediction: large when the VIO at the image time is itself a prediction,
        small when it has data there (docs/pipeline.md#the-output).
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
        q_at = quat_mul(f.q, q_vio) if f.q is not None else q_vio     # f.apply's orientation
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
