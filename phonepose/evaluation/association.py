"""Time association of an estimate with a reference, as rpg_trajectory_evaluation and evo do it.

Both return ``(i_est, i_ref)`` index arrays (int64, equal length).

- :func:`associate_rpg` (TUM ``associate.py`` as rpg uses it): candidates are all pairs with
  ``|t_est - t_ref| < max_diff`` (strict, default 0.02 s), taken greedily in the order of
  ``(|dt|, i_est, i_ref)`` while neither side is used yet (one-to-one); sorted by ``i_est``.
- :func:`associate_evo` (evo 1.38 ``sync.associate_trajectories``): the shorter trajectory is the
  query (the estimate when both have the same length); each query stamp takes the nearest stamp of
  the other (ties to the lower index) if ``|dt| <= max_diff`` (default 0.01 s). Not one-to-one.

Both are vectorised: candidates come from ``np.searchsorted`` windows, and the greedy one-to-one
matching is resolved in rounds of "locally dominant" candidates (a candidate that comes first in
the order among all remaining candidates of its estimate pose *and* of its reference pose is the
one greedy accepts), which gives exactly the greedy result.
"""

from __future__ import annotations

import numpy as np

_MAX_ROUNDS = 64


def _sorted_view(stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = np.asarray(stamps, dtype=float)
    if s.size < 2 or np.all(np.diff(s) >= 0):
        return s, np.arange(s.size)
    order = np.argsort(s, kind="stable")
    return s[order], order


def associate_rpg(est_stamps: np.ndarray, ref_stamps: np.ndarray, max_diff: float = 0.02):
    """rpg's greedy one-to-one association (``|dt| < max_diff``); returns ``(i_est, i_ref)``."""
    te = np.asarray(est_stamps, dtype=float)
    tr_sorted, order = _sorted_view(ref_stamps)
    if te.size == 0 or tr_sorted.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    lo = np.searchsorted(tr_sorted, te - max_diff, side="left")
    hi = np.searchsorted(tr_sorted, te + max_diff, side="right")
    # widen by one each side so that rounding of te +- max_diff cannot drop a candidate
    lo = np.maximum(lo - 1, 0)
    hi = np.minimum(hi + 1, tr_sorted.size)
    # the candidates' indices in the smallest integer type that holds them, each temporary dropped when used: a few
    # candidates a pose made this the evaluation's peak memory (the order and values are the same in any type)
    itype: type[np.signedinteger] = np.int32 if max(te.size, tr_sorted.size) < 2**31 - 1 else np.int64
    counts: np.ndarray = (hi - lo).astype(itype)
    del hi
    ci = np.repeat(np.arange(te.size, dtype=itype), counts)
    cj_sorted: np.ndarray = np.arange(ci.size, dtype=np.int64 if ci.size >= 2**31 - 1 else itype)
    cj_sorted -= np.repeat(np.cumsum(counts, dtype=cj_sorted.dtype) - counts, counts)
    cj_sorted += np.repeat(lo.astype(itype), counts)
    del lo, counts
    dt = te[ci]
    dt -= tr_sorted[cj_sorted] + 0.0
    np.abs(dt, out=dt)
    keep = dt < max_diff
    ci, cj_sorted, dt = ci[keep], cj_sorted[keep], dt[keep]
    del keep
    cj = order[cj_sorted].astype(itype)
    del cj_sorted
    rank = np.lexsort((cj, ci, dt))
    del dt
    ci, cj = ci[rank], cj[rank]
    del rank
    acc_i, acc_j = [], []
    used_i = np.zeros(te.size, bool)
    used_j = np.zeros(np.asarray(ref_stamps).size, bool)
    rounds = 0
    while ci.size:
        rounds += 1
        if rounds > _MAX_ROUNDS:  # long chains of blocking candidates (never seen on real data): finish in order
            ci, cj = _greedy_tail(ci, cj, used_i, used_j)
            acc_i.append(ci)
            acc_j.append(cj)
            break
        first_i = np.zeros(ci.size, bool)
        first_j = np.zeros(ci.size, bool)
        first_i[np.unique(ci, return_index=True)[1]] = True
        first_j[np.unique(cj, return_index=True)[1]] = True
        win = first_i & first_j
        acc_i.append(ci[win])
        acc_j.append(cj[win])
        used_i[ci[win]] = True
        used_j[cj[win]] = True
        rest = ~(used_i[ci] | used_j[cj])
        ci, cj = ci[rest], cj[rest]
    if not acc_i:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    i_est = np.concatenate(acc_i).astype(np.int64)
    i_ref = np.concatenate(acc_j).astype(np.int64)
    o = np.argsort(i_est, kind="stable")
    return i_est[o], i_ref[o]


def _greedy_tail(ci, cj, used_i, used_j):
    """Plain greedy over the remaining candidates (already in acceptance order)."""
    out_i, out_j = [], []
    for i, j in zip(ci.tolist(), cj.tolist(), strict=True):
        if not used_i[i] and not used_j[j]:
            used_i[i] = used_j[j] = True
            out_i.append(i)
            out_j.append(j)
    return np.asarray(out_i, np.int64), np.asarray(out_j, np.int64)


def nearest_indices(query: np.ndarray, stamps: np.ndarray, max_diff: float):
    """evo's ``matching_time_indices(query, stamps)``: ``(i_query, i_stamps)`` of nearest matches."""
    q = np.asarray(query, dtype=float)
    s = np.asarray(stamps, dtype=float)
    if q.size == 0 or s.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    if s.size > 1 and not np.all(np.diff(s) >= 0):
        # evo's linear fallback (argmin over unsorted stamps): the nearest stamp, found on a sorted copy
        s_sorted, order = np.sort(s, kind="stable"), np.argsort(s, kind="stable")
        k = np.clip(np.searchsorted(s_sorted, q), 1, s.size - 1)
        left, right = k - 1, k
        dl, dr = np.abs(s_sorted[left] - q), np.abs(s_sorted[right] - q)
        # among equal |dt| prefer the lowest original index
        pick_sorted = np.where(dr < dl, right, left)
        idx = order[pick_sorted]
        d = np.abs(s[idx] - q)
        ok = d <= max_diff
        return np.flatnonzero(ok).astype(np.int64), idx[ok].astype(np.int64)
    inside = ~((q < s[0] - max_diff) | (q > s[-1] + max_diff))
    k = np.searchsorted(s, q, side="right")
    k = np.minimum(k, s.size - 1)
    diff_ub = s[k] - q
    diff_lb = np.where(k > 0, q - s[np.maximum(k - 1, 0)], np.inf)
    take_ub = (diff_ub <= max_diff) & (diff_ub < diff_lb)
    take_lb = ~take_ub & (diff_lb <= max_diff) & (diff_lb <= diff_ub)
    ok = inside & (take_ub | take_lb)
    best = np.where(take_ub, k, k - 1)
    return np.flatnonzero(ok).astype(np.int64), best[ok].astype(np.int64)


def associate_evo(est_stamps: np.ndarray, ref_stamps: np.ndarray, max_diff: float = 0.01):
    """evo's nearest-stamp association (shorter trajectory as query); returns ``(i_est, i_ref)``."""
    te = np.asarray(est_stamps, dtype=float)
    tr = np.asarray(ref_stamps, dtype=float)
    if te.size > tr.size:  # evo: the estimate is "longer" -> the reference is the query
        i_ref, i_est = nearest_indices(tr, te, max_diff)
    else:
        i_est, i_ref = nearest_indices(te, tr, max_diff)
    return i_est, i_ref


def associate_index(n_est: int, n_ref: int):
    """KITTI: pose k with pose k (both files must have the same length, as evo requires)."""
    n = min(n_est, n_ref)
    return np.arange(n, dtype=np.int64), np.arange(n, dtype=np.int64)


def coverage(est_stamps: np.ndarray, ref_stamps: np.ndarray, max_diff: float) -> tuple[float, float]:
    """How much of each trajectory the matched poses cover: (the fraction of the estimate's poses that
    have a match, the fraction of the reference's time span between its first and last matched pose).

    An estimate scored against another session's ground truth (simulated sessions all start at the
    same stamp) still finds matches, but few, or over a short stretch: the caller warns."""
    i_est, i_ref = associate_rpg(est_stamps, ref_stamps, max_diff)
    if i_est.size == 0 or est_stamps.size == 0:
        return 0.0, 0.0
    ref_span = float(ref_stamps.max() - ref_stamps.min())
    matched = ref_stamps[i_ref]
    ref_frac = 1.0 if ref_span <= 0 else float(matched.max() - matched.min()) / ref_span
    return i_est.size / est_stamps.size, ref_frac
