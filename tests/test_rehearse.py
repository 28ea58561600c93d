"""`phonepose record rehearse` (phonepose/record/rehearse/): a real recording rehearsed with no hardware.

The slow test runs it end to end: a simulated session's frames played by `record live --camera FILE`,
the real phone page (and the headset page, when `record live` serves one) in headless Chromium with
IWER's emulated WebXR devices driven by the simulated motion, then calibrate-gt and playback. The
fast tests check the pieces that make its numbers mean something: the WebXR axis conversion, the lag
estimate and the gravity cross-check (which fails on a wrong sign or axis order).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import DEADLINE_S, require_browser
from scipy.spatial.transform import Rotation

from phonepose.geometry import Pose
from phonepose.record.rehearse.scene import T_HEADSET_WORLD, ZUP_TO_YUP
from phonepose.record.rehearse.score import (
    GOAL_ATE_CM,
    GRAVITY_MAX_DEG,
    IMU_MAX_ACCEL,
    IMU_MAX_GYRO,
    LAG_MAX_MS,
    SCORED_TRACKERS,
    STREAM_MAX_DEG,
    STREAM_MAX_MM,
    check_stream,
    gravity_angle_deg,
    imu_lag_s,
)


def test_zup_to_yup_is_the_webxr_turn():
    """The simulator's worlds are z up, WebXR's y up with -z forward: up goes to +y, the simulator's
    forward (+y) to -z, x stays; a rotation (det +1), not a mirror."""
    R = ZUP_TO_YUP.rotation.as_matrix()
    assert np.allclose(R @ [0, 0, 1], [0, 1, 0]) and np.allclose(R @ [0, 1, 0], [0, 0, -1])
    assert np.allclose(R @ [1, 0, 0], [1, 0, 0]) and np.linalg.det(R) == pytest.approx(1.0)
    # the headset's world keeps its floor at y = 0: the simulator's floor (z = 0) lies there
    floor = T_HEADSET_WORLD.apply(np.array([[0.3, -0.2, 0.0], [2.0, 1.0, 0.0]]))
    assert np.allclose(floor[:, 1], 0.0, atol=1e-12)
    assert T_HEADSET_WORLD.rotation.apply([0, 0, 1]) == pytest.approx([0, 1, 0])


def _waving(s: np.ndarray) -> Pose:
    rv = np.column_stack([0.3 * np.sin(1.1 * s), 0.4 * np.sin(0.7 * s + 1), 0.2 * np.sin(1.9 * s)])
    return Pose(Rotation.from_rotvec(rv), np.column_stack([0.2 * np.sin(s), 1.4 + 0.1 * np.cos(1.3 * s), -0.3 + 0.05 * s]))


def test_check_stream_finds_a_known_lag():
    """Samples stamped 3 ms late against the motion they show: the lag comes out as +3 ms and the
    remaining difference vanishes."""
    sim0 = 10**18
    s = np.arange(0.0, 10.0, 1 / 60)
    stamps = sim0 + np.rint((s + 0.003) * 1e9).astype(np.int64)
    check = check_stream(stamps, _waving(s), _waving, sim0, (0.0, 11.0))
    assert check.lag_ms == pytest.approx(3.0, abs=0.05)
    assert check.median_mm > 0.3 and check.after_lag_max_mm < 0.01
    exact = check_stream(sim0 + np.rint(s * 1e9).astype(np.int64), _waving(s), _waving, sim0, (0.0, 11.0))
    assert exact.max_mm < 1e-6 and abs(exact.lag_ms) < 1e-3


def test_the_imu_s_own_lag_is_found_and_a_wrong_sign_survives_it():
    """Gyro samples stamped 12 ms late (the VIO's lag 4 ms): the shift that explains them is 12 ms, to the
    0.5 ms grid, and what is left is the noise; with one axis's sign wrong no shift brings the difference under
    the goal."""
    rng = np.random.default_rng(3)
    t_sim = np.arange(0.0, 14.0, 1 / 200)
    gyro_sim = np.column_stack([0.8 * np.sin(2.1 * t_sim), 0.5 * np.cos(3.3 * t_sim), 0.3 * np.sin(5.0 * t_sim + 1)])
    s = np.sort(rng.uniform(0.5, 13.5, 2500))            # the page's irregular event times
    truth = np.column_stack([np.interp(s, t_sim, gyro_sim[:, k]) for k in range(3)])
    recorded = truth + rng.normal(0, 0.002, truth.shape)
    lag = imu_lag_s(s + 0.012, recorded, t_sim, gyro_sim, 0.004)
    assert lag == pytest.approx(0.012, abs=0.00025)
    at = s + 0.012 - lag
    rms = np.sqrt(np.mean((recorded - np.column_stack([np.interp(at, t_sim, gyro_sim[:, k]) for k in range(3)])) ** 2))
    assert rms < 0.003
    flipped = recorded * [1, -1, 1]
    lag = imu_lag_s(s + 0.012, flipped, t_sim, gyro_sim, 0.004)
    at = s + 0.012 - lag
    rms = np.sqrt(np.mean((flipped - np.column_stack([np.interp(at, t_sim, gyro_sim[:, k]) for k in range(3)])) ** 2))
    assert rms > 4 * IMU_MAX_GYRO


def test_gravity_check_fails_on_a_wrong_sign_or_axis():
    """A still-ish phone in WebXR's 'local' space (y up) reads +g along the device's up: the check passes
    on consistent streams and gives tens of degrees for a mirrored accelerometer, a z-up reading of the
    poses, the viewer upside down, or a quaternion read w-first. (A viewer turned about its own y, -z
    taken for +z, leaves an upright phone's gravity alone: T1's r_ATE in the slow test catches that.)"""
    s = np.arange(0.0, 12.0, 1 / 60)
    vio = _waving(s)
    t_imu = np.arange(0.0, 12.0, 1 / 100)
    R = _waving(t_imu).rotation
    accel = R.inv().apply(np.array([0.0, 9.80665, 0.0]))
    ns = lambda t: np.rint(t * 1e9).astype(np.int64)  # noqa: E731
    assert gravity_angle_deg(ns(t_imu), accel, ns(s), vio) < 0.05
    assert gravity_angle_deg(ns(t_imu), accel, ns(s), vio, bin_s=1.0) < 0.05
    flip_x = Pose(Rotation.from_euler("x", 180, degrees=True), np.zeros(3))
    zup = Pose(Rotation.from_euler("x", 90, degrees=True), np.zeros(3))
    wrong = {"mirrored accel": (-accel, vio), "z up": (accel, zup @ vio), "upside down": (accel, vio @ flip_x),
             "w first": (accel, Pose.from_xyzw(vio.translation, vio.rotation.as_quat()[:, [3, 0, 1, 2]]))}
    for what, (a, v) in wrong.items():
        assert gravity_angle_deg(ns(t_imu), a, ns(s), v) > 20, what


def test_gravity_check_takes_the_vio_as_recorded_out_of_order_and_repeated():
    """A live recording keeps samples in the order received: a clock-sync update can stamp one before its
    predecessor, or on the same ns (CI met it: scipy's Slerp refused the stamps). Such samples are skipped as
    playback skips them: the angle is the one of the stream without them."""
    s = np.arange(0.0, 12.0, 1 / 60)
    t_imu = np.arange(0.0, 12.0, 1 / 100)
    tilt = Rotation.from_euler("z", 2, degrees=True)          # a 2 deg error, so the angle is not just 0
    accel = (_waving(t_imu).rotation * tilt).inv().apply(np.array([0.0, 9.80665, 0.0]))
    ns = lambda t: np.rint(t * 1e9).astype(np.int64)  # noqa: E731
    kept = np.delete(np.arange(len(s)), 300)                  # what playback keeps of the stream below
    want = gravity_angle_deg(ns(t_imu), accel, ns(s)[kept], _waving(s)[kept])
    order = np.arange(len(s))
    order[[300, 301]] = order[[301, 300]]                     # one pair swapped: 300 comes late, skipped
    stamps, vio = ns(s)[order], _waving(s)[order]
    stamps = np.insert(stamps, 500, stamps[499])              # one stamp repeated (a sample of another pose)
    vio = Pose.concatenate([vio[np.arange(500)], Pose.from_xyzw([9.0, 9.0, 9.0], [1.0, 0.0, 0.0, 0.0]),
                            vio[np.arange(500, len(s))]])
    assert want == pytest.approx(2.0, abs=0.05)
    assert gravity_angle_deg(ns(t_imu), accel, stamps, vio) == want


@pytest.mark.slow
def test_rehearsal_end_to_end(tmp_path):
    """The whole live path with no hardware; the goals of issue 20 (docs/recording-real-sessions.md#rehearsal)."""
    from phonepose.errors import ConfigError
    from phonepose.record.rehearse import rehearse, rows
    from phonepose.record.rehearse.browser import find_iwer
    from phonepose.session import SessionReader

    try:
        find_iwer()
    except ConfigError as exc:   # no node: tools/install-test-browser.sh could not run npm ci
        pytest.skip(str(exc))
    require_browser()

    # a longer lead-in than the command's: the browser may take longer to start on a loaded machine
    result = rehearse(tmp_path / "r", lead_in_s=30.0, timeout_s=DEADLINE_S, echo=lambda line: None)
    sc = result.scores
    # the recording has what the pages sent through their own WebXR code: frames, VIO, the anchor, IMU, the
    # headset's ground truth
    with SessionReader(result.files["live.mcap"]) as reader:
        summary = reader.summary()
    for topic in ("/display/camera/image", "/controller/vio/pose", "/controller/imu", "/controller/anchor",
                  "/display/anchor", "/gt/controller/pose"):
        assert summary.has(topic), topic
    assert sc.frames > 400 and sc.anchors == 1
    assert sc.vio.samples > 25 * 14 and sc.imu_samples > 20 * 14
    # pose timing and the axis conventions: the recorded VIO and ground truth are the played ones once the
    # clock's lag is out (a wrong sign or axis is centimetres or tens of degrees), gravity through the VIO
    # matches the accelerometer, and the anchor-mapped VIO alone (T1) keeps the true orientation (a viewer
    # turned about any axis between the page and the recorder's controller body would turn it)
    for check in (sc.vio, sc.gt):
        assert check is not None and abs(check.lag_ms) < LAG_MAX_MS
        assert check.after_lag_max_mm < STREAM_MAX_MM and check.after_lag_max_deg < STREAM_MAX_DEG
    assert sc.gravity_deg < GRAVITY_MAX_DEG
    assert sc.t1_rate_deg is not None and sc.t1_rate_deg < 3.0
    assert sc.imu_gyro_rms < IMU_MAX_GYRO and sc.imu_accel_rms < IMU_MAX_ACCEL
    # calibrate-gt recovers the simulated clock delay, the headset's world and the grip on the phone
    c = sc.calibration
    assert c is not None
    assert c.time_error_ms <= 5.0, c
    assert c.world_mm <= 5.0 and c.world_deg <= 0.5, c
    assert c.body_mm <= 5.0 and c.body_deg <= 0.5, c
    assert c.residual_mm < 5.0 and c.residual_deg < 1.0, c
    # T4-T8 inside the view score as on the source session
    for t in SCORED_TRACKERS:
        src, reh = sc.ate_source_cm[t], sc.ate_rehearsed_cm[t]
        assert src is not None and reh is not None, t
        assert abs(reh - src) <= GOAL_ATE_CM, (t, reh, src)
    assert result.met, [r for r in rows(sc) if r.met is False]
    assert set(result.files) == {"source.mcap", "camera.avi", "camera.yaml", "live.mcap", "rehearsal.json",
                                 "gt-calibration.yaml"}


def test_cli_refuses_before_any_work(tmp_path, cli, monkeypatch):
    """A missing --iwer file, an --out folder of the user's: one line, the exit code, nothing written."""
    monkeypatch.chdir(tmp_path)

    def run(*args: str):
        return cli("record", "rehearse", *args)

    r = run("--out", "r", "--iwer", "missing.js")
    assert r.returncode == 5 and r.stderr.strip().splitlines() == [
        "phonepose: error: --iwer missing.js: no such file (expected IWER's build/iwer.min.js)"]
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("the user's\n")
    iwer = tmp_path / "mine" / "iwer.min.js"   # the output rule is checked whether or not npm installed IWER
    iwer.write_text("// not run\n")
    r = run("--out", "mine", "--iwer", str(iwer))
    assert r.returncode == 6 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "holds files phonepose did not write" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"] and (mine / "notes.txt").read_text() == "the user's\n"
    assert sorted(p.name for p in mine.iterdir()) == ["iwer.min.js", "notes.txt"]
