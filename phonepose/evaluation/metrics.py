"""The per-tracker metrics, defined once: what each is, its unit, its scopes and its type.

Playback's metrics.json, ``evaluate --metric paper``, the experiment tables and the batch table
all take their keys, order and types from :data:`METRICS` (one result type, not one layout per
command). A tracker's result is ``{scope: {key: value}}`` with the
scopes ``inside``, ``outside`` and ``total``; a metric defined for ``total`` only appears there.
``None`` is a value that cannot be computed (and ``null`` in JSON).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

SCOPES = ("inside", "outside", "total")
ALL_SCOPES = SCOPES
TOTAL_ONLY = ("total",)


@dataclass(frozen=True)
class MetricDef:
    key: str                     # the JSON key (unit in the name, SI or deg)
    label: str                   # table header, in the display unit
    scale: float                 # value -> display unit
    kind: type                   # int or float (the batch table's Parquet type)
    scopes: tuple[str, ...]
    doc: str                     # where it is defined
    zero_default: bool = False   # int counts: 0 rather than None when nothing was counted


METRICS: tuple[MetricDef, ...] = (
    MetricDef("frames", "frames", 1, int, ALL_SCOPES, "ticks with both a pose and ground truth", zero_default=True),
    MetricDef("p_ate_m", "p_ATE cm", 100, float, ALL_SCOPES, "docs/evaluation.md, the paper's metrics"),
    MetricDef("r_ate_deg", "r_ATE deg", 1, float, ALL_SCOPES, "docs/evaluation.md, the paper's metrics"),
    MetricDef("p_re_m", "p_RE cm", 100, float, ALL_SCOPES, "docs/evaluation.md, the paper's metrics"),
    MetricDef("boundary_jumps", "jumps", 1, int, TOTAL_ONLY, "phonepose.evaluation.boundary", zero_default=True),
    MetricDef("boundary_jump_max_m", "jump max cm", 100, float, TOTAL_ONLY, "phonepose.evaluation.boundary"),
    MetricDef("boundary_jump_rms_m", "jump RMS cm", 100, float, TOTAL_ONLY, "phonepose.evaluation.boundary"),
    MetricDef("lag_s", "lag ms", 1000, float, TOTAL_ONLY, "phonepose.evaluation.controller"),
    MetricDef("lag_resolution_s", "lag res. ms", 1000, float, TOTAL_ONLY, "phonepose.evaluation.controller"),
    MetricDef("jitter_m", "jitter mm", 1000, float, TOTAL_ONLY, "phonepose.evaluation.controller"),
    MetricDef("jitter_deg", "jitter deg", 1, float, TOTAL_ONLY, "phonepose.evaluation.controller"),
    MetricDef("still_ticks", "still ticks", 1, int, TOTAL_ONLY, "phonepose.evaluation.controller",
              zero_default=True),
    MetricDef("availability", "avail. %", 100, float, TOTAL_ONLY, "phonepose.evaluation.controller"),
)
BY_KEY = {m.key: m for m in METRICS}
CONTROLLER_KEYS = ("lag_s", "lag_resolution_s", "jitter_m", "jitter_deg", "still_ticks", "availability")


def keys(scope: str) -> list[str]:
    return [m.key for m in METRICS if scope in m.scopes]


def _clean(v, definition: MetricDef):
    if v is None:
        return 0 if definition.zero_default else None
    if definition.kind is int:
        return int(v)
    v = float(v)
    return v if math.isfinite(v) else None


def normalise(result: dict | None, include_controller: bool = True) -> dict:
    """A tracker's result in the exact layout: every scope, every key of it, in :data:`METRICS` order.
    ``include_controller=False``: without the controller metrics (a result that has none)."""
    out = {}
    for scope in SCOPES:
        src = (result or {}).get(scope) or {}
        out[scope] = {k: _clean(src.get(k), BY_KEY[k]) for k in keys(scope)
                      if include_controller or k not in CONTROLLER_KEYS}
    return out


def flat_columns() -> dict[str, type]:
    """The batch table's metric columns (``<key>_<scope>``) and their types."""
    return {f"{m.key}_{scope}": m.kind for m in METRICS for scope in m.scopes}


def is_int_column(name: str) -> bool | None:
    """True/False for a known metric column, None for another column."""
    kind = flat_columns().get(name)
    return None if kind is None else kind is int


__all__ = ["METRICS", "MetricDef", "SCOPES", "normalise", "keys", "flat_columns", "is_int_column"]
