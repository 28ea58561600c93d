"""``playback --check-live``: a session's live estimates (``record live -t``) against playback's, tick by tick.

The live trackers wrote ``/trackers/<name>/pose`` at every tick with a pose (log time = the tick) and their
figures as MCAP metadata (phonepose.record.live.tracking). Playback replays the session with the same trackers,
rate and correction math; over the grid ticks the live run formed (its first to last tick) each tick's estimate
must be the very same message: both absent, or the same serialized PoseInFrame.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass

from phonepose.errors import SessionContentError
from phonepose.pipeline.trackers import make_trackers
from phonepose.playback.engine import _check_camera_trackers, _ticks_ahead
from phonepose.playback.livereport import live_report
from phonepose.playback.scheduler import TickScheduler
from phonepose.schemas.topics import Frame, tracker_pose_topic
from phonepose.session import SessionReader
from phonepose.session.codec import pose_in_frame
from phonepose.session.context import read_context


@dataclass
class LiveCheck:
    tracker: str
    compared: int       # grid ticks from the live run's first to its last
    identical: int
    different: int
    first_difference_ns: int | None = None


def check_live(session: str | os.PathLike) -> list[LiveCheck]:
    """Every live tracker's estimates against playback's (the module docstring)."""
    session = os.fspath(session)
    report = live_report(session)
    if report is None:
        raise SessionContentError(f"{session}: no live tracking in this session (record it with "
                                  "`record live -t TRACKER`)")
    names = list(report["trackers"])
    first, last = report["first_tick_ns"], report["last_tick_ns"]
    trackers = make_trackers(names, report["correction_math"])
    with contextlib.ExitStack() as stack:
        reader = stack.enter_context(SessionReader(session))
        live: dict[str, dict[int, bytes]] = {}
        for name in names:
            live[name] = {m.log_time: bytes(m.data)
                          for _s, _c, m in reader.raw_messages([tracker_pose_topic(name)])}
        checks = {name: LiveCheck(name, 0, 0, 0) for name in names}
        if first is None or last is None:
            return list(checks.values())
        context = read_context(reader)
        _check_camera_trackers(session, context, trackers)
        from phonepose.pipeline.shared import SharedStages

        stages = SharedStages(context)
        stack.callback(stages.close)
        stages.map_vio_samples = any(t.uses_vio_samples for t in trackers)
        for t in trackers:
            t.reset()
        scheduler = TickScheduler(reader, context, rate_hz=report["rate_hz"])
        for tick, _gt in _ticks_ahead(scheduler.with_truth(), stages):
            if tick.t_ns > last:
                break
            obs = stages.process(tick)
            for tr in trackers:
                pose = tr.step(obs)
                if tick.t_ns < first:
                    continue
                c = checks[tr.name]
                mine = None if pose is None else pose_in_frame(pose, Frame.DISPLAY_VIO, tick.t_ns).SerializeToString()
                c.compared += 1
                if mine == live[tr.name].get(tick.t_ns):
                    c.identical += 1
                else:
                    c.different += 1
                    if c.first_difference_ns is None:
                        c.first_difference_ns = tick.t_ns
    return list(checks.values())
