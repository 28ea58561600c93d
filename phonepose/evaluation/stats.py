"""Summary statistics of an error vector, as rpg_trajectory_evaluation and evo report them.

``std`` is the population standard deviation (``np.std``, ddof 0) in both tools; ``sse`` is evo's
sum of squared errors. An empty vector gives ``None`` for every statistic (``num_samples`` 0).
"""

from __future__ import annotations

import numpy as np

STAT_KEYS = ("rmse", "mean", "median", "std", "min", "max")

# Per-pose and per-pair errors are computed this many rows at a time. Every step is row by row (the
# reductions run over the whole error vector afterwards), so the values are the same bits as one
# whole-array pass, while the temporaries are one block's (docs/performance.md#memory). 2048 rows
# keep numpy's per-call cost negligible (one block covers a typical 2000-pose evaluation).
BLOCK_ROWS = 2048


def row_blocks(n: int) -> list[slice]:
    """``slice``s of ``BLOCK_ROWS`` rows covering ``range(n)`` in order."""
    return [slice(a, min(a + BLOCK_ROWS, n)) for a in range(0, n, BLOCK_ROWS)]


def statistics(errors: np.ndarray, *, sse: bool = False) -> dict:
    """``{"rmse", "mean", "median", "std", "min", "max", "num_samples"}`` (+ ``"sse"`` if asked)."""
    e = np.asarray(errors, dtype=float).ravel()
    n = int(e.size)
    if n == 0:
        out: dict[str, float | None] = {k: None for k in STAT_KEYS}
        out["num_samples"] = 0
        if sse:
            out["sse"] = None
        return out
    sq = float(np.dot(e, e))
    out = {
        "rmse": float(np.sqrt(sq / n)),
        "mean": float(np.mean(e)),
        "median": float(np.median(e)),
        "std": float(np.std(e)),
        "min": float(np.min(e)),
        "max": float(np.max(e)),
        "num_samples": n,
    }
    if sse:
        out["sse"] = sq
    return out


def rmse(errors: np.ndarray) -> float | None:
    e = np.asarray(errors, dtype=float).ravel()
    return float(np.sqrt(np.dot(e, e) / e.size)) if e.size else None
