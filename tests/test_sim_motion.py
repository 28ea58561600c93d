"""`record sim --motion`: a recorded hand-held trajectory (TUM RGB-D freiburg1_xyz, fr2_desk) drives the task."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from phonepose.evaluation.trajectory import load_trajectory
from phonepose.geometry import Pose
from phonepose.record.sim import SimSession
from phonepose.record.sim.recorded import CUTOFF_HZ, MotionSpec, load_window, low_passed

DATA = Path(__file__).parent / "data" / "evo"
FR1 = str(DATA / "freiburg1_xyz-groundtruth.txt")
FR2 = str(DATA / "fr2_desk_groundtruth.txt")


def test_the_task_is_the_recorded_motion_moved_rigidly_into_the_workspace():
    spec = MotionSpec(FR1, start_s=2.0, duration_s=6.0)
    s = SimSession("exp2", "TRI1", 1, seed=0, motion=spec)   # --path is unused with a motion
    plan = s.plan
    assert plan.path == "motion:freiburg1_xyz-groundtruth" and plan.task_end - plan.task_start == pytest.approx(6.0, abs=0.02)
    window = load_window(spec)
    i, j = np.searchsorted(window.t, [0.5, 5.0])
    # distances and turns between two samples of the (low-passed) window are the simulated controller's:
    # a rigid placement
    a, b = s.traj(plan.task_start + window.t[[i, j]])
    d_rec = np.linalg.norm(window.poses.translation[j] - window.poses.translation[i])
    assert np.linalg.norm(b.translation - a.translation) == pytest.approx(d_rec, abs=1e-9)
    turn_rec = (window.poses.rotation[i].inv() * window.poses.rotation[j]).magnitude()
    assert (a.rotation.inv() * b.rotation).magnitude() == pytest.approx(turn_rec, abs=1e-9)
    # and the window is the recording itself below the cutoff: within 1 mm and 0.2 deg of its samples
    rec = load_trajectory(FR1, "tum")
    t_rec = rec.stamps - rec.stamps[0]
    k = np.searchsorted(t_rec, 2.0 + window.t[[i, j]])
    k0 = np.searchsorted(t_rec, 2.0)
    d_file = np.linalg.norm(rec.poses.translation[k[1]] - rec.poses.translation[k[0]])
    assert abs(d_file - d_rec) < 1e-3
    turn_file = (rec.poses.rotation[k[0]].inv() * rec.poses.rotation[k[1]]).magnitude()
    assert abs(np.degrees(turn_file - turn_rec)) < 0.2
    assert t_rec[k0] == pytest.approx(2.0, abs=0.01)
    # the window's mean position is the workspace centre in front of the display camera
    task = s.traj(plan.task_start + load_window(spec).t)
    centre = s.world.T_world_camera.apply(np.array(spec.centre))
    np.testing.assert_allclose(task.translation.mean(axis=0), centre, atol=1e-9)
    assert s.in_view.any() and len(s.t_cam) > 100


def test_the_recording_is_low_passed_above_a_hands_band():
    """A 1 Hz swing and turn with 60 Hz jitter on top, sampled at 300 Hz (fr2_desk's rate): the swing stays
    to 1e-4 m and 0.01 deg away from the window's ends, the jitter falls by the filter's -75 dB."""
    t = np.arange(0.0, 10.0, 1 / 300)
    swing, wobble = 0.1 * np.sin(2 * np.pi * t), np.radians(20.0) * np.sin(2 * np.pi * t)
    jitter = np.sin(2 * np.pi * 60.0 * t)
    poses = Pose(Rotation.from_rotvec(np.column_stack([wobble + np.radians(0.1) * jitter, 0 * t, 0 * t])),
                 np.column_stack([swing + 0.001 * jitter, 0 * t, 0 * t]))
    grid, smooth = low_passed(t, poses, CUTOFF_HZ)
    np.testing.assert_allclose(grid, t, atol=1e-9)
    middle = (t > 1.0) & (t < 9.0)                           # the filter's start-up and run-out left aside
    assert np.abs(smooth.translation[middle, 0] - swing[middle]).max() < 1e-4
    angle = smooth.rotation.as_rotvec()[:, 0]
    assert np.degrees(np.abs(angle[middle] - wobble[middle]).max()) < 0.01
    before = np.abs(poses.translation[middle, 0] - swing[middle]).max()
    assert np.abs(smooth.translation[middle, 0] - swing[middle]).max() < before * 10 ** (-60 / 20)


def test_a_recording_at_twice_the_cutoff_or_slower_is_only_resampled():
    """25 Hz (nothing above the 15 Hz cutoff to remove), and a window too short to filter: the samples as given."""
    for rate, n in ((25.0, 250), (300.0, 12)):
        t = np.arange(n) / rate
        poses = Pose(Rotation.from_rotvec(np.column_stack([0.3 * np.sin(t), 0 * t, 0 * t])), np.column_stack([t, t, t]))
        grid, out = low_passed(t, poses, CUTOFF_HZ)
        np.testing.assert_allclose(grid, t, atol=1e-9)
        np.testing.assert_allclose(out.translation, poses.translation, atol=1e-9)
        assert np.degrees((out.rotation.inv() * poses.rotation).magnitude()).max() < 1e-6


def test_the_simulated_accelerometer_follows_the_recorded_path_between_its_samples():
    """A C2 path between the window's samples: the true acceleration is continuous (piecewise-linear
    positions gave 0 between samples and spikes at them)."""
    from phonepose.record.sim.imu import true_imu

    s = SimSession("exp2", "TRI1", 1, seed=0, motion=MotionSpec(FR1, start_s=2.0, duration_s=6.0))
    t = s.plan.task_start + 1.0 + np.arange(0.0, 2.0, 0.001)
    _, accel = true_imu(s.traj, t)
    jumps = np.linalg.norm(np.diff(accel, axis=0), axis=1)
    assert jumps.max() < 0.5, jumps.max()                      # m/s^2 per ms: no spikes
    assert np.linalg.norm(accel, axis=1).min() > 5.0          # gravity is in it throughout


def test_motion_scale_shrinks_the_displacements():
    w = load_window(MotionSpec(FR2, start_s=50.0, duration_s=20.0, scale=0.3))   # fr2_desk's duplicate stamp is dropped
    assert np.all(np.diff(w.t) > 0) and w.t[-1] == pytest.approx(20.0, abs=0.05)
    w1, w2 = load_window(MotionSpec(FR1, duration_s=5.0)), load_window(MotionSpec(FR1, duration_s=5.0, scale=0.5))
    np.testing.assert_allclose(w2.poses.translation, 0.5 * w1.poses.translation, atol=1e-15)


@pytest.mark.parametrize("args, needle", [
    (["--motion", FR2, "--motion-start", "25"], "gap in the window"),           # fr2_desk's 12 s gap at 31.7 s
    (["--motion", FR1, "--motion-start", "25"], "is not inside the file's"),
    (["--motion", FR1, "--motion-centre", "0,0"], "--motion-centre"),
])
def test_a_bad_motion_window_is_one_line_before_anything_is_written(tmp_path, args, needle, cli):
    out = tmp_path / "s.mcap"
    r = cli("record", "sim", "--out", str(out), "-q", *args)
    assert r.returncode == 5 and needle in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not out.exists()
