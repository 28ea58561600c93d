"""Typed results of the Python API: a playback's metrics per tracker and scope, and an evaluation's statistics.

Each type is built from the document the CLI writes (``metrics.json``, ``evaluate --json``) and gives it back
with ``to_json()``: the typed fields are the document's values, so the two never disagree. ``to_table()`` is a
pyarrow Table (imported when called).
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from phonepose.evaluation.metrics import METRICS, SCOPES, keys
from phonepose.evaluation.trajectory import Trajectory

if TYPE_CHECKING:
    import pyarrow as pa

    from phonepose.playback.collector import TrackerTrajectory


@dataclass(frozen=True)
class ScopeMetrics:
    """One tracker's accuracy inside or outside the camera's view (docs/evaluation.md); None: not computable."""

    frames: int                       # ticks with both a pose and ground truth
    p_ate_m: float | None             # position ATE RMSE, m
    r_ate_deg: float | None           # rotation ATE RMSE, deg
    p_re_m: float | None              # position relative error, m


@dataclass(frozen=True)
class TotalMetrics(ScopeMetrics):
    """The whole task window: the scopes' metrics plus the boundary jump and the AR-controller metrics."""

    boundary_jumps: int = 0                     # ticks where the marker enters or leaves the view
    boundary_jump_max_m: float | None = None
    boundary_jump_rms_m: float | None = None
    lag_s: float | None = None                  # phonepose.evaluation.controller
    lag_resolution_s: float | None = None
    jitter_m: float | None = None
    jitter_deg: float | None = None
    still_ticks: int = 0
    availability: float | None = None           # share of the task window's ticks with a pose


@dataclass(frozen=True)
class TrackerMetrics:
    """A tracker's metrics in the three scopes: ``metrics.json``'s ``trackers[name]``, typed."""

    name: str
    inside: ScopeMetrics
    outside: ScopeMetrics
    total: TotalMetrics

    @classmethod
    def from_json(cls, name: str, doc: Mapping[str, Mapping[str, Any]]) -> TrackerMetrics:
        """From a normalised result (phonepose.evaluation.metrics.normalise): every scope, every key."""
        return cls(name, ScopeMetrics(**doc["inside"]), ScopeMetrics(**doc["outside"]), TotalMetrics(**doc["total"]))

    def scope(self, scope: str) -> ScopeMetrics:
        if scope not in SCOPES:
            from phonepose.errors import ConfigError
            raise ConfigError(f"scope {scope!r}: expected one of {', '.join(SCOPES)}")
        return getattr(self, scope)

    def to_json(self) -> dict:
        """``{"inside"|"outside"|"total": {key: value}}`` in metrics.json's key order."""
        return {scope: {k: getattr(self.scope(scope), k) for k in keys(scope)} for scope in SCOPES}


@dataclass(frozen=True)
class TrackerRun(TrackerMetrics):
    """A tracker of a playback: its metrics and its trajectory over the task window (display_vio)."""

    _trajectories: Mapping[str, TrackerTrajectory] | None = field(default=None, repr=False, compare=False)

    def _read(self) -> TrackerTrajectory | None:
        return None if self._trajectories is None else self._trajectories[self.name]

    @property
    def trajectory(self) -> Trajectory | None:
        """The ticks where the tracker had a pose (stamps in s, as ``trajectories/<name>.tum``); None: no pose."""
        traj = self._read()
        if traj is None or traj.poses is None:
            return None
        return Trajectory(traj.stamps_ns / 1e9, traj.poses, self.name)

    @property
    def stamps_ns(self) -> np.ndarray:
        traj = self._read()
        return np.zeros(0, np.int64) if traj is None else traj.stamps_ns

    @property
    def in_view(self) -> np.ndarray:
        """At :attr:`stamps_ns`: whether the marker was recognised."""
        traj = self._read()
        return np.zeros(0, bool) if traj is None else traj.inside


def _metric_columns() -> list[tuple[str, type]]:
    return [(m.key, m.kind) for m in METRICS]


def metrics_table(session: str, trackers: Mapping[str, TrackerMetrics]) -> pa.Table:
    """One row per tracker and scope; a metric a scope does not have (the total's only) is null there."""
    import pyarrow as pa

    rows: dict[str, list] = {"session": [], "tracker": [], "scope": []}
    rows.update({key: [] for key, _ in _metric_columns()})
    for name, m in trackers.items():
        for scope in SCOPES:
            values = m.scope(scope)
            rows["session"].append(session)
            rows["tracker"].append(name)
            rows["scope"].append(scope)
            for key, _ in _metric_columns():
                rows[key].append(getattr(values, key, None))
    schema = pa.schema([("session", pa.string()), ("tracker", pa.string()), ("scope", pa.string())]
                       + [(key, pa.int64() if kind is int else pa.float64()) for key, kind in _metric_columns()])
    return pa.table(rows, schema=schema)


@dataclass(frozen=True)
class PlaybackRun:
    """What :func:`phonepose.play` returns: every tracker's metrics and trajectory, and the ground truth."""

    session: str                              # the session's file name (metrics.json's "session")
    rate_hz: float
    trackers: Mapping[str, TrackerRun]        # in the order they were played
    ground_truth_note: dict | None            # metrics.json's "ground_truth" (a --gt-calibration), else None
    ground_truth: Trajectory | None           # the GT at the task window's ticks (display_vio), None without GT
    n_ticks: int
    n_task_ticks: int
    frames_decoded: int
    out: Path | None = None                   # the output folder (None: played in memory)
    rerun: Path | None = None
    wall_s: float = 0.0
    files: Mapping[str, str] = field(default_factory=dict)

    @property
    def has_gt(self) -> bool:
        return self.ground_truth is not None and len(self.ground_truth) > 0

    def __getitem__(self, name: str) -> TrackerRun:
        try:
            return self.trackers[name]
        except KeyError:
            from phonepose.errors import ConfigError
            raise ConfigError(f"no tracker {name!r} in this playback; it played {', '.join(self.trackers)}") from None

    def __iter__(self) -> Iterator[TrackerRun]:
        return iter(self.trackers.values())

    def __len__(self) -> int:
        return len(self.trackers)

    def to_json(self) -> dict:
        """The ``metrics.json`` document ``phonepose playback`` writes for the same run (its ``json.dumps(...,
        indent=2, allow_nan=False)`` plus a newline is the file, byte for byte)."""
        from phonepose.playback.outputs import metrics_document

        return metrics_document(self.session, self.rate_hz, {n: t.to_json() for n, t in self.trackers.items()},
                                ground_truth=copy.deepcopy(self.ground_truth_note))

    def to_table(self) -> pa.Table:
        """A pyarrow Table: one row per tracker and scope (inside, outside, total), a column per metric."""
        return metrics_table(self.session, self.trackers)


# ----------------------------------------------------------------------------- evaluation
@dataclass(frozen=True)
class Stats:
    """An error's statistics (phonepose.evaluation.stats.statistics); None where there are no samples."""

    rmse: float | None
    mean: float | None
    median: float | None
    std: float | None
    min: float | None
    max: float | None
    num_samples: int


_STAT_FIELDS = tuple(f.name for f in dataclasses.fields(Stats))


def _stats_in(doc: Mapping[str, Any], where: str = "") -> Iterator[tuple[str, Stats]]:
    """Every statistics block of an evaluation document, by its dotted key path (``ate.trans_m``)."""
    if all(k in doc for k in _STAT_FIELDS):
        yield where, Stats(**{k: doc[k] for k in _STAT_FIELDS})
        return
    for key, value in doc.items():
        if isinstance(value, Mapping) and key != "align":
            yield from _stats_in(value, f"{where}.{key}" if where else str(key))


@dataclass(frozen=True)
class Evaluation:
    """What :func:`phonepose.evaluate` returns for rpg, ape or rpe: the ``evaluate --json`` document, typed."""

    metric: str                               # rpg | ape | rpe
    n_matched: int                            # associated pose pairs
    alignment: Mapping[str, Any]              # method, num_frames, scale, rotation, translation
    stats: Mapping[str, Stats]                # "ate.trans_m", "re.<L>.rot_deg", "ape", "rpe", ...
    _document: Mapping[str, Any] = field(repr=False, compare=False, default_factory=dict)

    @classmethod
    def from_json(cls, metric: str, doc: Mapping[str, Any]) -> Evaluation:
        return cls(metric, int(doc["n_matched"]), dict(doc["align"]), dict(_stats_in(doc)), copy.deepcopy(dict(doc)))

    def __getitem__(self, key: str) -> Stats:
        return self.stats[key]

    def to_json(self) -> dict:
        """The document ``phonepose evaluate --json`` prints for the same inputs and options."""
        return copy.deepcopy(dict(self._document))

    def to_table(self) -> pa.Table:
        """A pyarrow Table: one row per statistics block (``error`` is its key path), a column per statistic."""
        import pyarrow as pa

        rows = {"error": list(self.stats)}
        rows.update({k: [getattr(s, k) for s in self.stats.values()] for k in _STAT_FIELDS})
        schema = pa.schema([("error", pa.string())] + [(k, pa.int64() if k == "num_samples" else pa.float64())
                                                       for k in _STAT_FIELDS])
        return pa.table(rows, schema=schema)
