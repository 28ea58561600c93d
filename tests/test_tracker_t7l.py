"""T7L (ours, T7 with a latency-aware CM3) on hand-built Observations with a known constant latency.

The controller moves at constant velocity; its VIO frame is off the truth by a rigid error
``T_err`` (true = T_err · VIO). VIO is captured every 20 ms and received ``LATENCY`` later; ticks
every 50 ms; the marker (= truth at the image time) is seen on ticks 0..9, then not.
"""

from __future__ import annotations

import numpy as np

from phonepose.geometry import Pose
from phonepose.pipeline.corrections import marker_correction
from phonepose.pipeline.t7l import LatencyAwareCM3Tracker
from phonepose.pipeline.trackers import PAPER_TRACKERS, make_tracker, make_trackers, tracker_names
from phonepose.pipeline.types import Frame, MarkerObservation, Observation, Tick

LATENCY_NS = 120_000_000
VIO_PERIOD_NS = 20_000_000
TICK_NS = 50_000_000
IN_VIEW_TICKS = 10
T8_WINDOW_NS = LatencyAwareCM3Tracker.velocity_window_ns
VELOCITY = np.array([0.4, -0.2, 0.1])                        # m/s
R0 = Pose.from_rotvec([0.1, -0.2, 0.3], [0.0, 0.0, 0.0]).rotation
T_ERR = Pose.from_rotvec([0.02, 0.05, -0.1], [0.03, -0.01, 0.02])


def vio_at(t_ns: int, stop_ns: int | None = None) -> Pose:
    """Controller VIO (in display_vio, before any correction) captured at ``t``."""
    t_ns = t_ns if stop_ns is None else min(t_ns, stop_ns)
    return Pose(R0, np.array([0.1, 0.2, 0.3]) + VELOCITY * (t_ns / 1e9))


def truth_at(t_ns: int, stop_ns: int | None = None) -> Pose:
    return T_ERR @ vio_at(t_ns, stop_ns)


def observations(n_ticks: int, cut_after: int | None = None, stop_ns: int | None = None) -> list[Observation]:
    """``cut_after``: VIO samples received after that tick are replaced by garbage (causality test);
    ``stop_ns``: constant velocity until then, then standing still."""
    captures = range(-10 * VIO_PERIOD_NS, n_ticks * TICK_NS, VIO_PERIOD_NS)
    out = []
    for i in range(n_ticks):
        t = i * TICK_NS
        received = [c for c in captures if (i - 1) * TICK_NS < c + LATENCY_NS <= t]
        garbage = cut_after is not None and i > cut_after
        samples = [(c, Pose(R0, np.array([9.0, 9.0, 9.0])) if garbage else vio_at(c, stop_ns)) for c in received]
        marker = None
        if i < IN_VIEW_TICKS:
            marker = MarkerObservation(corners_px=np.zeros((4, 2)), T_camera_marker=Pose.identity(),
                                       T_dvio_controller=truth_at(t, stop_ns), reprojection_error_px=0.1,
                                       chosen_solution=0, ambiguity_ratio=10.0, id=7)
        tick = Tick(index=i, t_ns=t, frame=Frame(b"", "jpeg", t, is_new=True))
        # what the scheduler gives T1-T7: VIO interpolated at t by receipt time = captured at t - latency
        out.append(Observation(tick=tick, marker=marker, T_dvio_controller_vio=vio_at(t - LATENCY_NS, stop_ns),
                               controller_vio_samples_dvio=samples))
    return out


def run(tracker, obs):
    tracker.reset()
    return [tracker.step(o) for o in obs]


def test_registry_paper_is_t1_t7_and_all_adds_ours():
    assert [t.name for t in make_trackers("paper")] == list(PAPER_TRACKERS)
    assert tracker_names() == list(PAPER_TRACKERS) + ["T7L", "T8"]
    assert [t.name for t in make_trackers("all")] == list(PAPER_TRACKERS) + ["T7L", "T8"]


def test_offset_is_the_frame_error_where_cm3_absorbs_speed_times_latency():
    obs = observations(IN_VIEW_TICKS)
    t8 = make_tracker("T7L")
    run(t8, obs)
    # the newest pairable observation: its image time is at most (tick - latency)
    assert t8.current.as_pose().allclose(T_ERR, atol=1e-9)
    # T7's offset (CM3, same se3 math) on the last sighting is off by R_err · v · latency
    last = obs[-1]
    cm3 = marker_correction(last.marker.T_dvio_controller, last.T_dvio_controller_vio, "se3")
    error = cm3.as_pose().translation - T_ERR.translation
    expected = T_ERR.rotation.apply(VELOCITY * LATENCY_NS / 1e9)
    np.testing.assert_allclose(error, expected, atol=1e-9)
    assert np.linalg.norm(expected) > 0.04


def test_outside_predicts_vio_to_the_tick_time():
    obs = observations(IN_VIEW_TICKS + 8)
    est = run(make_tracker("T7L"), obs)
    for i in range(IN_VIEW_TICKS):
        assert est[i].allclose(truth_at(i * TICK_NS), atol=1e-12)     # marker inside
    for i in range(IN_VIEW_TICKS, len(obs)):
        assert est[i].allclose(truth_at(i * TICK_NS), atol=1e-9)      # corrected + predicted outside


def test_after_a_stop_outside_t8_is_exact_where_t7_keeps_speed_times_latency():
    # Under constant velocity forever, T7's absorbed offset and its VIO lag cancel; once the phone
    # stops outside the view (the usual case), T7 is left with R_err · v · latency.
    stop = IN_VIEW_TICKS * TICK_NS
    obs = observations(IN_VIEW_TICKS + 12, stop_ns=stop)
    t8 = run(make_tracker("T7L"), obs)
    t7 = run(make_tracker("T7", "se3"), obs)
    settled = stop + LATENCY_NS + 2 * T8_WINDOW_NS        # the stop is visible in received VIO
    expected = np.linalg.norm(VELOCITY) * LATENCY_NS / 1e9
    for i in range(len(obs)):
        t = i * TICK_NS
        if t >= settled:
            assert t8[i].allclose(truth_at(t, stop), atol=1e-9)
            assert abs(float(t7[i].distance_to(truth_at(t, stop))) - expected) < 1e-9


def test_before_any_vio_pairing_the_offset_is_not_invented():
    obs = observations(2)           # the first VIO sample after image time 0 arrives at 120 ms
    t8 = make_tracker("T7L")
    run(t8, obs)
    assert t8.current is None


def test_causal_later_samples_never_change_earlier_estimates():
    n, cut = IN_VIEW_TICKS + 6, IN_VIEW_TICKS + 2
    clean = run(make_tracker("T7L"), observations(n))
    spoiled = run(make_tracker("T7L"), observations(n, cut_after=cut))
    for i in range(cut + 1):
        assert spoiled[i].allclose(clean[i], atol=0)
    assert not spoiled[-1].allclose(clean[-1], atol=1e-3)


def test_vio_samples_are_mapped_only_when_a_tracker_reads_them(tmp_path):
    """The shared stages map the stamped VIO samples for T8 only: a T1-T7 playback skips that work."""
    from phonepose.pipeline.shared import SharedStages
    from phonepose.playback.engine import run_playback
    from phonepose.testing.playback_session import write_test_session

    session = tmp_path / "s.mcap"
    write_test_session(session, duration_s=1.0)
    seen = {}
    for trackers in ("paper", "all"):
        made, counts = [], []

        def stages_factory(context, made=made, counts=counts):   # this pass's lists
            stages = SharedStages(context)
            process = stages.process
            stages.process = lambda tick: counts.append(len((obs := process(tick)).controller_vio_samples_dvio)) or obs
            made.append(stages)
            return stages

        run_playback(session, trackers=trackers, write_outputs=False, stages_factory=stages_factory)
        seen[trackers] = (made[0].map_vio_samples, sum(counts))
    assert seen["paper"] == (False, 0)
    assert seen["all"][0] is True and seen["all"][1] >= 25   # ~30 Hz VIO over 1 s reaches T8
