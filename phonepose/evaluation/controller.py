"""What an AR input designer reads about a tracker, beside its error: lag, jitter, availability.

Formulas (docs/evaluation.md, "AR-controller metrics"); every input is on the task's ticks, ``gt``
and ``est`` associated (the same stamps) unless said otherwise:

- **lag** [s]: the time shift ``τ`` that minimises the RMS position error of the estimate moved
  earlier by ``τ``: ``argmin_τ sqrt(mean_k ‖p_est(t_k + τ) − p_gt(t_k)‖²)``, ``p_est`` linearly
  interpolated between its stamps, over the ``t_k`` where ``t_k + τ`` lies inside them, ``τ`` on a
  grid of ``resolution_s`` (5 ms) in ``[−max_shift_s, max_shift_s]``. Positive: the estimate is
  late. The resolution is the grid step; between the 20 Hz ticks the estimate is a straight line.
- **jitter** [m, deg]: the high-pass part of the error ``e_k = p_est,k − p_gt,k`` (and of the
  rotation error ``log(R_est,k R_gt,kᵀ)``) while the phone is held still: the RMS second difference
  ``sqrt(Σ ‖e_{k+1} − 2e_k + e_{k−1}‖² / (6 n))`` over the ``n`` runs of three consecutive still
  ticks. Constant and linearly drifting errors give 0; white noise of σ per axis gives ``σ√3``
  (the RMS length of the 3-D noise vector). Held still: the ground truth moves less than
  ``still_m`` over ``still_window_s`` centred on the tick (tremor alone stays below it).
- **availability**: the fraction of the task's ticks (those with ground truth) at which the
  tracker gave a pose.
"""

from __future__ import annotations

import numpy as np

from phonepose.geometry import Pose
from phonepose.series import interp_columns

LAG_RESOLUTION_S = 0.005     # the lag grid: finer than a tick (50 ms), coarser than the stamps' jitter
LAG_MAX_SHIFT_S = 0.5        # > any latency of the simulated or real streams (~0.15 s)
STILL_WINDOW_S = 0.5         # "held still": the truth moves less than STILL_M over this window ...
STILL_M = 0.01               # ... (hand tremor is ~1 mm; a pointing movement is 10-40 cm)
_JITTER_NOISE = 6.0          # E‖Δ²e‖² = 6 σ² per axis for white noise of σ


LAG_BLOCK_POINTS = 60_000   # shifted stamps interpolated per call: bounded memory (~5 MB) whatever the length


def lag_curve(stamps_s: np.ndarray, gt_positions: np.ndarray, est_stamps_s: np.ndarray, est_positions: np.ndarray,
              resolution_s: float = LAG_RESOLUTION_S,
              max_shift_s: float = LAG_MAX_SHIFT_S) -> tuple[list[float], list[float]]:
    """The shifts (s) of the grid whose window keeps most of the task, and the mean squared position error
    (m²) of the estimate moved by each: what :func:`lag` minimises ([] with fewer than 2 estimates)."""
    t_est = np.asarray(est_stamps_s, dtype=float)
    p_est = np.asarray(est_positions, dtype=float).reshape(-1, 3)
    t_gt = np.asarray(stamps_s, dtype=float)
    p_gt = np.asarray(gt_positions, dtype=float).reshape(-1, 3)
    if t_est.size < 2 or t_gt.size == 0:
        return [], []
    steps = int(round(max_shift_s / resolution_s))
    taus = [k * resolution_s for k in range(-steps, steps + 1)]
    shifts, errors = [], []
    # Several shifts per np.interp call: on a short session the per-shift calls cost 4x the arithmetic.
    # Each shift's error is the per-shift formula's to the bit: the same interpolations and squared
    # distances element by element, and its mean over exactly its own window's stamps, in order.
    per_block = max(1, LAG_BLOCK_POINTS // t_gt.size)
    moved_at = _Segments(t_est, p_est)
    for start in range(0, len(taus), per_block):
        block = taus[start:start + per_block]
        q = t_gt[None, :] + np.array(block)[:, None]
        sq = None      # the squared distances summed over x, y, z in that order, as np.sum(..., axis=2) does
        for k, moved in enumerate(moved_at.columns(q.ravel())):
            d = moved.reshape(len(block), t_gt.size) - p_gt[:, k]
            sq = d * d if sq is None else sq + d * d
        assert sq is not None
        use = (q >= t_est[0]) & (q <= t_est[-1])
        for tau, row, keep in zip(block, sq, use, strict=True):
            if int(keep.sum()) < max(2, t_gt.size // 2):     # the shifted window must keep most of the task
                continue
            shifts.append(tau)
            errors.append(float(np.mean(row[keep])))
    return shifts, errors


class _Segments:
    """np.interp of each column at many points, for lag_curve: the value at a point inside the stamps is
    interp_columns' to the bit (the same slope of its segment, times the same offset, plus the same sample);
    outside them it is any finite number (lag_curve leaves those points out). The slopes are computed once per
    segment, not once per point and shift, and gathered column by column (1-D takes are cheaper than rows of
    three): lag_curve interpolates ~200 shifts of every stamp, most of a playback's metrics
    (docs/performance.md#where-a-playbacks-time-goes). Stamps repeated or values not finite: interp_columns itself."""

    def __init__(self, t: np.ndarray, p: np.ndarray) -> None:
        self.t, self.p = t, p
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            slope = (p[1:] - p[:-1]) / (t[1:] - t[:-1])[:, None]
        self.exact = bool(np.isfinite(slope).all())
        self.slope = slope

    def columns(self, x: np.ndarray) -> list[np.ndarray]:
        """The interpolated values at ``x``, one array per column."""
        t, p = self.t, self.p
        if not self.exact:
            out = interp_columns(x, t, p)
            return [out[:, k] for k in range(p.shape[1])]
        j = np.minimum(np.maximum(t.searchsorted(x, side="right") - 1, 0), len(t) - 2)
        offset = x - t.take(j)
        at_end = x == t[-1]             # np.interp's value there is the last sample's own
        cols = []
        for k in range(p.shape[1]):        # (columns of the arrays as they are: no copy that grows with them)
            values = p[:, k]
            col = self.slope[:, k].take(j) * offset + values.take(j)
            if at_end.any():
                col[at_end] = values[-1]
            cols.append(col)
        return cols


def lag(stamps_s: np.ndarray, gt_positions: np.ndarray, est_stamps_s: np.ndarray, est_positions: np.ndarray,
        resolution_s: float = LAG_RESOLUTION_S, max_shift_s: float = LAG_MAX_SHIFT_S) -> float | None:
    """The shift (s) of the estimate that best matches the truth (None: fewer than 2 estimates)."""
    best, best_err = None, np.inf
    for tau, err in zip(*lag_curve(stamps_s, gt_positions, est_stamps_s, est_positions, resolution_s, max_shift_s),
                        strict=True):
        if err < best_err:                          # ties: the earliest (most negative) shift
            best, best_err = tau, err
    return best


def still_ticks(stamps_s: np.ndarray, gt_positions: np.ndarray, window_s: float = STILL_WINDOW_S,
                still_m: float = STILL_M) -> np.ndarray:
    """Per tick: the truth moves less than ``still_m`` between ``t - window/2`` and ``t + window/2``."""
    t = np.asarray(stamps_s, dtype=float)
    p = np.asarray(gt_positions, dtype=float).reshape(-1, 3)
    if t.size < 2:
        return np.zeros(t.size, bool)
    inside = (t - window_s / 2 >= t[0]) & (t + window_s / 2 <= t[-1])
    a, b = interp_columns(t - window_s / 2, t, p), interp_columns(t + window_s / 2, t, p)
    return inside & (np.linalg.norm(b - a, axis=1) < still_m)


def _second_difference_rms(errors: np.ndarray, ok: np.ndarray) -> float | None:
    triple = ok[:-2] & ok[1:-1] & ok[2:]
    if not triple.any():
        return None
    d2 = errors[2:] - 2 * errors[1:-1] + errors[:-2]
    return float(np.sqrt(np.sum(d2[triple] ** 2) / (_JITTER_NOISE * triple.sum())))


def jitter(stamps_s: np.ndarray, gt: Pose, est: Pose, still: np.ndarray,
           tick_s: float | None = None) -> tuple[float | None, float | None]:
    """(position jitter m, rotation jitter deg) over runs of 3 consecutive still ticks (None: no such run).

    ``stamps_s``: the associated stamps; ticks further apart than 1.5 ``tick_s`` (a gap: no
    estimate in between) do not form a run (``tick_s`` defaults to the median spacing)."""
    t = np.asarray(stamps_s, dtype=float)
    if t.size < 3:
        return None, None
    dt = np.diff(t)
    gap = dt > 1.5 * (float(np.median(dt)) if tick_s is None else tick_s)
    ok = np.asarray(still, dtype=bool).copy()
    ok[1:-1] &= ~gap[:-1] & ~gap[1:]          # the middle of a triple: both its gaps one tick
    pos_err = np.atleast_2d(est.translation) - np.atleast_2d(gt.translation)
    rot_err = np.degrees((est.rotation * gt.rotation.inv()).as_rotvec().reshape(-1, 3))
    return _second_difference_rms(pos_err, ok), _second_difference_rms(rot_err, ok)


def availability(task_ticks: int, ticks_with_estimate: int) -> float | None:
    """Fraction of the task's ticks at which the tracker gave a pose (None: no task tick)."""
    return None if task_ticks <= 0 else ticks_with_estimate / task_ticks


def controller_metrics(gt_stamps_s: np.ndarray, gt: Pose, est_stamps_s: np.ndarray, est: Pose,
                       common_s: np.ndarray, i_gt: np.ndarray, i_est: np.ndarray) -> dict:
    """Lag, jitter and availability of one tracker in the metrics.json layout (``None``: not computable).

    ``gt``/``est`` are the task's ground truth and the tracker's poses at their stamps;
    ``common_s``, ``i_gt``, ``i_est``: the association (stamps both have, and their indices)."""
    gt_p = np.atleast_2d(gt.translation)
    est_p = np.atleast_2d(est.translation)
    still = still_ticks(gt_stamps_s, gt_p)
    whole = common_s.size == len(gt_p) == len(est_p)     # one to one: no copies of the poses
    j_p, j_r = (jitter(common_s, gt if whole else gt[i_gt], est if whole else est[i_est], still[i_gt])
                if common_s.size else (None, None))
    return {"lag_s": lag(gt_stamps_s, gt_p, est_stamps_s, est_p), "lag_resolution_s": LAG_RESOLUTION_S,
            "jitter_m": j_p, "jitter_deg": j_r, "still_ticks": int(still[i_gt].sum()) if common_s.size else 0,
            "availability": availability(int(np.asarray(gt_stamps_s).size), int(common_s.size))}

