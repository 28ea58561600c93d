"""T1-T7 on hand-built Observations: each switches method at the FoV boundary as Table 1 says."""

from __future__ import annotations

import numpy as np
import pytest

from phonepose.errors import ConfigError
from phonepose.geometry import Pose
from phonepose.pipeline.corrections import cm1_correction, marker_correction
from phonepose.pipeline.trackers import TRACKERS, CorrectionKind, Method, make_tracker, make_trackers, tracker_names
from phonepose.pipeline.types import CalibrationEvent, CalibrationKind, MarkerObservation, Observation, Tick

rng = np.random.default_rng(7)


def random_pose() -> Pose:
    return Pose.from_rotvec(rng.uniform(-0.5, 0.5, 3), rng.uniform(-1, 1, 3))


def cm1_event(fix: Pose, align: Pose) -> CalibrationEvent:
    return CalibrationEvent(kind=CalibrationKind.CM1, t_ns=0, log_time_ns=0, pose_fix_vio=fix, pose_align_vio=align)


CM2_EVENT = CalibrationEvent(kind=CalibrationKind.CM2, t_ns=0, log_time_ns=0)


def observation(i: int, vio: Pose | None, marker: Pose | None, events=()) -> Observation:
    m = None
    if marker is not None:
        m = MarkerObservation(corners_px=np.zeros((4, 2)), T_camera_marker=Pose.identity(), T_dvio_controller=marker,
                              reprojection_error_px=0.1, chosen_solution=0, ambiguity_ratio=10.0, id=7)
    return Observation(tick=Tick(index=i, t_ns=i * 50_000_000, events=list(events)), marker=m,
                       T_dvio_controller_vio=vio)


def test_registry_is_table_1():
    assert tracker_names()[:7] == ["T1", "T2", "T3", "T4", "T5", "T6", "T7"]
    rows = {n: (TRACKERS[n].inside, TRACKERS[n].outside, TRACKERS[n].correction) for n in tracker_names()[:7]}
    V, M, C = Method.VIO, Method.MARKER, CorrectionKind
    assert rows == {"T1": (V, V, C.NONE), "T2": (V, V, C.CM1), "T3": (V, V, C.CM2), "T4": (M, V, C.NONE),
                    "T5": (M, V, C.CM1), "T6": (M, V, C.CM2), "T7": (M, V, C.CM3)}


def test_make_trackers_names_and_errors():
    assert [t.name for t in make_trackers("all")] == tracker_names()
    assert [t.name for t in make_trackers(["T7", "T1"])] == ["T7", "T1"]
    assert [t.name for t in make_trackers("T2, t3")] == ["T2", "T3"]
    with pytest.raises(ConfigError, match="T1, T2, T3, T4, T5, T6, T7"):
        make_trackers(["T1", "T9"])
    with pytest.raises(ConfigError, match="paper, se3"):
        make_tracker("T1", correction_math="euler")


@pytest.mark.parametrize("math", ["paper", "se3"])
def test_each_tracker_switches_at_the_fov_boundary(math):
    V = [random_pose() for _ in range(8)]
    M = {k: random_pose() for k in (2, 3, 6)}
    fix, align = random_pose(), random_pose()
    ticks = [
        observation(0, V[0], None),                                  # out, nothing calibrated yet
        observation(1, V[1], None, [cm1_event(fix, align)]),         # out, CM1 alignment arrives
        observation(2, V[2], M[2], [CM2_EVENT]),  # in, CM2 moment
        observation(3, V[3], M[3]),                                  # in
        observation(4, V[4], None),                                  # out: the boundary
        observation(5, None, None),                                  # out, no VIO
        observation(6, None, M[6]),                                  # in, no VIO
        observation(7, V[7], None),                                  # out again
    ]
    cm1 = cm1_correction(fix, align, math)
    cm2 = marker_correction(M[2], V[2], math)
    cm3_at = {4: marker_correction(M[3], V[3], math), 7: marker_correction(M[3], V[3], math)}
    # T7's offset was last renewed at tick 3: tick 6 has a marker but no VIO to pair it with

    def expected(name, k):
        vio, marker = ticks[k].T_dvio_controller_vio, ticks[k].marker
        if name in ("T4", "T5", "T6", "T7") and marker is not None:
            return marker.T_dvio_controller
        if vio is None:
            return None
        if name == "T1" or name == "T4":
            return vio
        if name in ("T2", "T5"):
            return vio if k < 1 else cm1.apply(vio)
        if name in ("T3", "T6"):
            return vio if k < 2 else cm2.apply(vio)
        return vio if k < 3 else cm3_at[k].apply(vio)  # T7 before its first sighting: uncorrected

    trackers = make_trackers("all", math)
    for k, obs in enumerate(ticks):
        for t in trackers[:7]:
            got, want = t.step(obs), expected(t.name, k)
            if want is None:
                assert got is None, (t.name, k)
            else:
                assert got is not None and got.allclose(want, atol=1e-9), (t.name, k)
    # the switch is real: at tick 3 (in) T7 reports the marker, at tick 4 (out) VIO + CM3,
    # which lands where the marker was relative to VIO at the last sighting
    t7 = make_tracker("T7", math)
    outs = [t7.step(o) for o in ticks[:5]]
    assert outs[3].allclose(M[3]) and not outs[4].allclose(V[4], atol=1e-3)


def test_cm2_waits_for_the_marker_after_its_event():
    V = [random_pose() for _ in range(4)]
    M3 = random_pose()
    t3 = make_tracker("T3")
    assert t3.step(observation(0, V[0], None, [CM2_EVENT])).allclose(V[0])
    assert t3.step(observation(1, V[1], None)).allclose(V[1])          # still pending: no marker yet
    assert t3.step(observation(2, V[2], M3)).allclose(M3, atol=1e-9)   # captured here
    assert t3.step(observation(3, V[3], None)).allclose(marker_correction(M3, V[2]).apply(V[3]), atol=1e-9)


def test_t6_ignores_sightings_without_a_cm2_event():
    V0, V1, M0 = random_pose(), random_pose(), random_pose()
    t6 = make_tracker("T6")
    assert t6.step(observation(0, V0, M0)).allclose(M0)
    assert t6.step(observation(1, V1, None)).allclose(V1)  # no CM2 moment yet: uncorrected VIO


def test_reset_forgets_corrections():
    V0, V1, M0 = random_pose(), random_pose(), random_pose()
    t7 = make_tracker("T7")
    t7.step(observation(0, V0, M0))
    assert not t7.step(observation(1, V1, None)).allclose(V1, atol=1e-6)
    t7.reset()
    assert t7.step(observation(1, V1, None)).allclose(V1)


def test_cm1_literal_reading_is_selectable():
    fix, align, now = random_pose(), random_pose(), random_pose()
    literal = make_tracker("T2", cm1_reading="paper-literal")
    literal.step(observation(0, now, None, [cm1_event(fix, align)]))
    out = literal.step(observation(1, align, None))
    np.testing.assert_allclose(out.translation, 2 * align.translation - fix.translation, atol=1e-9)



def test_paper_keyword_and_registering_our_own():
    from phonepose.pipeline.trackers import CompositeTracker, TrackerSpec, register

    assert [t.name for t in make_trackers("paper")] == ["T1", "T2", "T3", "T4", "T5", "T6", "T7"]
    spec = TrackerSpec("X9", Method.MARKER, Method.MARKER, CorrectionKind.NONE, "test only",
                       factory=lambda spec, math, reading: CompositeTracker(spec, math, reading))
    register(spec)
    try:
        assert tracker_names()[-1] == "X9" and make_trackers("all")[-1].name == "X9"
        assert [t.name for t in make_trackers("paper")][-1] == "T7"
        with pytest.raises(ValueError):
            register(spec)
    finally:
        TRACKERS.pop("X9")
