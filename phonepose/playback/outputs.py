"""Playback outputs: TUM trajectories, metrics.json, and the metric computation hook.

Formatting is fixed so that the same playback gives byte-identical files: TUM stamps are
written from integer nanoseconds (``sec.nnnnnnnnn``), poses with 9 decimals, metrics.json with
sorted tracker names, 2-space indent and ``null`` for every value that cannot be computed.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from phonepose.errors import OutputError
from phonepose.geometry import Pose

SCOPES = ("inside", "outside", "total")
METRIC_KEYS = ("p_ate_m", "r_ate_deg", "p_re_m")


def format_stamp(t_ns: int) -> str:
    t_ns = int(t_ns)
    sign = "-" if t_ns < 0 else ""
    t_ns = abs(t_ns)
    return f"{sign}{t_ns // 1_000_000_000}.{t_ns % 1_000_000_000:09d}"


def _f(v: float) -> str:
    s = f"{float(v):.9f}"
    return "0.000000000" if s == "-0.000000000" else s


def write_tum(path: str | os.PathLike, stamps_ns, poses: Pose | None) -> None:
    """``t tx ty tz qx qy qz qw`` per line; the quaternion sign is made canonical (qw >= 0).

    Written in blocks of lines, so a long trajectory never exists as one string in memory."""
    try:
        with open(path, "w") as f:
            f.write("# timestamp tx ty tz qx qy qz qw\n")
            if poses is not None and len(stamps_ns):
                t = np.atleast_2d(poses.translation)
                q = np.atleast_2d(poses.rotation.as_quat(canonical=True))
                lines = []
                for i, stamp in enumerate(stamps_ns):
                    lines.append(" ".join([format_stamp(stamp), *(_f(v) for v in t[i]), *(_f(v) for v in q[i])]) + "\n")
                    if len(lines) == 2048:
                        f.write("".join(lines))
                        lines.clear()
                f.write("".join(lines))
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None


def _clean(v):
    if v is None:
        return None
    if isinstance(v, (int, np.integer)):
        return int(v)
    v = float(v)
    return v if math.isfinite(v) else None


def empty_scope() -> dict:
    return {"frames": 0, "p_ate_m": None, "r_ate_deg": None, "p_re_m": None}


def normalise_metrics(m: dict | None) -> dict:
    """The exact ``{"inside"|"outside"|"total": {"frames", "p_ate_m", "r_ate_deg", "p_re_m"}}`` layout."""
    out = {}
    for scope in SCOPES:
        src = (m or {}).get(scope) or {}
        d = {"frames": int(src.get("frames") or 0)}
        for k in METRIC_KEYS:
            d[k] = _clean(src.get(k))
        out[scope] = d
    return out


# ----------------------------------------------------------------------------- metrics
def _minimal_paper_metrics(stamps, gt: Pose, est: Pose, inside) -> dict:
    """Fallback when phonepose.evaluation is not importable: no alignment (both are in display_vio),
    ATE = RMSE of position / rotation errors, RE = RMSE of the relative translation error between
    consecutive frames of the same scope."""
    inside = np.asarray(inside, dtype=bool)
    out = {}
    for scope, mask in (("inside", inside), ("outside", ~inside), ("total", np.ones_like(inside))):
        idx = np.flatnonzero(mask)
        if idx.size == 0:
            out[scope] = empty_scope()
            continue
        g, e = gt[idx], est[idx]
        p = float(np.sqrt(np.mean(np.sum((g.translation - e.translation) ** 2, axis=-1))))
        r = float(np.degrees(np.sqrt(np.mean(g.angle_to(e) ** 2))))
        pre = None
        if idx.size >= 2:
            dg = (g[:-1].inv() @ g[1:]).translation
            de = (e[:-1].inv() @ e[1:]).translation
            pre = float(np.sqrt(np.mean(np.sum((dg - de) ** 2, axis=-1))))
        out[scope] = {"frames": int(idx.size), "p_ate_m": p, "r_ate_deg": r, "p_re_m": pre}
    return out


def paper_metrics(stamps_s: np.ndarray, gt: Pose, est: Pose, inside: np.ndarray) -> dict:
    """The evaluation module's paper_metrics when available, else the minimal version above."""
    if len(stamps_s) == 0:
        return {s: empty_scope() for s in SCOPES}
    try:
        from phonepose.evaluation import paper_metrics as real
    except ImportError:
        real = None
    if real is None:
        return normalise_metrics(_minimal_paper_metrics(stamps_s, gt, est, inside))
    return normalise_metrics(real(np.asarray(stamps_s, dtype=float), gt, est, np.asarray(inside, dtype=bool)))


def metrics_document(session: str, rate_hz: float, trackers: dict[str, dict]) -> dict:
    """The metrics.json document: ``{"session", "rate_hz", "trackers": {name: {scope: {...}}}}``."""
    rate = int(rate_hz) if float(rate_hz).is_integer() else float(rate_hz)
    return {"session": session, "rate_hz": rate,
            "trackers": {name: normalise_metrics(trackers[name]) for name in trackers}}


def write_metrics(path: str | os.PathLike, session: str, rate_hz: float, trackers: dict[str, dict]) -> dict:
    doc = metrics_document(session, rate_hz, trackers)
    try:
        Path(path).write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n")
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    return doc
