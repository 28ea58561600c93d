"""Fuzzing the trackers' step functions with hypothesis: random, NaN, inf and zero-norm poses.

Whatever the shared stages hand over (valid or broken poses, CM1 events with missing or
non-finite poses, markers without a display pose), every tracker T1-T7 in both correction
maths must either return None (no estimate this tick), return a finite pose with a unit
quaternion, or raise a PhoneposeError. Nothing else may come out, and nothing non-finite.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from phonepose.errors import PhoneposeError
from phonepose.geometry import Pose
from phonepose.pipeline.trackers import make_trackers
from phonepose.pipeline.types import MarkerObservation, Observation, Tick
from phonepose.playback.scheduler import calibration_event
from phonepose.schemas import phonepose_pb2 as pb
from phonepose.session.codec import encode_pose

FUZZ = settings(max_examples=int(os.environ.get("PHONEPOSE_FUZZ_EXAMPLES", "150")), deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow])

SPECIAL = st.sampled_from([math.nan, math.inf, -math.inf, 0.0, 1e300, -1e-300])
NUMBER = st.one_of(st.floats(-10, 10, allow_nan=False), SPECIAL)


@st.composite
def poses(draw):
    """A Pose that may be valid, or carry NaN/inf in its translation or rotation."""
    kind = draw(st.sampled_from(["valid", "valid", "bad-translation", "inf-rotation", "none"]))
    if kind == "none":
        return None
    q = np.array([draw(st.floats(-1, 1, allow_nan=False)) for _ in range(4)]) + np.array([0, 0, 0, 1.5])
    t = np.array([draw(st.floats(-5, 5, allow_nan=False)) for _ in range(3)])
    if kind == "bad-translation":
        t[draw(st.integers(0, 2))] = draw(SPECIAL)
    if kind == "inf-rotation":
        q[draw(st.integers(0, 3))] = math.inf     # scipy turns this into a NaN rotation
    return Pose(Rotation.from_quat(q), t)


@st.composite
def cm_events(draw):
    out = []
    for _ in range(draw(st.integers(0, 2))):
        ev = pb.CalibrationEvent(kind=draw(st.sampled_from([pb.CalibrationEvent.CM1, pb.CalibrationEvent.CM2])))
        for pose in (ev.pose_fix_vio, ev.pose_align_vio):
            if draw(st.booleans()):   # else left unset: all-zero quaternion
                pose.position.x, pose.position.y, pose.position.z = (draw(NUMBER) for _ in range(3))
                q = pose.orientation
                q.x, q.y, q.z, q.w = (draw(NUMBER) for _ in range(4))
        out.append(calibration_event(ev, 1))   # as the scheduler hands it on
    return out


@st.composite
def observations(draw, index: int):
    marker = None
    if draw(st.booleans()):
        marker = MarkerObservation(corners_px=np.zeros((4, 2)), T_camera_marker=Pose.identity(),
                                   T_dvio_controller=draw(poses()), reprojection_error_px=0.1,
                                   chosen_solution=0, ambiguity_ratio=2.0, id=7)
    t_ns = 1_000_000_000 + index * 50_000_000
    tick = Tick(index=index, t_ns=t_ns, events=draw(cm_events()))
    # VIO samples with capture stamps (T8): possibly bad poses, repeated or backwards stamps
    samples = [(t_ns - draw(st.sampled_from([0, 20_000_000, 120_000_000, -5_000_000, 10**12])), p)
               for p in draw(st.lists(poses(), max_size=3)) if p is not None]
    return Observation(tick=tick, marker=marker, T_dvio_controller_vio=draw(poses()), controller_vio_samples_dvio=samples)


def _finite_pose(p: Pose) -> bool:
    q = p.rotation.as_quat()
    return bool(np.isfinite(p.translation).all() and np.isfinite(q).all() and abs(np.linalg.norm(q) - 1) < 1e-6)


@FUZZ
@given(data=st.data(), math_kind=st.sampled_from(["paper", "se3"]))
def test_trackers_return_finite_poses_none_or_our_error(data, math_kind):
    trackers = make_trackers("all", math_kind)   # T1-T7 and ours (T8)
    assert [t.name for t in trackers][-1] == "T8"
    for t in trackers:
        t.reset()
    for i in range(data.draw(st.integers(1, 8))):
        obs = data.draw(observations(i))
        for t in trackers:
            try:
                est = t.step(obs)
            except PhoneposeError:
                continue
            assert est is None or _finite_pose(est), (t.name, est)


def test_a_bad_cm1_event_is_ignored_not_used():
    """T2 (CM1) keeps its previous offset when an event's poses are NaN or unset, and says so once."""
    (t2,) = make_trackers(["T2"])
    good = pb.CalibrationEvent(kind=pb.CalibrationEvent.CM1)
    encode_pose(Pose.from_xyzw([0.1, 0, 0], [0, 0, 0, 1]), good.pose_fix_vio)
    encode_pose(Pose.identity(), good.pose_align_vio)
    vio = Pose.from_xyzw([1.0, 2.0, 3.0], [0, 0, 0, 1])
    est = t2.step(Observation(Tick(index=0, t_ns=1, events=[calibration_event(good, 1)]), None, vio))
    assert np.allclose(est.translation, [1.1, 2.0, 3.0])
    bad = pb.CalibrationEvent(kind=pb.CalibrationEvent.CM1)
    bad.pose_fix_vio.position.x = math.nan
    unset = pb.CalibrationEvent(kind=pb.CalibrationEvent.CM1)
    events = [calibration_event(bad, 2), calibration_event(unset, 2)]
    assert [(e.pose_fix_vio, e.pose_align_vio) for e in events] == [(None, None), (None, None)]
    est = t2.step(Observation(Tick(index=1, t_ns=2, events=events), None, vio))
    assert np.allclose(est.translation, [1.1, 2.0, 3.0])   # the good offset stays


@pytest.mark.parametrize("bad", [np.array([np.nan, 0, 0]), np.array([0, np.inf, 0])])
def test_a_non_finite_input_pose_gives_no_estimate(bad):
    for t in make_trackers("all"):
        est = t.step(Observation(Tick(index=0, t_ns=1), None, Pose(Rotation.identity(), bad)))
        assert est is None, t.name
