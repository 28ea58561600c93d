"""What a playback keeps of every tick for the metrics and the trajectory files, in constant memory.

The metrics need each tracker's whole trajectory (the alignment and the relative errors run over
all of it), so a playback must keep ``(t, pose, in view)`` of every task-window tick for every
tracker and for the ground truth: ~65 bytes per tick and tracker packed, ~8 MB for ten minutes of
nine trackers + GT, which alone would break the "memory flat in session length" budget (a
10-minute session's peak <= 1.05x a 1-minute one's, docs/performance.md#memory). So each
:class:`TrajectoryCollector` packs the values into ``array`` buffers (8 bytes per number) and
moves them every ``BLOCK_TICKS`` ticks into an unnamed temporary file (deleted when closed, also
on a crash); ``stamps()`` / ``poses()`` read them back when the metrics ask, one tracker at a
time, as the same float64 bits. :class:`Trajectories` is the playback result's view of them: each
trajectory is read from its file when it is looked up, never all of them at once.
"""

from __future__ import annotations

import io
import tempfile
from array import array
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from phonepose.geometry import Pose

BLOCK_TICKS = 1024          # ~65 kB in memory per collector between two spills


@dataclass
class TrackerTrajectory:
    """One tracker's output over the task window (only the ticks where it had a pose)."""

    name: str
    stamps_ns: np.ndarray                 # (N,) int64
    poses: Pose | None                    # N poses in display_vio (None when N == 0)
    inside: np.ndarray                    # (N,) bool: marker recognised at that tick
    ticks_without_pose: int = 0           # task-window ticks where step() returned None


class TrajectoryCollector:
    """Per-tick ``(t_ns, pose, inside)`` of one tracker (or of the GT), packed, spilled to a temporary file."""

    def __init__(self) -> None:
        self.none = 0                      # ticks where the pose was None (not kept)
        self._n_spilled = 0
        self._file: io.BufferedRandom | None = None
        self._new_block()

    def _new_block(self) -> None:
        self._t = array("q")
        self._rot = array("d")      # x, y, z, w per tick
        self._trans = array("d")    # x, y, z per tick
        self._inside = array("b")

    def add(self, t_ns: int, pose: Pose | None, inside: bool) -> None:
        if pose is None:
            self.none += 1
            return
        self._t.append(t_ns)
        self._rot.extend(pose.quat_xyzw.ravel().tolist())
        self._trans.extend(np.asarray(pose.translation, dtype=float).ravel().tolist())
        self._inside.append(bool(inside))
        if len(self._t) >= BLOCK_TICKS:
            self._spill()

    def __len__(self) -> int:
        return self._n_spilled + len(self._t)

    def _spill(self) -> None:
        if self._file is None:
            self._file = tempfile.TemporaryFile(prefix="phonepose-trajectory-")
        for a in (self._t, self._rot, self._trans, self._inside):
            a.tofile(self._file)
        self._n_spilled += len(self._t)
        self._new_block()

    def _read(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(t int64 (N,), quat xyzw (N, 4), translation (N, 3), inside bool (N,)), in tick order."""
        n = len(self)
        t, rot = np.empty(n, np.int64), np.empty((n, 4))
        trans, inside = np.empty((n, 3)), np.empty(n, np.int8)
        k = 0
        if self._file is not None:
            self._file.seek(0)
            while k < self._n_spilled:
                m = min(BLOCK_TICKS, self._n_spilled - k)   # every spilled block is BLOCK_TICKS long
                for dst in (t[k:k + m], rot[k:k + m], trans[k:k + m], inside[k:k + m]):
                    self._file.readinto(dst.data.cast("B"))
                k += m
        m = len(self._t)
        for dst, src in ((t, self._t), (rot, self._rot), (trans, self._trans), (inside, self._inside)):
            dst[k:k + m] = np.frombuffer(src, dtype=dst.dtype).reshape(dst[k:k + m].shape)
        return t, rot, trans, inside.astype(bool)

    def stamps(self) -> np.ndarray:
        return self._read()[0]

    def inside(self) -> np.ndarray:
        return self._read()[3]

    def poses(self) -> Pose | None:
        if not len(self):
            return None
        _t, rot, trans, _inside = self._read()
        return Pose.from_xyzw(trans, rot)

    def trajectory(self, name: str) -> TrackerTrajectory:
        t, rot, trans, inside = self._read()
        poses = Pose.from_xyzw(trans, rot) if len(t) else None
        return TrackerTrajectory(name, t, poses, inside, self.none)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


class Trajectories(Mapping[str, TrackerTrajectory]):
    """Tracker name -> :class:`TrackerTrajectory`, each read from its collector when looked up (so a
    caller holds only the ones it keeps)."""

    def __init__(self, collectors: dict[str, TrajectoryCollector]):
        self._collectors = collectors

    def __getitem__(self, name: str) -> TrackerTrajectory:
        return self._collectors[name].trajectory(name)

    def __iter__(self) -> Iterator[str]:
        return iter(self._collectors)

    def __len__(self) -> int:
        return len(self._collectors)
