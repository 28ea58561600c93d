"""The paper's metrics (Park & Ogawa 2024, section 4.2.3, after Zhang & Scaramuzza 2018).

:func:`paper_metrics` is what the playback engine calls per tracker. Choices (docs/evaluation.md):

- Input: ``gt`` and ``est`` are already associated (one row each, same stamps); rows where the
  tracker had no pose are dropped by the caller before the call.
- p_ATE [m] / r_ATE [deg]: RMSE of ``‖p_gt − p_est‖`` and of the rotation angle of
  ``R_est R_gtᵀ``, **without alignment** (both are in the display frame; the paper measures ATE
  without aligning).
- p_RE [m]: RMSE of the relative *position* error of sub-trajectories, pooled over the default
  lengths (10..50 % of the GT path length, truncated to 2 decimals), pairs (i, j) found on the
  GT path distance with rpg's rule (tolerance 0.2·L, each pair with its true start). The estimate
  is first aligned to the GT with posyaw (translation + rotation about gravity, z up), as the
  paper says ("translation and rotation around gravity were employed to align the RE"); the
  error of a pair is ``‖(p_est,j − p_est,i) − (p_gt,j − p_gt,i)‖``. Unlike rpg's RE translation
  (which expresses the displacement in the start pose's own frame), this does not mix the
  orientation error into p_RE. It is the reading the paper's Table 5 supports: there T1, T2 and
  T3 have the *same* p_RE in every sequence, which holds when p_RE depends on positions only
  (eqs. 5-6 shift VIO positions by a constant) but not with rpg's formula, where the corrected
  orientation would change it. rpg's full RE stays available in ``phonepose evaluate``.
- inside/outside: a frame belongs to the split given by ``inside``; an RE pair belongs to the
  split of its **start** frame. "total" uses every frame and every pair.
- ``None`` where a value cannot be computed (no frames in the split, no RE pair, path too short).
"""

from __future__ import annotations

import numpy as np

from phonepose.evaluation.alignment import align
from phonepose.evaluation.ate import absolute_errors
from phonepose.evaluation.boundary import boundary_jump_stats
from phonepose.evaluation.relative import accumulated_distances, default_lengths, find_pairs
from phonepose.evaluation.stats import rmse, row_blocks
from phonepose.geometry import Pose

SCOPES = ("inside", "outside", "total")


def _empty() -> dict:
    return {"frames": 0, "p_ate_m": None, "r_ate_deg": None, "p_re_m": None}


def relative_translation_pairs(gt: Pose, est: Pose, lengths=None) -> tuple[np.ndarray, np.ndarray]:
    """``(start index, translation error [m])`` of every RE pair over all ``lengths``, pooled."""
    n = len(gt)
    if n < 2:
        return np.zeros(0, np.int64), np.zeros(0)
    if lengths is None:
        lengths = default_lengths(gt.translation)
    d = accumulated_distances(gt.translation)
    p_gt = np.atleast_2d(gt.translation)
    p_est: np.ndarray | None = None        # the aligned estimate, once a length has pairs
    starts_all, errors_all = [], []
    for L in lengths:  # five lengths, not a loop over poses
        if not L > 0:
            continue
        s, e = find_pairs(d, float(L))
        if e.size >= 2:
            if p_est is None:
                # positions only (Alignment.apply's own expression): the rotations are not needed here
                p_est = align(gt, est, "posyaw").apply_positions(np.atleast_2d(est.translation))
            # one length and BLOCK_ROWS pairs at a time (row by row: the same values as whole arrays):
            # the (pairs, 3) temporaries would be the largest allocation of a long playback's metrics
            errors = np.empty(s.size)
            for rows in row_blocks(s.size):
                si, ei = s[rows], e[rows]
                err = (p_est[ei] - p_est[si]) - (p_gt[ei] - p_gt[si])
                errors[rows] = np.sqrt(np.sum(err * err, axis=1))
            starts_all.append(s)
            errors_all.append(errors)
    if not starts_all:
        return np.zeros(0, np.int64), np.zeros(0)
    # pooled one after the other, each list dropped once joined: the peak is 1.5x the pooled pairs, not 2x
    starts = np.concatenate(starts_all)
    del starts_all
    return starts, np.concatenate(errors_all)


def paper_metrics(stamps: np.ndarray, gt: Pose | None, est: Pose | None, inside: np.ndarray) -> dict:
    """``{"inside"|"outside"|"total": {"frames", "p_ate_m", "r_ate_deg", "p_re_m"}}`` (None = not computable);
    ``total`` also has the boundary jumps (phonepose.evaluation.boundary: count, max, RMS)."""
    stamps = np.asarray(stamps, dtype=float)
    inside = np.asarray(inside, dtype=bool).ravel()
    n = int(stamps.size)
    if n == 0 or gt is None or est is None:
        return {s: _empty() for s in SCOPES}
    if len(gt) != n or len(est) != n or inside.size != n:
        raise ValueError(f"paper_metrics: {n} stamps, {len(gt)} GT, {len(est)} estimates, {inside.size} flags")
    e_trans, e_rot = absolute_errors(gt, est)
    starts, re_trans = relative_translation_pairs(gt, est)
    pair_inside = inside[starts]
    out = {}
    for scope, mask, pmask in (("inside", inside, pair_inside), ("outside", ~inside, ~pair_inside),
                               ("total", np.ones(n, bool), np.ones(starts.size, bool))):
        frames = int(mask.sum())
        if frames == 0:
            out[scope] = _empty()
            continue
        out[scope] = {"frames": frames, "p_ate_m": rmse(e_trans[mask]), "r_ate_deg": rmse(e_rot[mask]),
                      "p_re_m": rmse(re_trans[pmask])}
    if out["total"].get("frames"):
        out["total"].update(boundary_jump_stats(stamps, gt.translation, est.translation, inside))
    return out
