"""Time series as stamp arrays with rows of values: which samples are in order, and interpolating all
columns of the rows at once.

Recorded streams can repeat a stamp or step back (a clock-sync update, a duplicated message): the
consumers that need rising stamps keep the samples :func:`newer_than_before`. numpy's ``np.interp``
takes one column; :func:`interp_columns` is the same interpolation for every column in one call.
"""

from __future__ import annotations

import numpy as np


def newer_than_before(t: np.ndarray, after: float | int | None = None) -> np.ndarray:
    """Mask of the stamps newer than every earlier one, and than ``after`` (None: no bound). Integer stamps
    (nanoseconds) are compared as integers: a float sentinel would round stamps above 2**53."""
    t = np.asarray(t)
    if len(t) == 0:
        return np.zeros(0, bool)
    before = np.empty_like(t)
    before[1:] = t[:-1]
    if after is not None:
        before[0] = after
    elif t.dtype.kind in "iu":
        before[0] = np.iinfo(t.dtype).min
    else:
        before[0] = -np.inf
    keep = t > np.maximum.accumulate(before)
    if after is None and t.dtype.kind in "iu":
        keep[0] = True          # the smallest integer itself is newer than "no bound"
    return keep


def interp_columns(x, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """``np.interp(x, xp, fp[:, j])`` for every column j at once, to the bit: numpy's own formula (the value
    at a sample is that sample's, else (fp[j+1] - fp[j]) / (xp[j+1] - xp[j]) (x - xp[j]) + fp[j]), and its
    ends outside ``[xp[0], xp[-1]]``. ``xp`` ascending; ``x`` a float (a row back) or an array (rows back).

    Written out because T8 calls it for its accelerometer on every tick, where loops over columns cost. Where a slope
    is not finite (repeated stamps, or values that overflow) numpy has fallbacks, so those calls go to
    np.interp column by column."""
    xp = np.asarray(xp, dtype=float)
    fp = np.asarray(fp, dtype=float)
    if isinstance(x, float) and x == x and len(xp) > 1:
        return _interp_row(x, xp, fp)
    x = np.minimum(np.maximum(x, xp[0]), xp[-1])        # numpy's ends (NaN stays NaN)
    j = np.minimum(xp.searchsorted(x, side="right") - 1, len(xp) - 2)
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])[..., None]
    if not np.isfinite(slope).all():
        return np.stack([np.interp(x, xp, fp[:, k]) for k in range(fp.shape[1])], axis=-1)
    out = slope * (x - xp[j])[..., None] + fp[j]
    at_sample = (x == xp[j]) | (x == xp[-1])
    if at_sample.any():
        out = np.where(at_sample[..., None], fp[np.where(x == xp[-1], len(xp) - 1, j)], out)
    return out


def _interp_row(x: float, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """interp_columns at one (not NaN) float: the same formula on one row, with the index found and the ends
    clamped as Python numbers (T8 interpolates single instants several times a tick, where the array path's
    per-call overhead dominates)."""
    n = len(xp)
    lo, hi = float(xp[0]), float(xp[-1])
    x = hi if x > hi else (lo if x < lo else x)
    j = min(int(xp.searchsorted(x, side="right")) - 1, n - 2)
    if x == hi:
        return fp[n - 1].copy()
    if x == xp[j]:
        return fp[j].copy()
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    if not np.isfinite(slope).all():
        return np.array([np.interp(x, xp, fp[:, k]) for k in range(fp.shape[1])])
    return slope * (x - xp[j]) + fp[j]


def interp_columns_inside(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """interp_columns where the caller knows every ``x`` lies in ``[xp[0], xp[-1])``, ``xp`` strictly rising and
    ``fp`` finite: the same numbers (a zero's sign aside: at a sample, slope * 0 + value is the value) without
    the clamping, the end and at-sample cases and the finiteness check, half its array operations
    (T8 interpolates its accelerometer integral at the window's VIO stamps on every tick)."""
    j = xp.searchsorted(x, side="right") - 1
    f0, x0 = fp[j], xp[j]         # (each row gathered once)
    return (fp[j + 1] - f0) / (xp[j + 1] - x0)[:, None] * (x - x0)[:, None] + f0
