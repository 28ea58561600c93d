"""Where a session's ground truth comes from: its own ``/gt/controller/pose`` topic, or a trajectory
file from any motion-capture system (``--gt FILE``, TUM or EuRoC csv, read by evaluate's readers).

Either way the result is one :class:`GroundTruthSeries`: ascending, unique stamps (seconds, on the
ground truth's own clock: the session's log time for the topic, the file's stamps for a file) and
the tracked body's poses ``T_world_grip`` in the ground truth's own world. ``calibrate-gt`` ties
that clock and world to the recording; playback associates the series tick by tick.

A file is a sidecar: the recording is never rewritten (docs/recording-real-sessions.md).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np

from phonepose.errors import ConfigError, SessionContentError
from phonepose.geometry import Pose, RawPose

GT_FORMATS = ("tum", "euroc")


@dataclass(frozen=True)
class GroundTruthSeries:
    stamps_s: np.ndarray      # (N,) ascending, unique; the ground truth's clock
    poses: Pose               # N poses T_world_grip
    source: str               # "/gt/controller/pose" or the file's path
    duplicates: int = 0       # samples dropped because their stamp repeated an earlier one

    def __len__(self) -> int:
        return len(self.stamps_s)

    @property
    def is_file(self) -> bool:
        return not self.source.startswith("/")

    def raw_samples(self) -> tuple[np.ndarray, list[RawPose]]:
        """(stamps in ns, raw poses): what the playback scheduler streams."""
        q = self.poses.rotation.as_quat(canonical=False)
        t = np.atleast_2d(self.poses.translation)
        raws = [tuple(float(v) for v in (*q[k], *t[k])) for k in range(len(q))]
        return np.rint(self.stamps_s * 1e9).astype(np.int64), cast(list[RawPose], raws)   # 7 floats each: q then t


def unique_ascending(stamps: np.ndarray, poses: Pose, source: str) -> GroundTruthSeries:
    """Sorted by stamp; of samples with the same stamp (duplicated messages) the first is kept."""
    stamps = np.asarray(stamps, dtype=float)
    order = np.argsort(stamps, kind="stable")
    stamps = stamps[order]
    keep = np.ones(len(stamps), dtype=bool)
    keep[1:] = np.diff(stamps) > 0
    idx = order[keep]
    return GroundTruthSeries(stamps[keep], poses[idx], source, duplicates=int(np.count_nonzero(~keep)))


def gt_format_of(path: str | os.PathLike, fmt: str | None = None) -> str:
    """The file's format: as given, else EuRoC for ``.csv`` and TUM for anything else."""
    if fmt is None:
        return "euroc" if Path(path).suffix.lower() == ".csv" else "tum"
    if fmt not in GT_FORMATS:
        raise ConfigError(f"{{gt_format}} {fmt!r}: expected one of {', '.join(GT_FORMATS)}", parameter="gt_format",
                          value=fmt, expected=f"one of {', '.join(GT_FORMATS)}")
    return fmt


def file_ground_truth(path: str | os.PathLike, fmt: str | None = None) -> GroundTruthSeries:
    """A TUM or EuRoC trajectory file as ground truth (evaluate's readers: one line per bad file)."""
    from phonepose.evaluation.trajectory import load_trajectory
    from phonepose.files import check_input

    check_input(path, "ground-truth file")
    traj = load_trajectory(path, gt_format_of(path, fmt))
    assert traj.stamps is not None   # TUM and EuRoC files are stamped (only KITTI is not)
    series = unique_ascending(traj.stamps, traj.poses, os.fspath(path))
    if len(series) < 2:
        raise SessionContentError(f"{path}: fewer than 2 poses: not a ground-truth trajectory")
    return series


def session_ground_truth(path: str | os.PathLike) -> GroundTruthSeries:
    """The session's ``/gt/controller/pose`` samples at their log time (the time playback associates by)."""
    from phonepose.schemas.topics import Topic
    from phonepose.session import SessionReader, codec

    stamps: list[float] = []
    raws: list[RawPose] = []
    with SessionReader(path) as reader:
        if not reader.summary().has(Topic.GT_CONTROLLER_POSE):
            raise SessionContentError(f"{path}: no ground truth ({Topic.GT_CONTROLLER_POSE}); "
                                      "give a motion-capture trajectory with {gt} FILE", parameter="gt")
        for m in reader.messages([Topic.GT_CONTROLLER_POSE]):
            try:
                raws.append(codec.raw_pose(m.msg.pose))
            except codec.BrokenPose:
                continue     # skipped as playback skips it
            stamps.append(m.log_time_ns / 1e9)
    if len(raws) < 2:
        raise SessionContentError(f"{path}: fewer than 2 finite poses on {Topic.GT_CONTROLLER_POSE}")
    arr = np.asarray(raws, dtype=float)
    return unique_ascending(np.asarray(stamps), Pose.from_xyzw(arr[:, 4:], arr[:, :4]), Topic.GT_CONTROLLER_POSE)


def ground_truth_source(reader) -> str:
    """Where the session's ``/gt/...`` comes from (``SessionInfo.ground_truth_source``: "simulator",
    "webxr-headset (...)"); a live recording writes the info again when a headset names it, so the last
    non-empty value counts. Empty: none named (an older file, or no ground truth in it)."""
    from phonepose.schemas.topics import Topic

    source = ""
    if reader.summary().has(Topic.SESSION_INFO):
        for m in reader.messages([Topic.SESSION_INFO]):
            source = m.msg.ground_truth_source or source
    return source


def load_ground_truth(session: str | os.PathLike, gt_file: str | os.PathLike | None = None,
                      fmt: str | None = None) -> GroundTruthSeries:
    """``gt_file`` if given (the session's own ground truth is then ignored), else the session's topic."""
    return file_ground_truth(gt_file, fmt) if gt_file is not None else session_ground_truth(session)
