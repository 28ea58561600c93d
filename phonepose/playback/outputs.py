"""Playback outputs: metrics.json and the call into the evaluation module's paper metrics.

TUM trajectories are written by :func:`phonepose.evaluation.trajectory.write_tum` (one writer,
fixed format). metrics.json has a fixed layout, 2-space indent and ``null`` for every value that
cannot be computed, so the same playback gives byte-identical files.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from phonepose.errors import OutputError
from phonepose.geometry import Pose

SCOPES = ("inside", "outside", "total")
METRIC_KEYS = ("p_ate_m", "r_ate_deg", "p_re_m")
TOTAL_KEYS = ("boundary_jumps", "boundary_jump_max_m", "boundary_jump_rms_m")   # total scope only


def _clean(v):
    if v is None:
        return None
    if isinstance(v, (int, np.integer)):
        return int(v)
    v = float(v)
    return v if math.isfinite(v) else None


def empty_scope(scope: str = "inside") -> dict:
    d = {"frames": 0, "p_ate_m": None, "r_ate_deg": None, "p_re_m": None}
    if scope == "total":
        d.update({"boundary_jumps": 0, "boundary_jump_max_m": None, "boundary_jump_rms_m": None})
    return d


def normalise_metrics(m: dict | None) -> dict:
    """The exact ``{"inside"|"outside"|"total": {"frames", "p_ate_m", "r_ate_deg", "p_re_m"}}`` layout;
    ``total`` also has ``boundary_jumps`` (count), ``boundary_jump_max_m`` and ``boundary_jump_rms_m``."""
    out = {}
    for scope in SCOPES:
        src = (m or {}).get(scope) or {}
        d = {"frames": int(src.get("frames") or 0)}
        for k in METRIC_KEYS:
            d[k] = _clean(src.get(k))
        if scope == "total":
            d["boundary_jumps"] = int(src.get("boundary_jumps") or 0)
            d["boundary_jump_max_m"] = _clean(src.get("boundary_jump_max_m"))
            d["boundary_jump_rms_m"] = _clean(src.get("boundary_jump_rms_m"))
        out[scope] = d
    return out


# ----------------------------------------------------------------------------- metrics
def paper_metrics(stamps_s: np.ndarray, gt: Pose, est: Pose, inside: np.ndarray) -> dict:
    """The paper's p_ATE / r_ATE / p_RE per scope (phonepose.evaluation), in the metrics.json layout."""
    from phonepose.evaluation import paper_metrics as compute

    if len(stamps_s) == 0:
        return {s: empty_scope(s) for s in SCOPES}
    return normalise_metrics(compute(np.asarray(stamps_s, dtype=float), gt, est, np.asarray(inside, dtype=bool)))


def metrics_document(session: str, rate_hz: float, trackers: dict[str, dict], ground_truth: dict | None = None) -> dict:
    """The metrics.json document: ``{"session", "rate_hz", ["ground_truth",] "trackers": {name: {scope: {...}}}}``.

    ``ground_truth`` (only with ``playback --hand-eye``) says how the ground truth was re-expressed."""
    rate = int(rate_hz) if float(rate_hz).is_integer() else float(rate_hz)
    doc: dict[str, Any] = {"session": session, "rate_hz": rate}
    if ground_truth is not None:
        doc["ground_truth"] = ground_truth
    doc["trackers"] = {name: normalise_metrics(trackers[name]) for name in trackers}
    return doc


def write_metrics(path: str | os.PathLike, session: str, rate_hz: float, trackers: dict[str, dict],
                  ground_truth: dict | None = None) -> dict:
    doc = metrics_document(session, rate_hz, trackers, ground_truth)
    try:
        Path(path).write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n")
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    return doc
