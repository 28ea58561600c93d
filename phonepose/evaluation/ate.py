"""Absolute trajectory error (Zhang & Scaramuzza; rpg_trajectory_evaluation ``compute_absolute_error``).

Per associated pose k, after alignment: ``e_trans = ‖p_gt − p_es_aligned‖`` [m] and
``e_rot = angle(R_es_aligned · R_gtᵀ)`` [deg]. The "scale" error compares consecutive motions
``|‖Δp_es_aligned‖ / ‖Δp_gt‖ − 1|·100`` [%] as rpg intends; ``rpg_quirk=True`` reproduces what
rpg's code computes (``np.diff(x, 0)`` is a no-op, so it compares position norms).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.evaluation.stats import BLOCK_ROWS, row_blocks
from phonepose.geometry import Pose, rotation_inverse, rotation_product


def translation_errors(gt: Pose, est_aligned: Pose) -> np.ndarray:
    d = np.atleast_2d(gt.translation) - np.atleast_2d(est_aligned.translation)
    return np.sqrt(np.sum(d * d, axis=1))


def rotation_errors_deg(gt: Pose, est_aligned: Pose) -> np.ndarray:
    return np.degrees(np.atleast_1d(rotation_product(est_aligned.rotation, rotation_inverse(gt.rotation)).magnitude()))


def scale_errors_perc(gt_positions: np.ndarray, est_aligned_positions: np.ndarray, rpg_quirk: bool = False):
    g = np.asarray(gt_positions, dtype=float)
    e = np.asarray(est_aligned_positions, dtype=float)
    if not rpg_quirk:
        g, e = np.diff(g, axis=0), np.diff(e, axis=0)
    dg = np.sqrt(np.sum(g * g, axis=1))
    de = np.sqrt(np.sum(e * e, axis=1))
    ok = dg > 0
    return np.abs((de[ok] / dg[ok] - 1.0) * 100)


def absolute_errors(gt: Pose, est_aligned: Pose) -> tuple[np.ndarray, np.ndarray]:
    """``(e_trans [m], e_rot [deg])`` per pose (computed ``BLOCK_ROWS`` poses at a time: the same values)."""
    n = len(gt)
    if n <= BLOCK_ROWS:
        return translation_errors(gt, est_aligned), rotation_errors_deg(gt, est_aligned)
    e_trans, e_rot = np.empty(n), np.empty(n)
    q_gt, q_est = gt.rotation.as_quat(), est_aligned.rotation.as_quat()   # (Pose[rows] would copy them per block)
    for rows in row_blocks(n):
        g = Pose(Rotation(q_gt[rows], normalize=False, copy=False), gt.translation[rows])
        e = Pose(Rotation(q_est[rows], normalize=False, copy=False), est_aligned.translation[rows])
        e_trans[rows], e_rot[rows] = translation_errors(g, e), rotation_errors_deg(g, e)
    return e_trans, e_rot
