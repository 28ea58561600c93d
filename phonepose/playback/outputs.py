"""Playback outputs: metrics.json and the call into the evaluation module's paper metrics.

TUM trajectories are written by :func:`phonepose.evaluation.trajectory.write_tum` (one writer,
fixed format). metrics.json has a fixed layout, 2-space indent and ``null`` for every value that
cannot be computed, so the same playback gives byte-identical files.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from phonepose.errors import OutputError
from phonepose.evaluation.metrics import SCOPES
from phonepose.geometry import Pose


def empty_scope(scope: str = "inside") -> dict:
    return normalise_metrics(None)[scope]


def normalise_metrics(m: dict | None) -> dict:
    """The exact metrics.json layout of one tracker (phonepose.evaluation.metrics: every metric, its scopes
    and order): ``{"inside"|"outside"|"total": {"frames", "p_ate_m", "r_ate_deg", "p_re_m"}}``; ``total``
    also has the boundary jumps (count, max, RMS) and the AR-controller metrics (lag, jitter, availability)."""
    from phonepose.evaluation.metrics import normalise

    return normalise(m)


# ----------------------------------------------------------------------------- metrics
def paper_metrics(stamps_s: np.ndarray, gt: Pose | None, est: Pose | None, inside: np.ndarray) -> dict:
    """The paper's p_ATE / r_ATE / p_RE per scope (phonepose.evaluation), in the metrics.json layout."""
    from phonepose.evaluation import paper_metrics as compute

    if len(stamps_s) == 0:
        return {s: empty_scope(s) for s in SCOPES}
    return normalise_metrics(compute(np.asarray(stamps_s, dtype=float), gt, est, np.asarray(inside, dtype=bool)))


def metrics_document(session: str, rate_hz: float, trackers: dict[str, dict], ground_truth: dict | None = None) -> dict:
    """The metrics.json document: ``{"session", "rate_hz", ["ground_truth",] "trackers": {name: {scope: {...}}}}``.

    ``ground_truth`` (only with ``playback --gt-calibration``) says how the ground truth was re-expressed."""
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
