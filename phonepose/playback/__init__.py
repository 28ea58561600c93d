"""Playback: one streaming pass over a session, a tick every 1/rate s, every tracker per tick.

See docs/playback.md. ``run_playback`` is the entry point the CLI, experiments and demos use.
"""

from __future__ import annotations


def __getattr__(name: str):
    # lazy: importing phonepose.playback must not pull in OpenCV/Rerun
    if name in ("run_playback", "PlaybackResult", "TrackerTrajectory", "PlaybackEngine"):
        from phonepose.playback import engine

        return getattr(engine, name)
    raise AttributeError(name)


__all__ = ["run_playback", "PlaybackResult", "TrackerTrajectory", "PlaybackEngine"]
