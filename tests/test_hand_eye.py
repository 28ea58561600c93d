"""Hand-eye calibration (phonepose/calibration/hand_eye.py), `calibrate-hand-eye` and `playback --gt-calibration`."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from phonepose.calibration.hand_eye import HandEye, estimate_hand_eye, hand_eye_from_session, load_hand_eye, save_hand_eye
from phonepose.errors import InputFileError, SessionContentError
from phonepose.geometry import Pose
from phonepose.playback.engine import run_playback
from phonepose.testing.playback_session import write_test_session

X_TRUE = Pose(Rotation.from_rotvec(np.radians([-9.0, 3.0, 5.5])), np.array([0.004, -0.002, 0.003]))
Z_TRUE = Pose(Rotation.from_euler("zyx", [70.0, 4.0, -2.0], degrees=True), np.array([1.5, -0.3, 0.9]))


def phone_motion(t: np.ndarray, axes: str = "xyz") -> Pose:
    """A hand turning the phone about several axes (smooth; 0.2-0.7 Hz), in the phone's VIO world."""
    rv = np.zeros((len(t), 3))
    for k, (amp, f) in enumerate(((25.0, 0.23), (18.0, 0.41), (30.0, 0.17))):
        if "xyz"[k] in axes:
            rv[:, k] = np.radians(amp) * np.sin(2 * np.pi * f * t + k)
    pos = np.column_stack([0.2 * np.sin(0.3 * t), 0.1 * np.cos(0.5 * t), 0.05 * t])
    return Pose(Rotation.from_rotvec(rv), pos)


def mocap_of(phone_t: np.ndarray, offset_s: float, axes: str = "xyz"):
    """The rigid body as motion capture reports it: its own world Z, its frame X, stamps offset_s late."""
    stamps = np.arange(0.0, 30.0, 1 / 120)
    body = Z_TRUE @ phone_motion(stamps - offset_s, axes) @ X_TRUE
    return stamps, body


def test_recovers_the_rotation_and_the_clock_offset_exactly():
    t = np.arange(0.2, 29.5, 1 / 30)
    stamps, body = mocap_of(t, 0.030)
    he = estimate_hand_eye(t, phone_motion(t), stamps, body, translation=X_TRUE.translation)
    assert he.time_offset_s == 0.030
    assert np.degrees(he.T_controller_mocap.angle_to(X_TRUE)) < 0.01     # 120 Hz slerp of a smooth motion
    assert np.allclose(he.T_controller_mocap.translation, X_TRUE.translation)   # as given, not estimated
    assert he.residual_deg < 0.01 and he.pairs > 500


def test_negative_offset_and_no_offset():
    t = np.arange(0.5, 29.0, 1 / 30)
    for offset in (-0.12, 0.0):
        stamps, body = mocap_of(t, offset)
        he = estimate_hand_eye(t, phone_motion(t), stamps, body)
        assert he.time_offset_s == pytest.approx(offset, abs=1e-9)
        assert np.degrees(he.T_controller_mocap.angle_to(X_TRUE)) < 0.01


def test_one_axis_or_no_motion_is_refused():
    t = np.arange(0.2, 29.5, 1 / 30)
    stamps, body = mocap_of(t, 0.0, axes="z")
    with pytest.raises(SessionContentError, match="one axis only"):
        estimate_hand_eye(t, phone_motion(t, axes="z"), stamps, body)
    still = Pose(Rotation.identity(len(t)), np.zeros((len(t), 3)))
    with pytest.raises(SessionContentError, match=r"only 0 motions turn the phone"):
        estimate_hand_eye(t, still, stamps, Z_TRUE @ still[np.zeros(len(stamps), dtype=int)] @ X_TRUE)
    with pytest.raises(SessionContentError, match="do not overlap"):
        estimate_hand_eye(t + 100, phone_motion(t), stamps, body)


def test_file_round_trip_and_bad_files(tmp_path):
    he = HandEye(T_controller_mocap=X_TRUE, time_offset_s=0.03, pairs=12, residual_deg=0.25)
    save_hand_eye(tmp_path / "he.yaml", he)
    back = load_hand_eye(tmp_path / "he.yaml")
    assert back.T_controller_mocap.allclose(X_TRUE, atol=1e-12)
    assert (back.time_offset_s, back.pairs, back.residual_deg) == (0.03, 12, 0.25)
    (tmp_path / "garbage.yaml").write_text("not yaml at all\n")
    with pytest.raises(InputFileError, match="not an OpenCV YAML/XML hand-eye file"):
        load_hand_eye(tmp_path / "garbage.yaml")
    (tmp_path / "other.yaml").write_text("%YAML:1.0\nfoo: 1\n")
    with pytest.raises(InputFileError, match=r"expected a 4x4 matrix T_controller_gt, or an older hand-eye file's "
                                             r"T_controller_mocap\)$"):
        load_hand_eye(tmp_path / "other.yaml")
    with pytest.raises(InputFileError, match="no such hand-eye file"):
        load_hand_eye(tmp_path / "none.yaml")


def test_playback_moves_the_ground_truth_by_exactly_the_file(tmp_path):
    """GT at tick i becomes the mocap sample of tick i + 1 (offset 50 ms = one 20 Hz tick) times X^-1."""
    session = tmp_path / "s.mcap"
    write_test_session(session)
    save_hand_eye(tmp_path / "he.yaml", HandEye(T_controller_mocap=X_TRUE, time_offset_s=0.05))
    plain = run_playback(session, trackers="T1", write_outputs=False)
    moved = run_playback(session, trackers="T1", write_outputs=False, gt_calibration=tmp_path / "he.yaml")
    by_tick = {int(s): k for k, s in enumerate(plain.gt_stamps_ns)}
    pairs = [(k, by_tick[int(s) + 50_000_000]) for k, s in enumerate(moved.gt_stamps_ns) if int(s) + 50_000_000 in by_tick]
    assert len(pairs) >= len(moved.gt_stamps_ns) - 2
    i, j = np.array(pairs).T
    assert moved.gt[i].allclose(plain.gt[j] @ X_TRUE.inv(), atol=1e-9)
    assert moved.metrics["ground_truth"] == {"calibration_file": str(tmp_path / "he.yaml"), "method": "calibrate-hand-eye",
                                             "body_rotation_deg": round(float(np.degrees(X_TRUE.rotation.magnitude())), 6),
                                             "body_translation_m": [0.004, -0.002, 0.003], "time_offset_s": 0.05,
                                             "world_display_vio": "session"}
    assert "ground_truth" not in plain.metrics


@pytest.mark.slow
def test_simulated_session_cli_end_to_end(tmp_path, cli):
    """record sim -> calibrate-hand-eye finds the simulator's 11 deg hand-eye and 30 ms mocap clock;
    playback --gt-calibration then scores the trackers' own orientation error, not the rigid body's."""
    from phonepose.record.sim import SimSession, default_config, record_sim

    session = tmp_path / "s.mcap"
    record_sim(session, scenario="exp2", path="TRI2", trial=1, seed=0)
    truth = SimSession("exp2", "TRI2", 1, seed=0).world.hand_eye
    cfg = default_config()

    r = cli("calibrate-hand-eye", str(session), "--out", str(tmp_path / "he.yaml"), "--translation", "0,0,0")
    assert r.returncode == 0, r.stderr
    assert re.search(r"rigid body turned 1[01]\.\d\d ± 0\.\d\d deg .* mocap clock \+(29|30|31) ± \d\.\d ms \(1σ\); "
                     r"\d+ motions", r.stdout), r.stdout
    he = load_hand_eye(tmp_path / "he.yaml")
    assert he.time_offset_s == pytest.approx(cfg.mocap.clock_offset_s, abs=0.002)   # 1 ms grid, noisy VIO
    assert np.degrees(he.T_controller_mocap.angle_to(truth)) < 0.3       # of the simulator's 11 deg
    assert cfg.mocap.hand_eye_rotation_deg == 11.0
    # NaN / non-unit / inf VIO samples are skipped as playback skips them, not fatal
    from test_reliability_cli import _bad_quaternions, rewrite
    broken = hand_eye_from_session(rewrite(session, tmp_path / "broken.mcap", _bad_quaternions()))
    assert np.degrees(broken.T_controller_mocap.angle_to(truth)) < 0.5 and broken.pairs < he.pairs

    for args, name in (((), "plain"), (("--gt-calibration", str(tmp_path / "he.yaml")), "moved")):
        r = cli("playback", str(session), "-q", "-t", "T4,T8", "--out", str(tmp_path / name), *args)
        assert r.returncode == 0, r.stderr
    plain = json.loads((tmp_path / "plain" / "metrics.json").read_text())["trackers"]
    moved = json.loads((tmp_path / "moved" / "metrics.json").read_text())["trackers"]
    # the hand-eye rotation is every tracker's r_ATE without the calibration, and gone with it
    assert plain["T4"]["inside"]["r_ate_deg"] > 9.0 and moved["T4"]["inside"]["r_ate_deg"] < 4.0
    assert moved["T8"]["total"]["r_ate_deg"] < moved["T4"]["total"]["r_ate_deg"]


def test_uncertainty_per_quantity_and_a_warning_with_numbers_when_the_motion_is_short():
    """Issue 17: a short recording gave 13.4 deg for a true 11 deg with a 0.22 deg residual and no warning."""
    rng = np.random.default_rng(4)

    def noisy(t):   # VIO-like rotation noise, 0.3 deg per pose
        P = phone_motion(t)
        return Pose(P.rotation * Rotation.from_rotvec(rng.normal(size=(len(t), 3)) * np.radians(0.3)), P.translation)

    t = np.arange(0.2, 29.5, 1 / 30)
    stamps, body = mocap_of(t, 0.030)
    long = estimate_hand_eye(t, noisy(t), stamps, body)
    assert long.warnings == () and 0 < long.sigma_rotation_deg < 0.2 and long.sigma_time_offset_ms < 5
    assert np.degrees(long.T_controller_mocap.angle_to(X_TRUE)) < 4 * long.sigma_rotation_deg
    short_t = t[(t > 10) & (t < 12.5)]
    short = estimate_hand_eye(short_t, noisy(short_t), stamps, body)
    assert short.sigma_rotation_deg > 0.5 and len(short.warnings) == 1
    assert short.warnings[0].startswith(f"the motion does not determine the hand-eye calibration well: rotation "
                                        f"±{short.sigma_rotation_deg:.2f} deg")
    assert f"from {short.pairs} motions, axis spread {short.axis_spread:.2f}" in short.warnings[0]
    assert np.degrees(short.T_controller_mocap.angle_to(X_TRUE)) < 4 * short.sigma_rotation_deg


def test_duplicated_messages_are_used_once(tmp_path):
    """Issue 18: duplicated messages made calibrate-hand-eye fail with a ValueError from the interpolation."""
    from test_reliability_cli import rewrite

    from phonepose.session import SessionWriter
    from phonepose.session.codec import pose_in_frame

    session = tmp_path / "s.mcap"
    t = np.arange(0.2, 12.0, 1 / 30)
    stamps, body = mocap_of(t, 0.030)
    msgs = [(int(1e9 * (100 + x)), "/controller/vio/pose", pose_in_frame(p, "controller_vio", int(1e9 * (100 + x))))
            for x, p in zip(t, phone_motion(t), strict=True)]
    msgs += [(int(1e9 * (100 + x)), "/gt/controller/pose", pose_in_frame(p, "world", int(1e9 * (100 + x))))
             for x, p in zip(stamps[stamps < 12.5], body[np.flatnonzero(stamps < 12.5)], strict=True)]
    with SessionWriter(session) as w:
        for ns, topic, msg in sorted(msgs, key=lambda m: m[0]):
            w.write(topic, msg, ns)

    def twice(topic, msg, t):
        doubled = topic in ("/controller/vio/pose", "/gt/controller/pose")
        return [(topic, msg, t), (topic, msg, t)] if doubled else [(topic, msg, t)]

    doubled = rewrite(session, tmp_path / "doubled.mcap", twice)
    he_once = hand_eye_from_session(session, bootstrap=0)
    he_twice = hand_eye_from_session(doubled, bootstrap=0)
    assert he_twice.T_controller_mocap.allclose(he_once.T_controller_mocap, atol=1e-12)
    assert (he_twice.pairs, he_twice.time_offset_s) == (he_once.pairs, he_once.time_offset_s)


def test_the_batched_bootstrap_fits_what_align_vectors_fits():
    """_uncertainty's batched SVD against a resample-by-resample refit with scipy's align_vectors (the code it
    replaced): the same 1σ to rounding, on a long and on a short (warned-about) recording."""
    from phonepose.calibration import hand_eye as module

    rng = np.random.default_rng(4)
    t = np.arange(0.2, 12.0, 1 / 30)
    stamps, body = mocap_of(t, 0.030)
    for tt in (t, t[(t > 10) & (t < 12.5)]):
        P = phone_motion(tt)
        P = Pose(P.rotation * Rotation.from_rotvec(rng.normal(size=(len(tt), 3)) * np.radians(0.3)), P.translation)
        he = estimate_hand_eye(tt, P, stamps, body, bootstrap=0)
        delta, R_X = he.time_offset_s, he.T_controller_mocap.rotation
        grid = np.round(np.arange(delta - 0.01, delta + 0.01 + 1e-9, 0.001), 6)
        sets = []
        for d in grid:
            _, _, a, b, tm = module._motions(tt, P, stamps, body, float(d), module.STEP_S, module.MIN_ANGLE_DEG,
                                             with_times=True)
            sets.append((a, b, np.floor((tm - tt[0]) / min(module.BLOCK_S, (tt[-1] - tt[0]) / 5)).astype(int)))
        n_blocks = max(int(s[2].max()) for s in sets) + 1
        angles, shifts = [], []
        for counts in module._bootstrap_counts(n_blocks, 12, seed=0):
            best = (np.inf, R_X, delta)
            for d, (a, b, blocks) in zip(grid, sets, strict=True):
                w = counts[blocks]
                R, _ = Rotation.align_vectors(a[w > 0], b[w > 0], weights=w[w > 0])
                cost = float(np.sum(w * np.sum((a - R.apply(b)) ** 2, axis=1)) / np.sum(w))
                if cost < best[0]:
                    best = (cost, R, float(d))
            angles.append(np.degrees((best[1].inv() * R_X).magnitude()))
            shifts.append(1e3 * (best[2] - delta))
        expected = (np.sqrt(np.mean(np.square(angles))), np.sqrt(np.mean(np.square(shifts))))
        got = module._uncertainty(tt, P, stamps, body, delta, R_X, module.STEP_S, module.MIN_ANGLE_DEG, n=12)
        assert expected[0] > 0.02 and expected[1] > 0.1           # a spread to compare, not zeros
        assert got == pytest.approx(expected, rel=1e-9, abs=1e-12)
