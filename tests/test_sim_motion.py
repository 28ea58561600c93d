"""`record sim --motion`: a recorded hand-held trajectory (TUM RGB-D freiburg1_xyz, fr2_desk) drives the task."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from phonepose.evaluation.trajectory import load_trajectory
from phonepose.record.sim import SimSession
from phonepose.record.sim.recorded import MotionSpec, load_window

DATA = Path(__file__).parent / "data" / "evo"
FR1 = str(DATA / "freiburg1_xyz-groundtruth.txt")
FR2 = str(DATA / "fr2_desk_groundtruth.txt")


def test_the_task_is_the_recorded_motion_moved_rigidly_into_the_workspace():
    spec = MotionSpec(FR1, start_s=2.0, duration_s=6.0)
    s = SimSession("exp2", "TRI1", 1, seed=0, motion=spec)   # --path is unused with a motion
    plan = s.plan
    assert plan.path == "motion:freiburg1_xyz-groundtruth" and plan.task_end - plan.task_start == pytest.approx(6.0, abs=0.02)
    rec = load_trajectory(FR1, "tum")
    t_rec = rec.stamps - rec.stamps[0]
    i, j = np.searchsorted(t_rec, [2.5, 7.0])
    # distances and turns between two recorded samples are the simulated controller's (a rigid placement)
    a, b = s.traj(np.array([plan.task_start + t_rec[i] - t_rec[np.searchsorted(t_rec, 2.0)],
                            plan.task_start + t_rec[j] - t_rec[np.searchsorted(t_rec, 2.0)]]))
    d_rec = np.linalg.norm(rec.poses.translation[j] - rec.poses.translation[i])
    assert np.linalg.norm(b.translation - a.translation) == pytest.approx(d_rec, abs=1e-9)
    turn_rec = (rec.poses.rotation[i].inv() * rec.poses.rotation[j]).magnitude()
    assert (a.rotation.inv() * b.rotation).magnitude() == pytest.approx(turn_rec, abs=1e-9)
    # the window's mean position is the workspace centre in front of the display camera
    task = s.traj(plan.task_start + load_window(spec).t)
    centre = s.world.T_world_camera.apply(np.array(spec.centre))
    np.testing.assert_allclose(task.translation.mean(axis=0), centre, atol=1e-9)
    assert s.in_view.any() and len(s.t_cam) > 100


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
def test_a_bad_motion_window_is_one_line_before_anything_is_written(tmp_path, args, needle):
    out = tmp_path / "s.mcap"
    r = subprocess.run([sys.executable, "-m", "phonepose", "record", "sim", "--out", str(out), "-q", *args],
                       capture_output=True, text=True)
    assert r.returncode == 5 and needle in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not out.exists()
