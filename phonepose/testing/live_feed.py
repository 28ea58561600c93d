"""A recorded session fed to the live trackers as a live recording would feed them, fast (tests).

Every stream's messages keep their order; each arrives ``delay`` after its log time (a delay drawn per message,
kept monotone on its stream), so the streams interleave by arrival instead of log time. The live trackers
(phonepose.record.live.tracking, the code ``record live -t`` runs) see the records in that order; the session is
written again with their estimates and figures, ready for ``playback --check-live``.
A fixture: production code never imports phonepose.testing (tests/test_imports.py).
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np

from phonepose.pipeline.trackers import make_trackers
from phonepose.playback.livereport import METADATA_NAME
from phonepose.record.live.tracking import LiveTracker
from phonepose.record.source import Record
from phonepose.session import SessionReader, SessionWriter
from phonepose.session.context import STATIC_TOPICS


def arrival_order(records: list[Record], max_delay_ns: dict[str, int], seed: int,
                  stream_of: Callable[[str], str] = lambda topic: topic) -> list[Record]:
    """``records`` (log-time order) in an arrival order: per stream in order, each late by up to its max delay."""
    rng = np.random.default_rng(seed)
    last: dict[str, int] = {}
    keyed = []
    for i, r in enumerate(records):
        key = stream_of(r.topic)
        arrive = r.log_time_ns + int(rng.integers(0, max_delay_ns.get(key, 0) + 1))
        arrive = max(arrive, last.get(key, arrive))     # a stream delivers in order
        last[key] = arrive
        keyed.append((arrive, i, r))
    keyed.sort(key=lambda k: (k[0], k[1]))
    return [r for _, _, r in keyed]


def replay_live(source: str | os.PathLike, out: str | os.PathLike, trackers: list, *, seed: int = 0,
                max_delay_ns: dict[str, int] | None = None, rate_hz: float = 20.0, **kwargs) -> LiveTracker:
    """Feed ``source`` to live ``trackers`` (names or tracker objects) in a generated arrival order; write it with
    their estimates to ``out``."""
    with SessionReader(source) as reader:
        msgs = [Record(m.topic, m.msg, m.log_time_ns, m.publish_time_ns) for m in reader.messages()]
    static = [r for r in msgs if r.topic in STATIC_TOPICS]
    data = [r for r in msgs if r.topic not in STATIC_TOPICS]
    published: list[Record] = []
    warnings: list[str] = []
    objs = make_trackers(trackers) if all(isinstance(t, str) for t in trackers) else trackers
    tracker = LiveTracker(objs, publish=published.append, now_ns=lambda: 0,
                          warn=warnings.append, rate_hz=rate_hz, **kwargs)
    tracker.warnings = warnings   # type: ignore[attr-defined]
    for r in static:
        tracker.handle(r)
    for r in arrival_order(data, max_delay_ns or {}, seed, tracker.merger.stream_of):
        tracker.handle(r)
    tracker.end()
    everything = sorted(msgs + published, key=lambda r: r.log_time_ns)
    with SessionWriter(out) as writer:
        for r in everything:
            writer.write(r.topic, r.message, r.log_time_ns, r.publish_time_ns)
        writer.add_metadata(METADATA_NAME, tracker.metadata())
    return tracker
