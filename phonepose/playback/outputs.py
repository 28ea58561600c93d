"""Playback outputs: metrics.json, errors.csv, the call into the evaluation module's paper metrics,
and the /pipeline/markers message of trackers.mcap.

TUM trajectories are written by :func:`phonepose.evaluation.trajectory.write_tum` (one writer,
fixed format). metrics.json has a fixed layout, 2-space indent and ``null`` for every value that
cannot be computed, so the same playback gives byte-identical files. errors.csv holds the
per-tick errors the metrics are the RMS of, every double written exactly (``repr``).
"""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from phonepose.errors import OutputError
from phonepose.evaluation.metrics import SCOPES
from phonepose.geometry import Pose
from phonepose.pipeline.types import Observation
from phonepose.schemas import phonepose_pb2 as pb
from phonepose.session.codec import encode_pose
from phonepose.topics import Frame


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



ERRORS_HEADER = ["timestamp", "tracker", "position_error_m", "rotation_error_deg", "in_view"]


def tick_errors(stamps_ns: np.ndarray, poses: Pose | None, gt_stamps_ns: np.ndarray,
                gt: Pose | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(stamps_ns, e_trans [m], e_rot [deg], index into the tracker's ticks)`` at the ticks where
    the tracker and the GT both have a pose: the association and errors the paper metrics use."""
    from phonepose.evaluation.ate import absolute_errors

    if gt is None or poses is None:
        empty = np.zeros(0)
        return np.zeros(0, np.int64), empty, empty, np.zeros(0, np.int64)
    common, i_est, i_gt = np.intersect1d(stamps_ns, gt_stamps_ns, assume_unique=True, return_indices=True)
    if common.size == 0:
        empty = np.zeros(0)
        return common, empty, empty, i_est
    e_trans, e_rot = absolute_errors(gt[i_gt], poses[i_est])
    return common, e_trans, e_rot, i_est


def write_errors(path: str | os.PathLike, trajectories: Mapping, gt_stamps_ns: np.ndarray, gt: Pose | None) -> None:
    """errors.csv: per tracker (in order) and task-window tick with GT, its position error (m),
    rotation error (degrees) and whether the marker was in view; ``timestamp`` as in the TUM files."""
    try:
        with open(path, "w", newline="") as f:
            w = csv.writer(f, lineterminator="\n")
            w.writerow(ERRORS_HEADER)
            for name in trajectories:
                traj = trajectories[name]     # one at a time, as the TUM files are written
                t, e_trans, e_rot, i_est = tick_errors(traj.stamps_ns, traj.poses, gt_stamps_ns, gt)
                inside = np.asarray(traj.inside, dtype=bool)[i_est]
                w.writerows((f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}", name, repr(float(p)), repr(float(r)),
                             int(v)) for ns, p, r, v in zip(t.tolist(), e_trans, e_rot, inside, strict=True))
                del traj
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None


def write_metrics(path: str | os.PathLike, session: str, rate_hz: float, trackers: dict[str, dict],
                  ground_truth: dict | None = None) -> dict:
    doc = metrics_document(session, rate_hz, trackers, ground_truth)
    try:
        Path(path).write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n")
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    return doc


def detections_message(obs: Observation) -> pb.MarkerDetections:
    """The /pipeline/markers message for this tick's frame (empty when nothing was recognised)."""
    msg = pb.MarkerDetections(frame_id=Frame.DISPLAY_CAMERA)
    stamp = obs.tick.frame_t_ns
    msg.timestamp.FromNanoseconds(int(stamp))
    m = obs.marker
    if m is not None:
        det = msg.detections.add(id=m.id, reprojection_error_px=m.reprojection_error_px,
                                 chosen_solution=m.chosen_solution,
                                 ambiguity_ratio=m.ambiguity_ratio if np.isfinite(m.ambiguity_ratio) else 0.0)
        det.corners_px.extend(float(v) for v in np.asarray(m.corners_px).reshape(-1))
        encode_pose(m.T_camera_marker, det.pose_in_camera)
        if m.T_dvio_controller is not None:
            encode_pose(m.T_dvio_controller, det.controller_in_display_vio)
    return msg
