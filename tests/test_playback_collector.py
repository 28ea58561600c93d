"""TrajectoryCollector: what a playback keeps per tick, spilled to a temporary file in blocks, read back bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from phonepose.geometry import Pose
from phonepose.playback import collector
from phonepose.playback.collector import Trajectories, TrajectoryCollector


@pytest.mark.parametrize("ticks", [0, 1, 9, 10, 28, 30])
def test_round_trip_across_spills(monkeypatch, ticks):
    monkeypatch.setattr(collector, "BLOCK_TICKS", 7)   # 28 ticks: 21 poses, three full blocks in the file
    rng = np.random.default_rng(ticks)
    c = TrajectoryCollector()
    kept = []
    for k in range(ticks):
        pose = None if k % 4 == 3 else Pose.from_rotvec(rng.normal(size=3), rng.normal(size=3))
        c.add(1_000 * k, pose, k % 2 == 1)
        if pose is not None:
            kept.append((1_000 * k, pose, k % 2 == 1))
    got = c.trajectory("T")
    assert got.ticks_without_pose == c.none == ticks // 4
    assert len(c) == len(got.stamps_ns) == len(kept)
    assert got.stamps_ns.dtype == np.int64 and got.inside.dtype == bool
    assert got.stamps_ns.tolist() == [t for t, _p, _i in kept]
    assert got.inside.tolist() == [i for _t, _p, i in kept]
    if not kept:
        assert got.poses is None and c.poses() is None
        return
    # the same float64 bits as the stack built from the poses in memory
    expected = Pose.from_xyzw(np.array([p.translation for _t, p, _i in kept]),
                              np.array([p.quat_xyzw for _t, p, _i in kept]))
    assert got.poses.translation.tobytes() == expected.translation.tobytes()
    assert got.poses.quat_xyzw.tobytes() == expected.quat_xyzw.tobytes()
    assert c.stamps().tobytes() == got.stamps_ns.tobytes() and c.inside().tolist() == got.inside.tolist()
    c.close()


def test_trajectories_read_each_on_lookup():
    a, b = TrajectoryCollector(), TrajectoryCollector()
    a.add(5, Pose.identity(), True)
    trajs = Trajectories({"A": a, "B": b})
    assert list(trajs) == ["A", "B"] and len(trajs) == 2
    assert trajs["A"].stamps_ns.tolist() == [5] and trajs["B"].poses is None
    assert trajs["A"] is not trajs["A"]        # read again at every lookup: nothing is held
