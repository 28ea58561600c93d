"""The simulated world without rendering: config, geometry of the anchor mapping, CM1, scenarios, IMU, GT."""

from __future__ import annotations

import dataclasses
import tomllib

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from phonepose.errors import ConfigError
from phonepose.geometry import Pose
from phonepose.record.sim import TABLE4, SimSession, default_config, load_config
from phonepose.record.sim.imu import true_imu
from phonepose.record.sim.scenarios import TICK_HZ
from phonepose.record.sim.world import GRAVITY, marker_in_view

# Every error of the world switched off.
NO_ERRORS = dict(
    display_vio=dict(jitter_m=0.0, jitter_deg=0.0, drift_m_per_sqrt_s=0.0, yaw_drift_deg_per_sqrt_s=0.0),
    controller_vio=dict(jitter_m=0.0, tilt_jitter_deg=0.0, drift_m_per_sqrt_s=0.0, drift_per_path_length=0.0,
                        yaw_drift_deg_per_sqrt_s=0.0, scale_error_sigma=0.0),
    anchor=dict(controller_translation_m=0.0, controller_yaw_deg=0.0, controller_tilt_deg=0.0,
                display_translation_m=0.0, display_yaw_deg=0.0, display_tilt_deg=0.0),
    network=dict(controller_latency_s=0.0, wifi_jitter_s=0.0),
    mocap=dict(noise_m=0.0, noise_deg=0.0, hand_eye_rotation_deg=0.0, hand_eye_translation_m=0.0,
               calibration_translation_m=0.0, calibration_rotation_deg=0.0),
    imu=dict(gyro_noise_density=0.0, accel_noise_density=0.0, gyro_bias_sigma=0.0, accel_bias_sigma=0.0,
             gyro_bias_random_walk=0.0, accel_bias_random_walk=0.0),
    human=dict(cm1_alignment_m=0.0, cm1_alignment_deg=0.0),
)


@pytest.fixture(scope="module")
def tri2():
    return SimSession("exp2", "TRI2", 1, seed=0)


@pytest.fixture(scope="module")
def tri2_clean():
    return SimSession("exp2", "TRI2", 1, seed=0, config=default_config().replace(**NO_ERRORS))


# ---------------------------------------------------------------- config
def test_effective_config_round_trips_through_toml():
    cfg = default_config()
    assert tomllib.loads(cfg.to_toml()) == dataclasses.asdict(cfg)


def test_config_file_overrides_a_subset(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text("[network]\ncontroller_latency_s = 0.05\n")
    cfg = load_config(f)
    assert cfg.network.controller_latency_s == 0.05
    assert cfg.network.wifi_jitter_s == default_config().network.wifi_jitter_s


@pytest.mark.parametrize("text, needle", [
    ("[anchor]\ncontroller_yaw_deg = 90\n", "'anchor.controller_yaw_deg' = 90.0 is out of range: allowed [0, 45]"),
    ("[anchor]\nbogus = 1\n", "unknown config key 'anchor.bogus'"),
    ("[nosuch]\nx = 1\n", "unknown config key 'nosuch'"),
    ("[render]\nmotion_blur = 3\n", "'render.motion_blur' must be true or false"),
    ("[render]\njpeg_quality = 80.5\n", "'render.jpeg_quality' must be an integer in [10, 100]"),
    ("[marker]\ndictionary = \"DICT_9X9\"\n", "'marker.dictionary' must be one of"),
    ("[anchor\n", "invalid TOML"),
])
def test_bad_config_names_the_key_and_range(tmp_path, text, needle):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(ConfigError) as exc:
        load_config(f)
    assert needle in str(exc.value)


def test_exact_mocap_is_the_true_pose_and_leaves_every_sensor_stream_unchanged(tri2):
    exact = SimSession("exp2", "TRI2", 1, seed=0, config=default_config().replace(mocap={"exact": True}))
    m = exact.cfg.mocap
    assert m.exact and all(getattr(m, k) == 0.0 for k in m.ERRORS) and m.rate_hz == 60.0
    # ground truth = the true controller pose on the display's clock, no calibration error
    np.testing.assert_array_equal(exact.log_gt, exact.t_gt)
    true = exact.traj(exact.t_gt)
    assert np.abs(exact.gt_ctrl.translation - true.translation).max() < 1e-12
    assert np.abs((exact.gt_ctrl.rotation * true.rotation.inv()).magnitude()).max() < 1e-9
    assert exact.world.calibration_error.translation.tolist() == [0.0, 0.0, 0.0]
    # the sensors see exactly the default session (the mocap's random draws still happen)
    np.testing.assert_array_equal(exact.t_cam, tri2.t_cam)
    np.testing.assert_array_equal(exact.T_cvio_ctrl.translation, tri2.T_cvio_ctrl.translation)
    np.testing.assert_array_equal(exact.gyro, tri2.gyro)
    assert tomllib.loads(exact.cfg.to_toml())["mocap"]["exact"] is True


# ---------------------------------------------------------------- anchors and VIO
def test_anchor_mapping_is_exact_without_errors(tri2_clean):
    s = tri2_clean
    mapped = s.mapped_controller()
    true = s.true_controller_in_dvio(s.t_cvio)
    assert np.max(mapped.distance_to(true)) < 1e-9
    assert np.max(mapped.angle_to(true)) < 1e-9


def test_default_anchor_error_puts_the_mapped_controller_5_to_7_cm_off():
    rms = []
    for seed in range(4):
        s = SimSession("exp2", "TRI1", 1, seed=seed)
        d = s.mapped_controller().distance_to(s.true_controller_in_dvio(s.t_cvio))
        rms.append(np.sqrt(np.mean(d ** 2)))
    assert 0.045 < np.mean(rms) < 0.075, rms


def test_display_vio_is_near_the_true_display_pose(tri2):
    s = tri2
    true = s.world.T_world_dvio.inv() @ s.world.T_world_display
    d = np.linalg.norm(s.T_dvio_display.translation - true.translation, axis=1)
    assert np.median(d) < 0.003


def test_controller_stream_arrives_with_the_configured_latency(tri2):
    s = tri2
    delay = s.arrive_cvio - s.t_cvio
    lat = s.cfg.network.controller_latency_s
    assert np.all(delay >= lat - 1e-12)
    assert lat < np.median(delay) < lat + 3 * s.cfg.network.wifi_jitter_s
    assert np.all(np.diff(s.arrive_cvio) >= 0) and np.all(np.diff(s.arrive_imu) >= 0)


# ---------------------------------------------------------------- CM1 / CM2
def test_cm1_user_aligns_the_real_phone_with_the_fixed_cg_object(tri2):
    s = tri2
    fix = s.T_map @ s.T_cvio_ctrl[s.j_fix]
    align = s.T_map @ s.T_cvio_ctrl[s.j_align]
    true_at_align = s.true_controller_in_dvio(s.t_cvio[s.j_align:s.j_align + 1])[0]
    # the real phone sits where the CG object was shown (within tremor and the human alignment error)
    assert fix.distance_to(true_at_align) < 0.02
    assert np.rad2deg(fix.angle_to(true_at_align)) < 5.0
    # the true correction x_fix - x_align cancels the mapped VIO error at the align moment
    err = align.translation - true_at_align.translation
    assert np.linalg.norm(err) > 0.03
    assert np.linalg.norm((fix.translation - align.translation) + err) < 0.02


def test_calibrations_come_before_the_task_and_cm2_is_in_view(tri2):
    s, p = tri2, tri2.plan
    assert s.t_cvio[s.j_fix] < s.t_cvio[s.j_align] < s.t_cm2 < p.task_start < p.task_end <= p.end
    i = int(np.argmin(np.abs(s.t_cam - s.t_cm2)))
    assert s.in_view[i]


# ---------------------------------------------------------------- scenarios
@pytest.mark.parametrize("path", ["TRI1", "TRI2", "REC1", "REC2"])
@pytest.mark.parametrize("trial", [1, 2, 3])
def test_exp2_frame_counts_match_the_papers_table_4(path, trial):
    s = SimSession("exp2", path, trial, seed=trial)
    total, outside = TABLE4[path][trial - 1]
    ticks = s.plan.task_start + np.arange(s.task_frames_20hz) / TICK_HZ
    assert len(ticks) == total
    in_view = marker_in_view(s.world, s.world.T_world_camera.inv() @ s.traj(ticks), s.cfg.marker.size_m)
    n_out = int(np.sum(~in_view))
    if outside == 0:
        assert n_out == 0
    else:
        assert abs(n_out - outside) <= 2, (n_out, outside)


def test_exp1_has_16_targets_at_25_and_35_cm_held_5_s():
    s = SimSession("exp1", None, 1, seed=0)
    targets = s.plan.targets
    assert len(targets) == 16
    T_cam = s.world.T_world_camera.inv()
    depths = np.array([(T_cam @ t.T_world).translation[2] for t in targets])
    assert np.sum(np.isclose(depths, 0.25, atol=1e-9)) == 8 and np.sum(np.isclose(depths, 0.35, atol=1e-9)) == 8
    assert sum(t.inside_view for t in targets) == 8
    for t in targets:
        assert t.hold_end - t.hold_start == pytest.approx(5.0)
        mid = (t.hold_start + t.hold_end) / 2
        assert s.traj(np.array([mid]))[0].distance_to(t.T_world) < 0.02
    assert s.plan.task_start == min(t.hold_start for t in targets)
    assert s.plan.task_end == max(t.hold_end for t in targets)


def test_same_seed_same_world_different_seed_different():
    a, b, c = (SimSession("exp2", "TRI1", 1, seed=k) for k in (5, 5, 6))
    assert np.array_equal(a.T_cam_ctrl.translation, b.T_cam_ctrl.translation)
    assert np.array_equal(a.gyro, b.gyro)
    n = min(len(a.t_cam), len(c.t_cam))
    assert not np.allclose(a.T_cam_ctrl.translation[:n], c.T_cam_ctrl.translation[:n])


# ---------------------------------------------------------------- IMU
def _integrate(gyro: np.ndarray, dts: np.ndarray, R0: Rotation) -> Rotation:
    R = R0
    for w, dt in zip(gyro, dts, strict=True):
        R = R * Rotation.from_rotvec(w * dt)
    return R


@pytest.mark.parametrize("noisy", [False, True])
def test_imu_integrates_back_to_the_true_orientation_over_1_s(noisy):
    cfg = default_config() if noisy else default_config().replace(imu=NO_ERRORS["imu"])
    s = SimSession("exp2", "TRI1", 1, seed=3, config=cfg)
    i0 = int(np.searchsorted(s.t_imu, s.plan.task_start))   # during the path: the phone turns
    n = int(np.searchsorted(s.t_imu, s.t_imu[i0] + 1.0)) - i0   # 1 s of samples (some may be dropped)
    assert n > 190
    # gyro samples are instantaneous rates: integrate with the midpoint rate of each interval,
    # over the actual sample spacing
    mid = 0.5 * (s.gyro[i0:i0 + n] + s.gyro[i0 + 1:i0 + n + 1])
    dts = np.diff(s.t_imu[i0:i0 + n + 1])
    R0 = s.traj(s.t_imu[i0:i0 + 1]).rotation[0]
    R1_true = s.traj(s.t_imu[i0 + n:i0 + n + 1]).rotation[0]
    R1 = _integrate(mid, dts, R0)
    err_deg = np.rad2deg((R1.inv() * R1_true).magnitude())
    turned = np.rad2deg((R0.inv() * R1_true).magnitude())
    assert turned > 2.0       # the test means something: the phone did rotate
    if noisy:
        im = cfg.imu
        # 1 s of turn-on bias (3 sigma per axis, 3 axes) plus the white-noise random walk
        bound = np.rad2deg(3 * np.sqrt(3) * (im.gyro_bias_sigma + im.gyro_noise_density)) * 1.0
        assert err_deg < bound
    else:
        assert err_deg < 0.01


def test_accelerometer_reads_gravity_when_still_and_matches_the_motion():
    s = SimSession("exp2", "TRI1", 1, seed=0, config=default_config().replace(imu=NO_ERRORS["imu"],
                   human=dict(tremor_m=0.0, tremor_deg=0.0, sway_m=0.0, sway_deg=0.0)))
    still = (s.t_imu > 0.1) & (s.t_imu < 1.2)          # the start hold
    assert np.allclose(np.linalg.norm(s.accel[still], axis=1), GRAVITY, atol=1e-4)
    # specific force in the world frame = a + g: check it against a numerical second derivative
    t = s.t_imu[(s.t_imu > s.plan.task_start) & (s.t_imu < s.plan.task_start + 1)][::20]
    gyro, acc = true_imu(s.traj, t)
    h = 1e-2
    a = (s.traj(t + h).translation - 2 * s.traj(t).translation + s.traj(t - h).translation) / h ** 2
    f_world = s.traj(t).rotation.apply(acc)
    assert np.allclose(f_world - np.array([0, 0, GRAVITY]), a, atol=0.02)


# ---------------------------------------------------------------- ground truth
def test_gt_is_the_true_pose_with_the_hand_eye_offset_and_clock_offset():
    cfg = default_config().replace(mocap=dict(noise_m=0.0, noise_deg=0.0, clock_offset_s=0.02))
    s = SimSession("exp2", "TRI1", 1, seed=0, config=cfg)
    expected = s.traj(s.t_gt) @ Pose(Rotation.concatenate([s.world.hand_eye.rotation] * len(s.t_gt)),
                                     np.tile(s.world.hand_eye.translation, (len(s.t_gt), 1)))
    assert np.max(expected.distance_to(s.gt_ctrl)) < 1e-12
    assert np.rad2deg(s.world.hand_eye.rotation.magnitude()) == pytest.approx(cfg.mocap.hand_eye_rotation_deg)
    assert np.allclose(s.log_gt - s.t_gt, 0.02)
    assert np.allclose(np.diff(s.t_gt), 1 / 60)


def test_marker_chain_through_the_display_vio_is_exact_without_errors(tri2_clean):
    """T_dvio_ctrl = T_dvio_display · T_display_camera · T_camera_ctrl: what marker trackers compute."""
    from phonepose.record.sim.world import T_DISPLAY_CAMERA

    s = tri2_clean
    i = np.arange(0, len(s.t_cam), 25)
    j = np.searchsorted(s.t_dvio, s.t_cam[i]).clip(0, len(s.t_dvio) - 1)
    chain = s.T_dvio_display[j] @ Pose(Rotation.concatenate([T_DISPLAY_CAMERA.rotation] * len(i)),
                                       np.tile(T_DISPLAY_CAMERA.translation, (len(i), 1))) @ s.T_cam_ctrl[i]
    true = s.true_controller_in_dvio(s.t_cam[i])
    assert np.max(chain.distance_to(true)) < 1e-9 and np.max(chain.angle_to(true)) < 1e-9


def test_trials_share_the_world_of_a_seed_but_not_the_motion():
    a, b = SimSession("exp1", None, 1, seed=4), SimSession("exp1", None, 2, seed=4)
    assert a.world.anchor_error_controller.allclose(b.world.anchor_error_controller, atol=0)
    assert a.world.T_world_cvio.allclose(b.world.T_world_cvio, atol=0)
    assert [t.index for t in a.plan.targets] != [t.index for t in b.plan.targets]


def test_relocalisation_jumps_step_the_controller_vio():
    cfg = default_config().replace(controller_vio=dict(jump_rate_per_min=30.0, jump_median_m=0.05, jitter_m=0.0))
    s = SimSession("exp2", "TRI1", 1, seed=2, config=cfg)
    err = s.mapped_controller().translation - s.true_controller_in_dvio(s.t_cvio).translation
    steps = np.linalg.norm(np.diff(err, axis=0), axis=1)
    jumps = s.cvio_model.jump_times
    assert len(jumps) >= 3
    assert np.sum(steps > 0.004) >= len(jumps) // 2      # most jumps show as a step (tiny ones may not)
    quiet = SimSession("exp2", "TRI1", 1, seed=2, config=default_config().replace(controller_vio=dict(jitter_m=0.0)))
    q_err = quiet.mapped_controller().translation - quiet.true_controller_in_dvio(quiet.t_cvio).translation
    assert np.max(np.linalg.norm(np.diff(q_err, axis=0), axis=1)) < 0.004


def test_dropped_frames_and_samples():
    cfg = default_config().replace(camera=dict(drop_rate=0.2), imu=dict(drop_rate=0.1))
    s = SimSession("exp2", "TRI1", 1, seed=0, config=cfg)
    full = SimSession("exp2", "TRI1", 1, seed=0)
    assert 0.7 < len(s.t_cam) / len(full.t_cam) < 0.9
    assert 0.85 < len(s.t_imu) / len(full.t_imu) < 0.95
    assert np.max(np.diff(s.t_cam)) > 1.5 / cfg.camera.rate_hz


def test_imu_noise_and_bias_have_the_configured_size():
    still = default_config().replace(human=dict(tremor_m=0.0, tremor_deg=0.0, sway_m=0.0, sway_deg=0.0),
                                     imu=dict(gyro_bias_random_walk=0.0, accel_bias_random_walk=0.0, drop_rate=0.0))
    s = SimSession("exp1", None, 1, seed=0, config=still)
    im = still.imu
    # the first hold of exp1 lasts 5 s: the phone is perfectly still
    t0 = s.plan.targets[0].hold_start
    sel = (s.t_imu > t0 + 0.1) & (s.t_imu < t0 + 4.9)
    gyro, accel = s.gyro[sel], s.accel[sel]
    sigma_g = im.gyro_noise_density * np.sqrt(im.rate_hz)
    sigma_a = im.accel_noise_density * np.sqrt(im.rate_hz)
    assert np.allclose(gyro.std(axis=0), sigma_g, rtol=0.15)
    assert np.allclose(accel.std(axis=0), sigma_a, rtol=0.15)
    g_bias, _ = s.imu_bias
    assert np.allclose(gyro.mean(axis=0), g_bias[0], atol=4 * sigma_g / np.sqrt(sel.sum()))
