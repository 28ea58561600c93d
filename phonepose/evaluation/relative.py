"""Relative error over sub-trajectories (Zhang & Scaramuzza; rpg ``compute_relative_error``).

- Lengths: 10, 20, 30, 40, 50 % of the raw GT path length, truncated to 2 decimals, or given.
- Pairs: ``d`` = cumulative path distance over the *matched* GT positions. For each start i, the
  end j ≥ i minimises ``|d_j − (d_i + L)|`` (first index on ties) and is kept if that gap is
  ``< 0.2·L`` (strict). ``d`` is non-decreasing, so the search is ``np.searchsorted`` plus a check
  of the neighbours, for every start at once.
- Error per pair: ``E = (T_gt,i⁻¹ T_gt,j)⁻¹ · (T_es,i⁻¹ T_es,j)`` (estimate translation × the
  Sim(3) scale s), ``E_w = Rot(T_es,j) · E · Rot(T_es,j)ᵀ``; trans = ‖t(E_w)‖ [m],
  trans_perc = trans / L · 100, rot = arccos((tr R_E − 1)/2) [deg], yaw = |yaw| and
  gravity = √(pitch² + roll²) of ``E_w`` with ZYX Euler angles [deg], rot_deg_per_m = rot / L.
- rpg's index-shift quirk (the k-th *found* end is paired with start k, not with its own start)
  is reproduced only with ``index_shift_quirk=True``; by default each end is paired with its true
  start (the intended maths). They differ only when some start in the middle has no valid end.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.evaluation.stats import BLOCK_ROWS, row_blocks
from phonepose.geometry import Pose

DEFAULT_PERCENTAGES = (0.1, 0.2, 0.3, 0.4, 0.5)
TOLERANCE = 0.2
_EPS = np.finfo(float).eps * 4.0


def truncate(x: float, digits: int = 2) -> float:
    stepper = 10.0 ** digits
    return math.trunc(stepper * x) / stepper


def default_lengths(gt_positions_raw: np.ndarray, percentages=DEFAULT_PERCENTAGES) -> list[float]:
    """rpg's default sub-trajectory lengths from the raw (not only matched) GT path length."""
    from phonepose.evaluation.trajectory import path_length

    total = path_length(gt_positions_raw)
    return [truncate(p * total, 2) for p in percentages]


def accumulated_distances(positions: np.ndarray) -> np.ndarray:
    p = np.asarray(positions, dtype=float)
    if len(p) == 0:
        return np.zeros(0)
    d = np.diff(p, axis=0)
    return np.concatenate(([0.0], np.cumsum(np.sqrt(np.sum(d * d, axis=1)))))


def _nearest_at_or_after(d: np.ndarray, start: np.ndarray, target: np.ndarray):
    """For each k: the first j ≥ start[k] minimising |d_j − target[k]| (d non-decreasing) and that gap
    (``BLOCK_ROWS`` k at a time: each k is independent, and the (k, 4) temporaries stay one block's)."""
    if start.size > BLOCK_ROWS:
        first, best_err = np.empty(start.size, np.intp), np.empty(start.size)
        for rows in row_blocks(start.size):
            first[rows], best_err[rows] = _nearest_at_or_after(d, start[rows], target[rows])
        return first, best_err
    n = d.size
    k = np.searchsorted(d, target, side="left")  # first j with d_j >= target
    cand = np.stack([k - 2, k - 1, k, k + 1], axis=1)
    valid = (cand >= start[:, None]) & (cand < n)
    cand_c = np.clip(cand, 0, n - 1)
    # in place: the same values as np.where(valid, |d - target|, inf), without its temporaries
    err = d[cand_c]
    err -= target[:, None]
    np.abs(err, out=err)
    err[~valid] = np.inf
    best = cand_c[np.arange(len(k)), np.argmin(err, axis=1)]
    best_err = np.min(err, axis=1)
    # first index of a plateau of equal distances (rpg keeps the first j on ties)
    first = np.maximum(np.searchsorted(d, d[best], side="left"), start)
    return first, best_err


def find_pairs(distances: np.ndarray, length: float, tolerance: float = TOLERANCE):
    """rpg's ``compute_comparison_indices_length``: ``(starts, ends)`` of the pairs found."""
    d = np.asarray(distances, dtype=float)
    if d.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    starts = np.arange(d.size)
    max_dist_diff = length * tolerance
    ends, err = _nearest_at_or_after(d, starts, d + length)
    ok = err < max_dist_diff
    return starts[ok].astype(np.int64), ends[ok].astype(np.int64)


def euler_zyx(m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(yaw, pitch, roll) [rad] of rotation matrices, Gohlke's ``euler_from_matrix(M, 'rzyx')``."""
    cy = np.sqrt(m[:, 0, 0] ** 2 + m[:, 1, 0] ** 2)
    regular = cy > _EPS
    yaw = np.where(regular, np.arctan2(m[:, 1, 0], m[:, 0, 0]), 0.0)
    pitch = np.arctan2(-m[:, 2, 0], cy)
    roll = np.where(regular, np.arctan2(m[:, 2, 1], m[:, 2, 2]), np.arctan2(-m[:, 1, 2], m[:, 1, 1]))
    return yaw, pitch, roll


@dataclass(frozen=True)
class RelativeErrors:
    length: float
    starts: np.ndarray
    ends: np.ndarray
    trans: np.ndarray  # m
    trans_perc: np.ndarray  # % of the nominal length
    rot_deg: np.ndarray
    yaw_deg: np.ndarray
    gravity_deg: np.ndarray
    rot_deg_per_m: np.ndarray

    def __len__(self) -> int:
        return int(self.trans.size)


def pair_errors(gt: Pose, est: Pose, starts: np.ndarray, ends: np.ndarray, scale: float = 1.0):
    """``(R_E_w (K,3,3), t_E_w (K,3), R_E (K,3,3))`` of every pair, whole-array."""
    rg = gt.rotation.as_matrix()
    re = est.rotation.as_matrix()
    pg = np.atleast_2d(gt.translation)
    pe = np.atleast_2d(est.translation)
    rgi, rgj, rei, rej = rg[starts], rg[ends], re[starts], re[ends]
    # T_c = T_es,i^-1 T_es,j (translation x s), T_m = T_gt,i^-1 T_gt,j
    r_c = np.einsum("kji,kjl->kil", rei, rej)
    t_c = np.einsum("kji,kj->ki", rei, pe[ends] - pe[starts]) * scale
    r_m = np.einsum("kji,kjl->kil", rgi, rgj)
    t_m = np.einsum("kji,kj->ki", rgi, pg[ends] - pg[starts])
    # E = T_m^-1 T_c
    r_e = np.einsum("kji,kjl->kil", r_m, r_c)
    t_e = np.einsum("kji,kj->ki", r_m, t_c - t_m)
    # E_w = Rot(T_es,j) E Rot(T_es,j)^T
    r_w = np.einsum("kij,kjl,kml->kim", rej, r_e, rej)
    t_w = np.einsum("kij,kj->ki", rej, t_e)
    return r_w, t_w, r_e


def relative_errors_at(gt: Pose, est: Pose, length: float, scale: float = 1.0,
                       index_shift_quirk: bool = False, distances: np.ndarray | None = None) -> RelativeErrors:
    """RE at one sub-trajectory length (fewer than 2 pairs → empty, as rpg)."""
    d = accumulated_distances(gt.translation) if distances is None else distances
    starts, ends = find_pairs(d, length)
    if ends.size < 2:
        starts = ends = np.zeros(0, np.int64)
    elif index_shift_quirk:
        starts = np.arange(ends.size, dtype=np.int64)
    if ends.size == 0:
        z = np.zeros(0)
        return RelativeErrors(length, starts, ends, z, z, z, z, z, z)
    quats = gt.rotation.as_quat(), est.rotation.as_quat()     # once: Pose's indexing copies them each time
    # BLOCK_ROWS pairs at a time: each pair's errors depend on its two poses only, so the values are the whole
    # arrays', and the (K, 3, 3) intermediates (~700 bytes a pair) stay one block's
    parts = [_block_errors(gt, est, quats, starts[rows], ends[rows], scale, length) for rows in row_blocks(ends.size)]
    trans, trans_perc, rot, yaw_deg, gravity_deg, rot_per_m = (
        np.concatenate([part[c] for part in parts]) for c in range(6))
    return RelativeErrors(length, starts, ends, trans, trans_perc, rot, yaw_deg, gravity_deg, rot_per_m)


def _block_errors(gt: Pose, est: Pose, quats: tuple[np.ndarray, np.ndarray], starts: np.ndarray, ends: np.ndarray,
                  scale: float, length: float):
    """(trans, trans %, rot deg, yaw deg, gravity deg, rot deg per m) of the pairs ``starts``-``ends``."""
    both = np.concatenate([starts, ends])
    n = starts.size
    local = np.arange(n)
    g, e = (Pose(Rotation(q[both], normalize=False, copy=False), np.atleast_2d(p.translation)[both])
            for q, p in zip(quats, (gt, est), strict=True))
    r_w, t_w, r_e = pair_errors(g, e, local, local + n, scale)
    trans = np.sqrt(np.sum(t_w * t_w, axis=1))
    cos = (np.trace(r_e, axis1=1, axis2=2) - 1.0) / 2.0
    rot = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    yaw, pitch, roll = euler_zyx(r_w)
    return (trans, trans / length * 100.0, rot, np.abs(yaw) * 180.0 / np.pi,
            np.sqrt(pitch ** 2 + roll ** 2) * 180.0 / np.pi, rot / length)


def relative_errors(gt: Pose, est: Pose, lengths, scale: float = 1.0,
                    index_shift_quirk: bool = False) -> dict[float, RelativeErrors]:
    d = accumulated_distances(gt.translation)
    return {float(L): relative_errors_at(gt, est, float(L), scale, index_shift_quirk, d) for L in lengths}
