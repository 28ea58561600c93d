"""The rehearsal's scores: the rehearsed recording against the source simulated session.

- **Streams**: the recorded ``/controller/vio/pose`` against the VIO the phone's emulated device
  played (its pose at each sample's stamp: a wrong axis or sign anywhere gives centimetres or tens of
  degrees, a clock error a lag along the motion, estimated here), the recorded IMU against the
  simulated one, and the ground truth against the true grip pose.
- **calibrate-gt** on the rehearsed session: its clock offset, world->camera and grip->body against
  the scene's :class:`~phonepose.record.rehearse.scene.Truth`.
- **playback** of both sessions (every tracker; the rehearsed one with calibrate-gt's file): p_ATE
  inside the view over the source's task window (sim time), from each playback's own trajectories
  and ground truth, with the metric playback uses (phonepose.evaluation.paper); beside it the
  rehearsed session scored against the true pose directly (no calibration in between).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeGuard

import numpy as np

from phonepose.geometry import Pose
from phonepose.record.rehearse.scene import Scene
from phonepose.record.rehearse.session import RecordedRun
from phonepose.series import interp_columns, newer_than_before

SCORED_TRACKERS = ("T4", "T5", "T6", "T7", "T7L", "T8")
# the goals a rehearsal is held to (docs/recording-real-sessions.md#rehearsal-the-whole-live-path-with-no-hardware)
GOAL_OFFSET_MS = 5.0
GOAL_MM = 5.0
GOAL_DEG = 0.5
GOAL_ATE_CM = 1.0
EXPLAIN_ATE_CM = 0.3
# the pose-timing tolerance: the recorder's clock-offset estimate (its pings; a few ms off on a loaded machine),
# held to calibrate-gt's goal for the clock; with that lag taken out, what is left must be a stamp's
# wobble (the estimate moves as pongs come), never the centimetres or tens of degrees of a wrong sign or axis
LAG_MAX_MS = 5.0
STREAM_MAX_MM = 3.0
STREAM_MAX_DEG = 1.0
GRAVITY_MAX_DEG = 5.0    # the accelerometer's bias (0.1 m/s², 0.6 deg) and sparse sampling; a wrong axis is 50-180 deg
IMU_MAX_GYRO = 0.05      # rad/s RMS, lag out: the simulated noise is 0.002; a wrong sign on one axis is 0.4
IMU_MAX_ACCEL = 0.5      # m/s² RMS: a wrong sign is ~10-20 (gravity)
# the IMU's own lag is sought within this of the VIO's (ms, on a 0.5 ms grid): the page stamps DeviceMotion
# events on its timer and the VIO on its XR frames; on a loaded machine the two lags differ by ms, enough at the
# hand's angular acceleration to put the gyro past IMU_MAX_GYRO with the VIO's lag
IMU_LAG_SEARCH_MS = 100.0


@dataclass
class StreamCheck:
    """A recorded pose stream against what was played, at the recorded stamps."""

    samples: int
    rate_hz: float
    median_mm: float
    max_mm: float
    median_deg: float
    max_deg: float
    lag_ms: float             # the recorded stamps are late by this against the played motion
    after_lag_median_mm: float
    after_lag_max_mm: float
    after_lag_max_deg: float


@dataclass
class CalibrationCheck:
    time_offset_ms: float
    true_time_offset_ms: float
    world_mm: float
    world_deg: float
    body_mm: float
    body_deg: float
    residual_mm: float
    residual_deg: float
    sightings: int
    sigma: dict = field(default_factory=dict)

    @property
    def time_error_ms(self) -> float:
        return abs(self.time_offset_ms - self.true_time_offset_ms)

    @property
    def ok(self) -> bool:
        return (self.time_error_ms <= GOAL_OFFSET_MS and self.world_mm <= GOAL_MM and self.world_deg <= GOAL_DEG
                and self.body_mm <= GOAL_MM and self.body_deg <= GOAL_DEG)


@dataclass
class Scores:
    vio: StreamCheck
    gt: StreamCheck | None
    imu_samples: int
    imu_rate_hz: float
    imu_gyro_rms: float          # rad/s: recorded minus simulated gyro at the recorded stamps
    imu_accel_rms: float         # m/s²
    gravity_deg: float           # recorded accelerometer vs gravity seen through the recorded VIO (2 s means)
    anchors: int                 # /controller/anchor messages recorded
    calibration: CalibrationCheck | None
    ate_source_cm: dict          # tracker -> p_ATE inside (cm), source session
    ate_rehearsed_cm: dict       # tracker -> p_ATE inside (cm), rehearsed session, calibrated GT
    ate_oracle_cm: dict          # tracker -> p_ATE inside (cm), rehearsed session against the true pose
    t1_rate_deg: float | None    # T1 (the anchor-mapped VIO alone) r_ATE against the true orientation, whole window
    window_s: tuple[float, float]
    clock_offsets_ms: dict       # page -> (recorder's estimate - rehearsal's measurement) ms
    frames: int
    calibration_error: str = ""  # calibrate-gt's refusal, if it refused
    imu_lag_ms: float = float("nan")   # the IMU's own lag (imu_lag_s), against the VIO's vio.lag_ms

    @property
    def ate_ok(self) -> bool:
        reh = self.ate_rehearsed_cm if self.calibration is not None else self.ate_oracle_cm
        return all(_finite(self.ate_source_cm.get(t)) and _finite(reh.get(t))
                   and abs(reh[t] - self.ate_source_cm[t]) <= GOAL_ATE_CM for t in SCORED_TRACKERS)


def _finite(v: float | None) -> TypeGuard[float]:
    return v is not None and math.isfinite(v)


# ------------------------------------------------------------------ reading the recording
def _poses(path: Path, topic: str) -> tuple[np.ndarray, Pose | None]:
    from phonepose.session import SessionReader, codec

    stamps, raws = [], []
    with SessionReader(path) as reader:
        for m in reader.messages([topic]):
            try:
                raws.append(codec.raw_pose(m.msg.pose))
            except codec.BrokenPose:
                continue
            stamps.append(m.msg.timestamp.ToNanoseconds())
    if not raws:
        return np.zeros(0, np.int64), None
    arr = np.asarray(raws, dtype=float)
    return np.asarray(stamps, dtype=np.int64), Pose.from_xyzw(arr[:, 4:], arr[:, :4])


def _imu(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    from phonepose.schemas.topics import Topic
    from phonepose.session import SessionReader

    t, g, a = [], [], []
    with SessionReader(path) as reader:
        for m in reader.messages([Topic.CONTROLLER_IMU]):
            t.append(m.msg.timestamp.ToNanoseconds())
            g.append((m.msg.gyro_x, m.msg.gyro_y, m.msg.gyro_z))
            a.append((m.msg.accel_x, m.msg.accel_y, m.msg.accel_z))
    return np.asarray(t, dtype=np.int64), np.asarray(g, float).reshape(-1, 3), np.asarray(a, float).reshape(-1, 3)


def recorder_clock_estimates_ms(path: Path) -> dict[str, float]:
    """The recorder's last logged page-clock offset per connection name (``phone #1 (...)`` -> ms)."""
    import re

    from phonepose.schemas.topics import Topic
    from phonepose.session import SessionReader

    found: dict[str, float] = {}
    pattern = re.compile(r"^(.*?): page clock offset ([+-][0-9.]+) ms")
    with SessionReader(path) as reader:
        for m in reader.messages([Topic.LOG]):
            hit = pattern.match(m.msg.message)
            if hit:
                found[hit.group(1)] = float(hit.group(2))
    return found


def check_stream(stamps_ns: np.ndarray, recorded: Pose, played, sim0_ns: int, window_s: tuple[float, float]) -> StreamCheck:
    """``played(s)``: the pose the device was driven to at sim time ``s``; compared at the recorded stamps
    inside ``window_s`` (sim seconds), then again after removing the best constant lag."""
    s = (stamps_ns - sim0_ns) / 1e9
    keep = (s >= window_s[0]) & (s <= window_s[1])
    s, rec = s[keep], recorded[np.flatnonzero(keep)]
    truth = played(s)
    dp = rec.translation - truth.translation
    ang = np.degrees(rec.angle_to(truth))
    # the lag that best explains the position differences along the motion: dp ≈ -v · lag
    h = 1e-3
    v = (played(s + h).translation - played(s - h).translation) / (2 * h)
    lag = float(-np.sum(v * dp) / max(np.sum(v * v), 1e-12))
    shifted = played(s - lag)
    after = np.linalg.norm(rec.translation - shifted.translation, axis=1)
    after_deg = np.degrees(rec.angle_to(shifted))
    span = s[-1] - s[0] if len(s) > 1 else float("nan")
    return StreamCheck(int(len(s)), (len(s) - 1) / span if span and span > 0 else float("nan"),
                       float(1e3 * np.median(np.linalg.norm(dp, axis=1))), float(1e3 * np.max(np.linalg.norm(dp, axis=1))),
                       float(np.median(ang)), float(np.max(ang)), 1e3 * lag,
                       float(1e3 * np.median(after)), float(1e3 * np.max(after)), float(np.max(after_deg)))


def imu_lag_s(s: np.ndarray, gyro: np.ndarray, t_sim: np.ndarray, gyro_sim: np.ndarray, around_s: float) -> float:
    """The constant lag (s) of the recorded gyro (``gyro`` at sim times ``s``) behind the simulated one (``gyro_sim``
    at ``t_sim``): of the shifts within ``IMU_LAG_SEARCH_MS`` of ``around_s`` (the VIO's lag) on a 0.5 ms grid,
    the one with the least RMS difference. A wrong sign or axis stays tenths of a rad/s whatever the shift."""
    best, best_rms = around_s, float("inf")
    for shift in around_s + np.arange(-IMU_LAG_SEARCH_MS, IMU_LAG_SEARCH_MS + 0.25, 0.5) / 1e3:
        at = s - shift
        ok = (at >= t_sim[0]) & (at <= t_sim[-1])
        if np.count_nonzero(ok) < 2:
            continue
        sim = interp_columns(at[ok], t_sim, gyro_sim)
        rms = float(np.sqrt(np.mean((gyro[ok] - sim) ** 2)))
        if rms < best_rms:
            best, best_rms = float(shift), rms
    return best


def gravity_angle_deg(t_imu_ns: np.ndarray, accel: np.ndarray, t_vio_ns: np.ndarray, vio: Pose,
                      bin_s: float | None = None) -> float:
    """The axis conventions of two independent streams of the page, checked against each other: gravity
    is -y in WebXR's 'local' space (y up), so a phone held in it reads the specific force
    ``R_local_deviceᵀ · (0, +g, 0)`` in DeviceMotion's device frame (x right, y up, z out of the screen:
    the viewer's axes). The angle between the recorded accelerometer and that prediction, each averaged
    over the session (the hand's accelerations average out; or the largest over ``bin_s`` bins): a wrong
    sign or axis order in either stream gives tens of degrees. (A page starved of timer callbacks sends
    the IMU at irregular, sparse times: its 8-12 Hz tremor then no longer averages out over a few
    seconds, so a short bin reads degrees off while the whole session does not.)"""
    from phonepose.geometry import interpolate_many

    # the recorder writes samples as received: a clock-sync update can stamp one at or before its
    # predecessor (counted in the session's summary); skipped as playback skips them (scheduler.py), so
    # the stamps interpolated are ascending and distinct
    keep = np.flatnonzero(newer_than_before(t_vio_ns))
    t_vio_ns, vio = t_vio_ns[keep], vio[keep]
    ok = (t_imu_ns >= t_vio_ns[0]) & (t_imu_ns <= t_vio_ns[-1])
    t = t_imu_ns[ok]
    R = interpolate_many(t_vio_ns / 1e9, vio, t / 1e9).rotation
    predicted = R.inv().apply(np.array([0.0, 9.80665, 0.0]))
    bins = np.zeros(len(t), int) if bin_s is None else np.floor((t - t[0]) / (bin_s * 1e9)).astype(int)
    worst = 0.0
    for b in np.unique(bins):
        m = bins == b
        if np.count_nonzero(m) < 10:
            continue
        a, p = accel[ok][m].mean(axis=0), predicted[m].mean(axis=0)
        cos = float(np.dot(a, p) / (np.linalg.norm(a) * np.linalg.norm(p)))
        worst = max(worst, float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))))
    return worst


# ------------------------------------------------------------------ p_ATE over the window
def window_ate_cm(result, t0_ns: int, t1_ns: int, truth=None, scope: str = "inside", key: str = "p_ate_m",
                  scale: float = 100.0) -> dict[str, float | None]:
    """p_ATE inside the view (cm) per tracker over [t0, t1] (or another of paper_metrics' numbers): against
    the playback's own ground truth, or ``truth(stamps_ns) -> Pose`` (display_vio) when given."""
    from phonepose.evaluation import paper_metrics

    out: dict[str, float | None] = {}
    for name, traj in result.trajectories.items():
        if traj.poses is None:
            out[name] = None
            continue
        inwin = (traj.stamps_ns >= t0_ns) & (traj.stamps_ns <= t1_ns)
        if truth is not None:
            idx = np.flatnonzero(inwin)
            stamps, est, gt, inside = traj.stamps_ns[idx], traj.poses[idx], truth(traj.stamps_ns[idx]), traj.inside[idx]
        else:
            if result.gt is None:
                out[name] = None
                continue
            common, i_est, i_gt = np.intersect1d(traj.stamps_ns[inwin], result.gt_stamps_ns, assume_unique=True,
                                                 return_indices=True)
            idx = np.flatnonzero(inwin)[i_est]
            stamps, est, gt, inside = common, traj.poses[idx], result.gt[i_gt], traj.inside[idx]
        if len(stamps) == 0:
            out[name] = None
            continue
        m = paper_metrics(stamps / 1e9, gt, est, inside)[scope][key]
        out[name] = None if m is None else scale * m
    return out


def calibration_check(cal, scene: Scene) -> CalibrationCheck:
    from phonepose.record.live.webxr import T_GTWORLD_XR

    truth = scene.truth()
    assert cal.T_world_camera is not None   # calibrate-gt always estimates it
    return CalibrationCheck(
        time_offset_ms=1e3 * cal.time_offset_s, true_time_offset_ms=1e3 * truth.time_offset_s,
        world_mm=float(1e3 * cal.T_world_camera.distance_to(T_GTWORLD_XR @ truth.T_world_camera)),
        world_deg=float(np.degrees(cal.T_world_camera.angle_to(T_GTWORLD_XR @ truth.T_world_camera))),
        body_mm=float(1e3 * cal.T_controller_gt.distance_to(truth.T_body_grip)),
        body_deg=float(np.degrees(cal.T_controller_gt.angle_to(truth.T_body_grip))),
        residual_mm=cal.residual_mm, residual_deg=cal.residual_deg, sightings=cal.samples, sigma=dict(cal.sigma))


def score(scene: Scene, run: RecordedRun, calibration_out: Path | None = None, echo=print) -> Scores:
    from phonepose.calibration.calibrate_gt import calibrate_gt_session
    from phonepose.calibration.gt_calibration import save_gt_calibration
    from phonepose.errors import SessionContentError
    from phonepose.playback.engine import run_playback
    from phonepose.record.live.recording import T_DISPLAY_CAMERA as T_LIVE_DISPLAY_CAMERA
    from phonepose.record.live.webxr import T_GTWORLD_XR
    from phonepose.record.sim import T0_NS
    from phonepose.schemas.topics import Topic

    plan = scene.session.plan
    window = (float(plan.task_start), float(plan.task_end))
    whole = (0.0, scene.duration_s)
    t_vio, vio = _poses(run.path, Topic.CONTROLLER_VIO_POSE)
    if vio is None:
        raise SessionContentError(f"{run.path}: the phone page recorded no WebXR pose")
    vio_check = check_stream(t_vio, vio, scene.phone_vio_local, run.sim0_ns, whole)
    gt_check = None
    if run.headset:
        t_gt, gt = _poses(run.path, Topic.GT_CONTROLLER_POSE)
        if gt is not None:   # the recorder turns the headset's WebXR space into gt_world (z up)
            gt_check = check_stream(t_gt, gt, lambda s: T_GTWORLD_XR @ scene.grip_in_headset_world(s), run.sim0_ns, whole)
    t_imu, gyro, accel = _imu(run.path)
    # the IMU is stamped on the page's clock like the VIO: compared at the stamps moved by its own lag, sought
    # near the VIO's
    s_imu = (t_imu - run.sim0_ns) / 1e9
    imu_lag = imu_lag_s(s_imu, gyro, scene.session.t_imu, scene.session.gyro, vio_check.lag_ms / 1e3)
    s_imu = s_imu - imu_lag
    ok = (s_imu >= scene.session.t_imu[0]) & (s_imu <= scene.session.t_imu[-1])
    sim_g = interp_columns(s_imu[ok], scene.session.t_imu, scene.session.gyro)
    sim_a = interp_columns(s_imu[ok], scene.session.t_imu, scene.session.accel)
    n_imu = int(np.count_nonzero(ok))
    span = s_imu[ok][-1] - s_imu[ok][0] if n_imu > 1 else float("nan")

    cal_check, cal, cal_error = None, None, ""
    if run.headset:
        echo("calibrate-gt on the rehearsed session ...")
        try:
            cal = calibrate_gt_session(run.path)
        except SessionContentError as exc:   # e.g. a --config whose motion cannot determine it: a row, not lost data
            cal_error = str(exc)
        else:
            cal_check = calibration_check(cal, scene)
            if calibration_out is not None:
                save_gt_calibration(calibration_out, cal)

    echo("playback --tracker all of the source session ...")
    src = run_playback(scene.source_path, trackers=["all"], write_outputs=False)
    echo("playback --tracker all of the rehearsed session ...")
    reh = run_playback(run.path, trackers=["all"], write_outputs=False, gt_calibration=cal)
    t0_src, t1_src = T0_NS + int(window[0] * 1e9), T0_NS + int(window[1] * 1e9)
    t0_reh, t1_reh = run.sim0_ns + int(window[0] * 1e9), run.sim0_ns + int(window[1] * 1e9)
    # the true marker frame in the rehearsed session's display_vio (= the display: record live's display
    # stands still), through the display camera, whose pose both worlds know
    T_dvio_world = T_LIVE_DISPLAY_CAMERA @ scene.session.world.T_world_camera.inv()

    def oracle(stamps_ns: np.ndarray) -> Pose:
        return T_dvio_world @ scene.true_marker_in_world((stamps_ns - run.sim0_ns) / 1e9)

    offsets = recorder_clock_estimates_ms(run.path)
    clock_err = {}
    for page, clock in run.clocks.items():
        est = [v for k, v in offsets.items() if k.startswith(page)]
        if est:
            clock_err[page] = est[-1] - clock.offset_ns / 1e6
    return Scores(vio_check, gt_check, n_imu, (n_imu - 1) / span if n_imu > 1 else float("nan"),
                  float(np.sqrt(np.mean((gyro[ok] - sim_g) ** 2))) if n_imu else float("nan"),
                  float(np.sqrt(np.mean((accel[ok] - sim_a) ** 2))) if n_imu else float("nan"),
                  gravity_angle_deg(t_imu[ok], accel[ok], t_vio, vio) if n_imu else float("nan"),
                  int(run.counts.get(Topic.CONTROLLER_ANCHOR, 0)),
                  cal_check, window_ate_cm(src, t0_src, t1_src),
                  window_ate_cm(reh, t0_reh, t1_reh) if cal is not None else {},
                  window_ate_cm(reh, t0_reh, t1_reh, truth=oracle),
                  window_ate_cm(reh, t0_reh, t1_reh, truth=oracle, scope="total", key="r_ate_deg", scale=1.0).get("T1"),
                  window, clock_err, run.counts.get(Topic.CAMERA_IMAGE, 0), cal_error, imu_lag_ms=1e3 * imu_lag)


@dataclass(frozen=True)
class Row:
    what: str
    value: str
    goal: str
    met: bool | None        # None: reported, no goal


def rows(sc: Scores) -> list[Row]:
    """The rehearsal's table: every number with the goal it is held to."""
    out = [Row("frames recorded", f"{sc.frames}", "", None),
           Row("anchors set (the Anchor button, tapped)", f"{sc.anchors}", "1", sc.anchors == 1),
           *_stream_rows("phone VIO", sc.vio),
           Row("IMU: recorded vs simulated (RMS)", f"gyro {sc.imu_gyro_rms:.4f} rad/s, accel {sc.imu_accel_rms:.3f} m/s² "
               f"({sc.imu_samples} samples, {sc.imu_rate_hz:.0f} Hz; its lag {sc.imu_lag_ms:.1f} ms out, the VIO's "
               f"{sc.vio.lag_ms:.1f} ms)", f"< {IMU_MAX_GYRO:g} rad/s, "
               f"{IMU_MAX_ACCEL:g} m/s²", sc.imu_gyro_rms < IMU_MAX_GYRO and sc.imu_accel_rms < IMU_MAX_ACCEL),
           Row("gravity: accelerometer vs VIO orientation (session means)", f"{sc.gravity_deg:.2f} deg",
               f"< {GRAVITY_MAX_DEG:g} deg", sc.gravity_deg < GRAVITY_MAX_DEG),
           Row("T1 r_ATE (anchor-mapped VIO vs the true orientation)", _deg(sc.t1_rate_deg), "< 3 deg",
               bool(_finite(sc.t1_rate_deg) and sc.t1_rate_deg < 3.0))]
    if sc.gt is not None:
        out += _stream_rows("headset grip", sc.gt)
    for page, err in sorted(sc.clock_offsets_ms.items()):
        out.append(Row(f"{page} page clock: the recorder's last logged offset - measured", f"{err:+.2f} ms", "", None))
    c = sc.calibration
    if sc.calibration_error:
        out.append(Row("calibrate-gt", f"refused: {sc.calibration_error}", "a calibration", False))
    if c is not None:
        out += [Row("calibrate-gt clock offset", f"{c.time_offset_ms:+.1f} ms (simulated {c.true_time_offset_ms:+.1f} ms)",
                    f"within {GOAL_OFFSET_MS:g} ms", c.time_error_ms <= GOAL_OFFSET_MS),
                Row("calibrate-gt world -> camera", f"{c.world_mm:.2f} mm / {c.world_deg:.3f} deg off",
                    f"{GOAL_MM:g} mm / {GOAL_DEG:g} deg", c.world_mm <= GOAL_MM and c.world_deg <= GOAL_DEG),
                Row("calibrate-gt grip -> body", f"{c.body_mm:.2f} mm / {c.body_deg:.3f} deg off",
                    f"{GOAL_MM:g} mm / {GOAL_DEG:g} deg", c.body_mm <= GOAL_MM and c.body_deg <= GOAL_DEG),
                Row("calibrate-gt residual", f"{c.residual_mm:.2f} mm / {c.residual_deg:.2f} deg RMS "
                    f"({c.sightings} sightings)", "", None)]
    w0, w1 = sc.window_s
    for t in SCORED_TRACKERS:
        src = sc.ate_source_cm.get(t)
        reh = sc.ate_rehearsed_cm.get(t) if c is not None else None
        ora = sc.ate_oracle_cm.get(t)
        main = reh if c is not None else ora
        met = bool(_finite(src) and _finite(main) and abs(main - src) <= GOAL_ATE_CM)
        text = f"source {_cm(src)}, rehearsed {_cm(main)}"
        if c is not None:
            text += f" (vs the true pose {_cm(ora)})"
        out.append(Row(f"{t} p_ATE inside, {w0:.1f}-{w1:.1f} s", text, f"within {GOAL_ATE_CM:g} cm", met))
    return out




def _stream_rows(what: str, c: StreamCheck) -> list[Row]:
    return [Row(f"{what}: recorded vs played", f"{c.median_mm:.3f} mm / {c.median_deg:.4f} deg median, max "
                f"{c.max_mm:.3f} mm / {c.max_deg:.4f} deg; once the lag is out {c.after_lag_max_mm:.3f} mm / "
                f"{c.after_lag_max_deg:.4f} deg max ({c.samples} poses, {c.rate_hz:.0f} Hz)",
                f"< {STREAM_MAX_MM:g} mm / {STREAM_MAX_DEG:g} deg (lag out)",
                c.after_lag_max_mm < STREAM_MAX_MM and c.after_lag_max_deg < STREAM_MAX_DEG),
            Row(f"{what}: pose timing (lag of the stamps)", f"{c.lag_ms:+.2f} ms", f"< {LAG_MAX_MS:g} ms",
                abs(c.lag_ms) < LAG_MAX_MS)]


def _deg(v) -> str:
    return f"{v:.2f} deg" if _finite(v) else "n/a"


def _cm(v) -> str:
    return f"{v:.3f} cm" if _finite(v) else "n/a"
