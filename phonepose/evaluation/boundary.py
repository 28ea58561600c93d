"""The boundary-jump metric: how much an estimate jumps where the marker enters or leaves the view.

At every tick ``i`` whose marker-in-view state differs from the previous tick's, the jump is

    | (p_est[i] - p_est[i-1]) - (p_gt[i] - p_gt[i-1]) |

the estimated position change minus the true one (metres), in the frame both trajectories are
given in (display_vio for playback; no alignment: a change of position does not depend on where
the origin is, and aligning would spread one jump over the whole trajectory). A pair counts only
when the two samples are consecutive ticks: at most ``max_gap_factor`` times the median sample
interval apart (a tracker without a pose at some tick leaves no pair across the hole).
T4-T7 switch source at such ticks; a tracker that does not jump has a maximum near the
tick-to-tick noise. Reported per tracker as the maximum and the RMS over all transitions.
"""

from __future__ import annotations

import math

import numpy as np


def boundary_jumps(stamps_s: np.ndarray, p_gt: np.ndarray, p_est: np.ndarray, inside: np.ndarray,
                   max_gap_factor: float = 1.5) -> np.ndarray:
    """The jump (m) at every in-view transition between consecutive samples, in time order."""
    stamps_s = np.asarray(stamps_s, dtype=float)
    inside = np.asarray(inside, dtype=bool).ravel()
    p_gt, p_est = np.asarray(p_gt, dtype=float).reshape(-1, 3), np.asarray(p_est, dtype=float).reshape(-1, 3)
    if not (len(stamps_s) == len(p_gt) == len(p_est) == len(inside)):
        raise ValueError(f"boundary_jumps: {len(stamps_s)} stamps, {len(p_gt)} GT, {len(p_est)} estimates, "
                         f"{len(inside)} flags")
    if len(stamps_s) < 2:
        return np.zeros(0)
    dt = np.diff(stamps_s)
    step = float(np.median(dt))
    pairs = (inside[1:] != inside[:-1]) & (dt <= max_gap_factor * step) & (dt > 0)
    i = np.flatnonzero(pairs) + 1
    d = (p_est[i] - p_est[i - 1]) - (p_gt[i] - p_gt[i - 1])
    return np.linalg.norm(d, axis=1)


def boundary_jump_stats(stamps_s, p_gt, p_est, inside) -> dict:
    """``{"boundary_jumps": n, "boundary_jump_max_m", "boundary_jump_rms_m"}`` (None without transitions)."""
    j = boundary_jumps(stamps_s, p_gt, p_est, inside)
    if j.size == 0:
        return {"boundary_jumps": 0, "boundary_jump_max_m": None, "boundary_jump_rms_m": None}
    return {"boundary_jumps": int(j.size), "boundary_jump_max_m": float(j.max()),
            "boundary_jump_rms_m": float(math.sqrt(float(np.mean(j * j))))}
