"""T8 (ours, the fused tracker) on hand-built Observations with known motion, latency and errors.

The controller's VIO frame is off the truth by a rigid error ``T_ERR`` (truth = T_ERR · VIO).
VIO is captured at 30 Hz and received ``LATENCY`` later; ticks every 50 ms; the marker (= the
truth at the image time, exactly) is recognised while ``visible(tick)``. Expected values follow
from the geometry: once the filter has paired sightings with VIO, its correction is T_ERR, and
the output is the truth.
"""

from __future__ import annotations

import dataclasses
import math

import hypothesis.strategies as st
import numpy as np
import pytest
from hypothesis import given
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from phonepose.evaluation.boundary import boundary_jump_stats, boundary_jumps
from phonepose.geometry import Pose
from phonepose.pipeline.t8 import CorrectionFilter, FusedTracker, FusionConfig
from phonepose.pipeline.t8.motion import RateCorrelation as _RateCorrelation
from phonepose.pipeline.trackers import make_tracker
from phonepose.pipeline.types import Frame, MarkerObservation, Observation, Tick

LATENCY_NS = 120_000_000
VIO_PERIOD_NS = 33_333_333
TICK_NS = 50_000_000
IMU_PERIOD_NS = 5_000_000
# mostly a heading error, as between two gravity-aligned VIO worlds (tilt 0.2 deg)
T_ERR = Pose.from_rotvec([0.03, -0.02, 0.04], [0.002, -0.003, 0.04])   # translation, rotation vector
R0 = Rotation.from_rotvec([0.1, -0.2, 0.3])


def static(t_s: float) -> Pose:
    return Pose(R0, np.array([0.1, 0.2, 0.4]))


def constant_velocity(t_s: float) -> Pose:
    return Pose(R0, np.array([0.1, 0.2, 0.4]) + np.array([0.3, -0.2, 0.1]) * t_s)


def circle(t_s: float) -> Pose:
    """0.15 m radius at 1 rad/s (0.15 m/s): the velocity turns, so a time offset is observable."""
    return Pose(R0 * Rotation.from_rotvec([0, 0, 0.2 * np.sin(t_s)]),
                np.array([0.15 * np.cos(t_s), 0.15 * np.sin(t_s), 0.4]))


def observations(truth, n_ticks: int, visible=lambda i: True, stamp_offset_ns: int = 0,
                 flip_at: int | None = None, image_age_ns: int = 0, vio_jitter_m: float = 0.0,
                 imu=None) -> list[Observation]:
    """``stamp_offset_ns``: the VIO stamps are that much earlier than the true capture times;
    ``image_age_ns``: each tick's image (and the marker in it) was captured that long before the tick;
    ``vio_jitter_m``: white noise (sigma per axis, seeded) on every VIO sample's position;
    ``imu``: t_s -> (gyro, accel) body-frame rows at 200 Hz, received with the VIO's latency (None: no IMU)."""
    captures = range(-10 * VIO_PERIOD_NS, n_ticks * TICK_NS, VIO_PERIOD_NS)
    noise = dict(zip(captures, np.random.default_rng(7).normal(size=(len(captures), 3)) * vio_jitter_m, strict=True))

    def vio(c: int) -> Pose:
        pose = T_ERR.inv() @ truth(c / 1e9)
        return pose.with_translation(pose.translation + noise[c]) if c in noise else pose
    out = []
    for i in range(n_ticks):
        t = i * TICK_NS
        received = [c for c in captures if (i - 1) * TICK_NS < c + LATENCY_NS <= t]
        samples = [(c - stamp_offset_ns, vio(c)) for c in received]
        marker = None
        t_img = t - image_age_ns
        if visible(i):
            pose = truth(t_img / 1e9)
            if i == flip_at:   # IPPE's other solution: the marker seen tilted the wrong way
                pose = Pose(pose.rotation * Rotation.from_rotvec([0.6, 0, 0]), pose.translation + [0, 0, 0.05])
            marker = MarkerObservation(corners_px=np.zeros((4, 2)), T_camera_marker=Pose.identity(),
                                       T_dvio_controller=pose, reprojection_error_px=0.1,
                                       chosen_solution=0, ambiguity_ratio=10.0, id=7)
        rows = np.zeros((0, 7))
        if imu is not None:
            stamps = [c for c in range(-10 * VIO_PERIOD_NS, t, IMU_PERIOD_NS) if (i - 1) * TICK_NS < c + LATENCY_NS <= t]
            rows = np.array([[c / 1e9, *imu(c / 1e9)[0], *imu(c / 1e9)[1]] for c in stamps]).reshape(-1, 7)
        tick = Tick(index=i, t_ns=t, frame=Frame(b"", "jpeg", t_img, is_new=True, T_dvio_display=Pose.identity()),
                    T_dvio_display=Pose.identity(), imu=rows)
        out.append(Observation(tick=tick, marker=marker, T_dvio_controller_vio=vio(t - LATENCY_NS),
                               controller_vio_samples_dvio=samples))
    return out


def run(tracker, obs):
    tracker.reset()
    return [tracker.step(o) for o in obs]


def errors(est, truth, obs):
    pos = np.array([np.linalg.norm(e.translation - truth(o.tick.t_ns / 1e9).translation) for e, o in zip(est, obs, strict=True)])
    rot = np.array([np.degrees((e.rotation * truth(o.tick.t_ns / 1e9).rotation.inv()).magnitude())
                    for e, o in zip(est, obs, strict=True)])
    return pos, rot


def test_t8_is_the_fused_tracker():
    t8 = make_tracker("T8")
    assert isinstance(t8, FusedTracker) and t8.uses_vio_samples


def test_static_phone_correction_is_the_frame_error_and_output_is_the_truth():
    obs = observations(static, 40, visible=lambda i: i < 20)
    t8 = FusedTracker()
    est = run(t8, obs)
    f = t8.filter
    assert f.ready and f.rejected == 0
    assert np.degrees((f.R * T_ERR.rotation.inv()).magnitude()) < 1e-6
    np.testing.assert_allclose(f.t, T_ERR.translation, atol=1e-9)
    assert abs(f.d) < 1e-9                      # a still phone says nothing against zero offset
    pos, rot = errors(est, static, obs)
    # from the first pairing on, inside and outside: the pair waits for the VIO up to half the time offset's
    # velocity window (0.1 s) past the image, which arrives one latency later (tick 6, 0.3 s)
    assert pos[6:].max() < 1e-6 and rot[6:].max() < 1e-6
    assert rot[:6].min() > 0.5                 # before it: the uncorrected VIO orientation (the frame error)


def test_constant_velocity_is_predicted_over_the_latency_inside_and_outside():
    obs = observations(constant_velocity, 60, visible=lambda i: i < 30)
    t8 = FusedTracker()
    est = run(t8, obs)
    pos, rot = errors(est, constant_velocity, obs)
    # the VIO reaches the display 0.12 s late; T8 moves it to the tick time at the fitted velocity
    assert pos[15:].max() < 1e-5, pos          # (the inside filter forgets its start-up by half per tick)
    assert rot[10:].max() < 1e-6
    # T1 (uncorrected VIO, as received): off by the frame error and by speed x latency
    t1_pos, _ = errors(run(make_tracker("T1"), obs), constant_velocity, obs)
    assert t1_pos[10:].min() > 0.02


def test_the_sighting_is_moved_from_its_image_time_to_the_tick():
    # the images are 20 ms old at every tick (a 30 Hz camera read at 20 Hz): T4 reports the marker where it
    # was then, speed x 20 ms = 7.5 mm behind; T8 moves it to the tick along the corrected VIO velocity
    age_ns = 20_000_000
    obs = observations(constant_velocity, 40, image_age_ns=age_ns)
    pos, _ = errors(run(FusedTracker(), obs), constant_velocity, obs)
    assert pos[10:].max() < 1e-5, pos
    speed = np.linalg.norm(constant_velocity(1.0).translation - constant_velocity(0.0).translation)
    t4_pos, _ = errors(run(make_tracker("T4"), obs), constant_velocity, obs)
    np.testing.assert_allclose(t4_pos[10:], speed * age_ns / 1e9, rtol=1e-9)
    # the option off: T8 reports the sighting where it was, as T4
    off, _ = errors(run(FusedTracker(config=FusionConfig(marker_to_tick=0)), obs), constant_velocity, obs)
    np.testing.assert_allclose(off[10:], speed * age_ns / 1e9, rtol=1e-6)


def test_marker_dropping_out_and_back_leaves_no_step():
    visible = lambda i: i < 20 or 40 <= i < 50                                     # noqa: E731
    obs = observations(constant_velocity, 60, visible=visible)
    est = run(FusedTracker(), obs)
    t = np.array([o.tick.t_ns / 1e9 for o in obs])
    p_gt = np.array([constant_velocity(s).translation for s in t])
    p_est = np.array([e.translation for e in est])
    inside = np.array([visible(i) for i in range(60)])
    jumps = boundary_jumps(t, p_gt, p_est, inside)
    assert len(jumps) == 3                       # out at 20, in at 40, out at 50
    assert jumps.max() < 1e-6
    # T4 switches from the marker to uncorrected VIO: its jump is the frame error (plus latency)
    t4 = run(make_tracker("T4"), obs)
    t4_jumps = boundary_jumps(t, p_gt, np.array([e.translation for e in t4]), inside)
    assert t4_jumps.min() > 0.01


ACCELERATION = np.array([0.4, -0.3, 0.2])   # m/s^2


def constant_acceleration(t_s: float) -> Pose:
    return Pose(R0, np.array([0.1, 0.2, 0.4]) + np.array([0.1, 0.05, 0.0]) * t_s + 0.5 * ACCELERATION * t_s ** 2)


def test_entering_the_view_the_motion_over_the_tick_is_the_velocity_at_the_tick():
    # out of view for 10 ticks, then back in: the output moves by the estimated motion over the switching tick.
    # The VIO velocity carried to the tick by the quadratic fit's whole acceleration (tau -> inf) leaves only
    # the truth's own curvature, |a| dt^2 / 2; the velocity at the newest VIO sample (~0.13 s old, tau = 0) is
    # |a| (h - dt/2) dt off; the default tau (a hand's acceleration does not last the latency) lies between
    visible = lambda i: i < 90 or 100 <= i                                           # noqa: E731
    obs = observations(constant_acceleration, 120, visible=visible)
    t = np.array([o.tick.t_ns / 1e9 for o in obs])
    p_gt = np.array([constant_acceleration(s).translation for s in t])
    inside = np.array([visible(i) for i in range(120)])
    dt = TICK_NS / 1e9

    def entry_jump(tau: float) -> float:
        est = run(FusedTracker(config=FusionConfig(entry_acceleration_time_s=tau)), obs)
        return float(boundary_jumps(t, p_gt, np.array([e.translation for e in est]), inside)[1])   # [0]: leaving

    assert entry_jump(math.inf) == pytest.approx(np.linalg.norm(ACCELERATION) * dt ** 2 / 2, rel=1e-3)
    assert entry_jump(0.0) > 4 * entry_jump(math.inf)
    assert entry_jump(math.inf) < entry_jump(FusionConfig().entry_acceleration_time_s) < entry_jump(0.0)


CURVE = np.array([0.2, -0.15, 0.1])   # m/s^2


def curving(t_s: float) -> Pose:
    """A constant acceleration ``CURVE``, turning round at 3 s (within 0.5 m of the start over 5 s)."""
    return Pose(R0, np.array([0.1, 0.2, 0.4]) + 0.5 * CURVE * (t_s - 3.0) ** 2)


def _accelerometer(bias: np.ndarray):
    """A perfect IMU on ``curving`` (constant orientation R0): specific force R0^T (a - g) plus a constant
    body-frame ``bias``; no rotation."""
    force = R0.inv().apply(CURVE - np.array([0.0, 0.0, -9.80665])) + bias
    return lambda t_s: (np.zeros(3), force)


@pytest.mark.parametrize("bias", [np.zeros(3), np.array([0.1, -0.08, 0.05])])
def test_the_accelerometer_predicts_a_constant_acceleration_exactly(bias):
    # outside the view the VIO (0.12 s late, in a frame tilted and turned by T_ERR) is predicted to the tick. The
    # VIO positions less the accelerometer's double integral (gravity removed through the VIO orientation and
    # the correction's tilt) are a line plus, with a bias, a parabola that the quadratic fit takes up exactly;
    # past the newest IMU sample the acceleration is carried whole (accel_carry_time_s -> inf): the output is the
    # truth. The default holds the velocity there and misses by |a| h^2 / 2, h the time from the newest IMU sample
    # to the tick; with tau = 0.05 s the acceleration decays and the output misses by |a| (h^2 / 2 - tau h +
    # tau^2 (1 - e^(-h/tau))); without the accelerometer the quadratic fit's slope alone
    # misses by |a| h_vio^2 / 2 (h_vio from the newest VIO sample). blend_time_s 0.01: no offset left from the exit;
    # 3e-5 m: the correction filter's own residual here (2e-5 m, the same with and without the accelerometer)
    visible = lambda i: i < 60                                                       # noqa: E731
    obs = observations(curving, 100, visible=visible, imu=_accelerometer(bias))
    outside = np.arange(65, 100)
    t_ns = np.array([obs[i].tick.t_ns for i in outside])
    h_imu = np.array([t_ns[k] / 1e9 - max(o.tick.imu[:, 0].max() for o in obs[:i + 1] if len(o.tick.imu))
                      for k, i in enumerate(outside)])
    h_vio = np.array([t_ns[k] - max(c for o in obs[:i + 1] for c, _ in o.controller_vio_samples_dvio)
                      for k, i in enumerate(outside)]) / 1e9
    a = np.linalg.norm(CURVE)

    def outside_error(**config) -> np.ndarray:
        est = run(FusedTracker(config=FusionConfig(blend_time_s=0.01, **config)), obs)
        return errors(est, curving, obs)[0][outside]

    np.testing.assert_allclose(outside_error(accel_carry_time_s=math.inf), 0, atol=3e-5)
    assert FusionConfig().accel_carry_time_s == 0   # the velocity at the newest IMU sample, held
    np.testing.assert_allclose(outside_error(), a * h_imu ** 2 / 2, atol=3e-5)
    tau = 0.05
    np.testing.assert_allclose(outside_error(accel_carry_time_s=tau),
                               a * (h_imu ** 2 / 2 - tau * h_imu - tau ** 2 * np.expm1(-h_imu / tau)), atol=3e-5)
    if not bias.any():
        np.testing.assert_allclose(outside_error(accel_prediction=0), a * h_vio ** 2 / 2, atol=3e-5)


def test_a_150_ms_vio_time_offset_is_estimated_online():
    # 20 s around the circle in view, then 5 s out of it, where only the (time-aligned) VIO is left
    obs = observations(circle, 500, visible=lambda i: i < 400, stamp_offset_ns=150_000_000)
    t8 = FusedTracker()
    est = run(t8, obs)
    assert t8.filter.d == pytest.approx(0.150, abs=0.005)
    pos, _ = errors(est, circle, obs)
    outside = slice(410, 500)
    assert np.sqrt(np.mean(pos[outside] ** 2)) < 0.002
    # without the offset state the VIO outside is predicted to the wrong moment: off by ~speed x offset
    frozen = FusedTracker(config=FusionConfig(init_time_offset_s=0.0))
    pos0, _ = errors(run(frozen, obs), circle, obs)
    assert np.sqrt(np.mean(pos0[outside] ** 2)) > 5 * np.sqrt(np.mean(pos[outside] ** 2))


def test_vio_jitter_does_not_bias_the_time_offset():
    # no offset at all, 1.5 mm of white VIO jitter (the simulator's): the velocity in d's Jacobian is a fit
    # centred on the pair's time, so it does not share the paired samples' noise with the residual (the
    # slope at the newest sample did: d settled at +16.8 ms here, 4.7 sigma, and +10 ms on simulated sessions)
    obs = observations(circle, 500, vio_jitter_m=0.0015)
    t8 = FusedTracker()
    run(t8, obs)
    sigma = np.sqrt(t8.filter.P[6, 6])     # the filter's own uncertainty of d: 3.6 ms
    assert abs(t8.filter.d) < 1.5 * sigma, (t8.filter.d, sigma)


def test_a_flipped_marker_pose_is_gated_out():
    obs = observations(static, 60, flip_at=40)
    t8 = FusedTracker()
    est = run(t8, obs)
    assert t8.filter.rejected == 1
    assert np.degrees((t8.filter.R * T_ERR.rotation.inv()).magnitude()) < 1e-6
    pos, rot = errors(est, static, obs)
    assert rot[10:].max() < 1e-6           # the orientation never follows the flipped frame


def test_config_rejects_unknown_and_non_numeric_parameters():
    from phonepose.errors import ConfigError
    assert FusionConfig.from_dict({"blend_time_s": "0.2"}).blend_time_s == 0.2
    with pytest.raises(ConfigError, match="unknown T8 parameter"):
        FusionConfig.from_dict({"nope": 1})
    with pytest.raises(ConfigError, match="not a number"):
        FusionConfig.from_dict({"blend_time_s": "x"})


# ----------------------------------------------------------------------------- the metric
def test_boundary_jump_is_the_estimated_minus_the_true_change_at_transitions():
    t = np.arange(10) * 0.05
    p_gt = np.column_stack([t * 0.2, np.zeros(10), np.zeros(10)])
    p_est = p_gt.copy()
    p_est[5:] += [0.0, 0.02, 0.0]                 # a 2 cm step where the marker is lost
    inside = np.array([True] * 5 + [False] * 5)
    np.testing.assert_allclose(boundary_jumps(t, p_gt, p_est, inside), [0.02])
    stats = boundary_jump_stats(t, p_gt, p_est, inside)
    assert stats["boundary_jumps"] == 1
    assert stats["boundary_jump_max_m"] == pytest.approx(0.02) and stats["boundary_jump_rms_m"] == pytest.approx(0.02)
    # a step elsewhere is not a boundary jump; no transition gives no value
    assert boundary_jump_stats(t, p_gt, p_est, np.ones(10, bool))["boundary_jump_max_m"] is None
    # a hole in the trajectory (no pose for a tick) leaves no pair across it
    keep = np.array([0, 1, 2, 3, 4, 6, 7, 8, 9])
    assert boundary_jumps(t[keep], p_gt[keep], p_est[keep], inside[keep]).size == 0


def test_boundary_jump_rms_over_two_transitions():
    t = np.arange(6) * 0.05
    p_gt = np.zeros((6, 3))
    p_est = np.zeros((6, 3))
    p_est[2:] += [0.03, 0, 0]
    p_est[4:] += [0, 0.04, 0]
    inside = np.array([True, True, False, False, True, True])
    stats = boundary_jump_stats(t, p_gt, p_est, inside)
    assert stats["boundary_jump_max_m"] == pytest.approx(0.04)
    assert stats["boundary_jump_rms_m"] == pytest.approx(np.sqrt((0.03 ** 2 + 0.04 ** 2) / 2))


def test_a_recognised_marker_without_display_pose_and_no_vio_keeps_the_last_sighting():
    """No VIO at all; the second frame's marker cannot be placed (display pose unknown): T8 reports
    the last sighting it could place (found by the tracker fuzz test)."""
    pose = static(0.0)
    seen = MarkerObservation(corners_px=np.zeros((4, 2)), T_camera_marker=Pose.identity(), T_dvio_controller=pose,
                             reprojection_error_px=0.1, chosen_solution=0, ambiguity_ratio=10.0, id=7)
    unplaced = MarkerObservation(corners_px=np.zeros((4, 2)), T_camera_marker=Pose.identity(), T_dvio_controller=None,
                                 reprojection_error_px=0.1, chosen_solution=0, ambiguity_ratio=10.0, id=7)
    obs = [Observation(tick=Tick(index=i, t_ns=i * TICK_NS, frame=Frame(b"", "jpeg", i * TICK_NS, is_new=True)),
                       marker=m, T_dvio_controller_vio=None) for i, m in enumerate([seen, unplaced])]
    est = run(FusedTracker(), obs)
    assert est[0].allclose(pose, atol=1e-12) and est[1].allclose(pose, atol=1e-12)


def _phone_at_R0(t8: FusedTracker, vio_until_s: float, gyro_until_s: float, rate: np.ndarray) -> FusedTracker:
    """``t8`` fed VIO samples at 30 Hz of a phone still at R0 up to ``vio_until_s`` and IMU rows at 200 Hz up to
    ``gyro_until_s``: the gyro reading ``rate`` (body frame, rad/s), the accelerometer gravity."""
    q0 = tuple(R0.as_quat().tolist())
    for k in range(int(round(vio_until_s * 30)) + 1):
        t8._add_vio(k / 30, (q0, np.zeros(3)))
    for k in range(int(round(gyro_until_s * 200)) + 1):
        t8._imu.add(k / 200, np.r_[rate, 0.0, 0.0, 9.80665])
    t8._new_gyro()          # what _ingest does after new IMU rows
    return t8


def _pull_case(data_until_s: float, sighting_error_deg: float, ambiguity: float = 13.0) -> tuple[Rotation, Rotation, float]:
    """A T8 whose filter is not yet ready (no correction), a still phone at R0 whose VIO and gyro samples
    end at ``data_until_s``, and one sighting at 0.9 s turned ``sighting_error_deg`` about x from R0, with IPPE
    ambiguity ratio ``ambiguity`` (13: FusionConfig.rotation_ambiguity_ref, the sighting's noise as configured)."""
    t8 = _phone_at_R0(FusedTracker("T8"), data_until_s, data_until_s, np.zeros(3))
    q0 = tuple(R0.as_quat().tolist())
    delta = Rotation.from_rotvec([np.radians(sighting_error_deg), 0, 0])
    t8._add_sighting(0.9, (tuple((delta * R0).as_quat().tolist()), np.zeros(3)), None, ambiguity)
    return Rotation.from_quat(t8._pulled_by_sighting(q0)), delta, t8.cfg


def test_orientation_pull_is_a_kalman_share_of_the_sighting_at_its_own_time():
    """Where VIO has data at the image time (h = 0) the sighting moves the output by
    s_v^2 / (s_v^2 + s_m^2) of its difference; 0.1 s past the newest VIO and gyro samples by
    (s_v^2 + (s_w 0.1)^2) / (... + s_m^2); a flip (> 3 sigma) not at all."""
    out, delta, c = _pull_case(data_until_s=1.0, sighting_error_deg=2.0)
    gain = c.pull_vio_rotation_deg ** 2 / (c.pull_vio_rotation_deg ** 2 + c.pull_marker_rotation_deg ** 2)
    assert np.degrees((out * R0.inv()).magnitude()) == pytest.approx(2.0 * gain, abs=1e-9)     # 0.165 deg
    out, delta, c = _pull_case(data_until_s=0.8, sighting_error_deg=2.0)
    P = c.pull_vio_rotation_deg ** 2 + (c.pull_prediction_deg_per_s * 0.1) ** 2
    assert np.degrees((out * R0.inv()).magnitude()) == pytest.approx(2.0 * P / (P + c.pull_marker_rotation_deg ** 2),
                                                                     abs=1e-6)                  # 1.21 deg
    out, _, _ = _pull_case(data_until_s=0.8, sighting_error_deg=20.0)
    assert (out * R0.inv()).magnitude() == 0.0


def _held_rate_case(config: FusionConfig, rate: np.ndarray, gyro_until_s: float, t_stamp: float) -> Rotation:
    """A still VIO at R0 up to 1 s and a gyro reading ``rate`` (body frame, rad/s) at 200 Hz up to
    ``gyro_until_s``: T8's orientation predicted to ``t_stamp``, relative to R0."""
    t8 = _phone_at_R0(FusedTracker("T8", config), 1.0, gyro_until_s, rate)
    return R0.inv() * Rotation.from_quat(t8._predicted_rotation(t_stamp))


@pytest.mark.parametrize("tau, carried", [(math.inf, 0.1), (0.2, 0.2 * (1 - math.exp(-0.1 / 0.2))), (0.0, 0.0)])
def test_past_the_newest_gyro_sample_the_mean_rate_decays_with_its_correlation_time(tau, carried):
    """From the newest VIO sample (1 s) to the newest gyro sample (1.05 s) the rotation is the gyro's; 0.1 s
    past it the mean rate acts tau (1 - e^(-0.1 / tau)) s (held whole for tau = inf, not at all for 0)."""
    rate = np.array([0.3, -0.2, 0.5])
    got = _held_rate_case(FusionConfig(gyro_rate_adapt_s=0, gyro_rate_time_s=tau), rate, 1.05, 1.15)
    np.testing.assert_allclose(got.as_rotvec(), rate * (0.05 + carried), atol=1e-12)


def test_the_rates_correlation_takes_each_newest_gyro_sample_once():
    """Every 4th tick carries no IMU rows (its rows come with the next tick) while the VIO, arriving, prunes the
    ring: the correlation gets one mean per newest gyro sample, in order, none twice (it took the same mean
    again on such ticks when it was updated where the prediction read it)."""
    obs = observations(circle, 120, imu=lambda t_s: (np.array([0.0, 0.0, 0.6]), np.array([0.0, 0.0, 9.80665])))
    for i in range(0, 120, 4):
        later = obs[i + 1].tick.imu
        obs[i + 1].tick.imu = np.vstack([obs[i].tick.imu, later])
        obs[i].tick.imu = np.zeros((0, 7))
    t8 = FusedTracker("T8")
    t8.reset()
    taken: list[float] = []
    update = t8._rate_correlation.update
    t8._rate_correlation.update = lambda t, rate: (taken.append(t), update(t, rate))[1]   # type: ignore[method-assign]
    for o in obs:
        t8.step(o)
    with_rows = sum(1 for o in obs if len(o.tick.imu))
    assert len(taken) == with_rows > 80
    assert (np.diff(taken) > 0).all()


def _correlation(rates, lag_s=0.25, step_s=0.125, memory_s=5.0, min_history_s=2.0):
    """The estimator fed one mean rate every ``step_s`` (binary fractions: the partner is exactly ``lag_s``
    earlier); the tau after each."""
    est = _RateCorrelation(lag_s, memory_s, min_history_s, initial=math.inf)
    return [est.update(k * step_s, np.asarray(r, dtype=float)) for k, r in enumerate(rates)]


@pytest.mark.parametrize("tau0", [0.1, 0.37, 2.0])
def test_the_rates_correlation_time_of_an_exponential_decay_is_its_time_constant(tau0):
    """A rate decaying as e^(-t / tau0): every mean is e^(-lag / tau0) times its partner, so rho is that and
    tau = tau0; before 2 s of means the initial tau (held)."""
    taus = _correlation([np.array([0.3, -0.2, 0.5]) * math.exp(-k * 0.125 / tau0) for k in range(40)])
    assert all(math.isinf(t) for t in taus[:16])                  # 15 * 0.125 s < 2 s
    assert taus[16:] == pytest.approx([tau0] * 24, rel=1e-9)


def test_a_steady_rate_is_held_and_a_reversing_one_is_not_carried():
    assert all(math.isinf(t) for t in _correlation([[0.1, 0.2, 0.3]] * 40))
    taus = _correlation([[0.1, 0.2, 0.3], [-0.1, -0.2, -0.3]] * 20, lag_s=0.125)     # partner: the step before
    assert taus[16:] == [0.0] * 24


@pytest.mark.parametrize("memory_s", [1.0, 5.0])
def test_the_rates_correlation_forgets_with_its_memory(memory_s):
    """A steady rate for 10 s (79 pairs of equal means), then one reversing every step (partner: the step
    before). The sums' terms weigh d^age, d = e^(-step / memory): the sum of products turns negative, and
    tau drops to 0, at the first n reversed pairs with d^n (2 - d^79) < 1."""
    x = [0.2, 0.0, 0.0]
    taus = _correlation([x] * 80 + [[-0.2, 0.0, 0.0], x] * 40, lag_s=0.125, memory_s=memory_s)
    d = math.exp(-0.125 / memory_s)
    n = next(n for n in range(1, 80) if d ** n * (2 - d ** 79) < 1)       # 6 pairs for 1 s, 28 for 5 s
    assert math.isinf(taus[79])
    assert 0 < taus[80 + n - 2] < math.inf and taus[80 + n - 1] == 0.0
    assert taus[-1] == 0.0


@pytest.mark.parametrize("ambiguity, noise_factor", [(13.0 / 4, 2.0), (52.0, 0.5), (0.25, math.sqrt(13.0)), (0.0, 1.0)])
def test_a_sighting_nearer_facing_the_camera_pulls_less(ambiguity, noise_factor):
    """A sighting's orientation noise scales with sqrt(13 / its IPPE ambiguity ratio) (the ratio clipped to >= 1;
    0: not known, as configured): a quarter of the ratio doubles it in the pull's Kalman share and in the filter's
    measurement noise, four times the ratio halves it."""
    out, _, c = _pull_case(data_until_s=1.0, sighting_error_deg=2.0, ambiguity=ambiguity)
    s_m = c.pull_marker_rotation_deg * noise_factor
    gain = c.pull_vio_rotation_deg ** 2 / (c.pull_vio_rotation_deg ** 2 + s_m ** 2)
    assert np.degrees((out * R0.inv()).magnitude()) == pytest.approx(2.0 * gain, abs=1e-9)
    tracker = FusedTracker()
    R_meas = tracker._measurement_noise(np.zeros(3), None, tracker._rotation_scale(ambiguity))
    np.testing.assert_allclose(np.sqrt(np.diag(R_meas)[:3]), np.radians(c.marker_rotation_deg * noise_factor), rtol=1e-12)


@given(arrays(np.float64, (5, 3), elements=st.floats(-100, 100)), arrays(np.float64, (5, 3), elements=st.floats(-1, 1)))
def test_the_accelerometer_path_s_cross_products_are_numpy_s(a, b):
    """T8 turns the specific forces past the newest VIO sample by the gyro with its own cross products (two
    gathered products instead of np.cross's argument handling, half the cost on a few rows): np.cross to the bit."""
    from phonepose.pipeline.t8.motion import cross_rows as _cross
    assert _cross(a, b).tobytes() == np.cross(a, b).tobytes()


def test_the_specific_forces_kept_between_ticks_are_those_computed_afresh():
    """T8 keeps the specific force it turned into the world for IMU samples up to the newest VIO sample (those
    never change) and turns only the new ones each tick: its outputs are the same, to the bit, as when it turns
    every sample of the window every tick. A turning, accelerating phone, with gyro and accelerometer."""
    def imu(t_s: float):
        rot = (R0 * Rotation.from_rotvec([0, 0, 0.2 * np.sin(t_s)])).inv()
        return np.array([0.0, 0.0, 0.2 * np.cos(t_s)]), rot.apply(-0.15 * np.array([np.cos(t_s), np.sin(t_s), 0])
                                                                  - np.array([0.0, 0.0, -9.80665]))

    class Afresh(FusedTracker):
        def _specific_force_world(self, *args):
            self._turned = (np.empty(0), np.empty((0, 3)))
            return super()._specific_force_world(*args)

    obs = observations(circle, 120, visible=lambda i: i < 40 or 70 < i < 90, imu=imu)
    kept, afresh = run(FusedTracker(), obs), run(Afresh(), obs)
    assert sum(p is not None for p in kept) > 100
    rows = lambda poses: np.array([np.r_[p.quat_xyzw, p.translation] for p in poses if p is not None])  # noqa: E731
    assert rows(kept).tobytes() == rows(afresh).tobytes()


@given(st.lists(st.lists(st.integers(0, 30), max_size=8), max_size=6))
def test_adding_a_batch_of_samples_is_adding_each_in_turn(batches):
    """T8's sample rings keep a row only if its stamp is newer than every earlier one, whether the rows come one
    by one or a batch at a time (in order, with repeats, out of order, older than what is kept)."""
    from phonepose.pipeline.t8.motion import Ring as _Ring
    one, many = _Ring(3, capacity=4), _Ring(3, capacity=4)
    for stamps in batches:
        t = np.array(stamps, dtype=float)
        values = np.stack([t, -t, 2 * t], axis=1)
        for ti, v in zip(t, values, strict=True):
            one.add(float(ti), v)
        many.add_many(t, values)
        assert many.t.tobytes() == one.t.tobytes() and many.v.tobytes() == one.v.tobytes()
        assert many.last_t == one.last_t


def test_a_burst_of_imu_samples_larger_than_the_rings_room_is_taken_whole():
    """A tick that brings seconds of IMU samples at once (a stalled stream catching up) made T8 loop for ever: its
    ring slid rows that were already at the front to make room. Now it grows, and every sample is kept."""
    import dataclasses

    def imu(t_s: float):
        return np.zeros(3), np.array([0.0, 0.0, 9.80665])

    obs = observations(static, 4, imu=imu)
    stamps = 0.2 + np.arange(600) / 200                  # 3 s at 200 Hz, newer than every sample before
    burst = np.column_stack([stamps, np.zeros((600, 3)), np.tile([0.0, 0.0, 9.80665], (600, 1))])
    obs.append(dataclasses.replace(obs[-1], tick=dataclasses.replace(obs[-1].tick, index=4, t_ns=int(3.3e9), imu=burst)))
    t8 = FusedTracker()
    run(t8, obs)
    kept = t8._imu.t[t8._imu.t >= stamps[0] - t8._t0_ns / 1e9 - 1e-9]
    np.testing.assert_allclose(kept[-len(stamps):] - kept[-len(stamps)], stamps - stamps[0], atol=1e-9)


def test_the_filter_skips_a_sighting_it_cannot_weigh_and_rejects_an_absurd_one():
    """update() solves S with LAPACK directly: a singular S (no uncertainty at all) skips the sighting without
    counting a rejection, as np.linalg.solve's LinAlgError did; a sighting with an infinite position is gated
    (a rejection), and neither moves the correction."""
    f = CorrectionFilter(FusionConfig())
    q = (0.0, 0.0, 0.0, 1.0)
    f.initialise((q, np.zeros(3)), (q, np.zeros(3)))
    f.P[:] = 0.0
    state = (f.q, f.t.copy(), f.d)
    zero = np.zeros(3)
    assert not f.update((q, np.array([0.01, 0.0, 0.0])), (q, zero), zero, zero, np.zeros((6, 6)))
    assert (f.rejections, f.rejected, f.accepted) == (0, 0, 0)
    f.P[:] = np.eye(7) * 1e-4
    assert not f.update((q, np.array([np.inf, 0.0, 0.0])), (q, zero), zero, zero, np.eye(6) * 1e-4)
    assert (f.rejections, f.rejected, f.accepted) == (1, 1, 0)
    assert f.q == state[0] and np.array_equal(f.t, state[1]) and f.d == state[2]
    assert f.update((q, np.array([0.01, 0.0, 0.0])), (q, zero), zero, zero, np.eye(6) * 1e-4)
    assert f.accepted == 1 and f.t[0] > 0.004          # an ordinary sighting still moves it


FLAGS = [f.name for f in dataclasses.fields(FusionConfig) if f.type in ("bool", bool)]


@given(st.sampled_from(FLAGS), st.sampled_from([True, False]), st.sampled_from([str, lambda v: str(v).upper(), int, bool]))
def test_a_flag_reads_as_a_bool_whatever_its_spelling(name, value, spell):
    """FusionConfig's flags are bool fields: true/false (any case), 1/0, as values or strings, read the same."""
    got = getattr(FusionConfig.from_dict({name: spell(value)}), name)
    assert got is value


@pytest.mark.parametrize("bad", ["2", "maybe", "", 0.5])
def test_a_flag_given_anything_else_is_refused_by_name(bad):
    from phonepose.errors import ConfigError
    for name in FLAGS:
        with pytest.raises(ConfigError, match=f"T8 parameter {name}=.* is not a flag"):
            FusionConfig.from_dict({name: bad})
