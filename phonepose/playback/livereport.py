"""The live trackers' figures in a session (``record live -t``): MCAP metadata :data:`METADATA_NAME`, one key
``report`` holding JSON (phonepose.record.live.tracking writes it; ``info`` and ``playback --check-live`` read
it). Light on purpose: ``info`` imports it.
"""

from __future__ import annotations

import json
import os

from phonepose.errors import SessionContentError

METADATA_NAME = "phonepose.live_tracking"


def live_report(path: str | os.PathLike) -> dict | None:
    """The live trackers' figures stored in a session (None if it has none or they cannot be read)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            found = [dict(meta.metadata) for meta in make_reader(f).iter_metadata() if meta.name == METADATA_NAME]
    except Exception:  # noqa: BLE001 - a damaged or foreign file: no figures, said by the caller
        return None
    if not found:
        return None
    try:
        report = json.loads(found[-1]["report"])
        _check(report)
    except (KeyError, TypeError, ValueError, AttributeError):
        raise SessionContentError(f"{path}: its live tracking figures (MCAP metadata {METADATA_NAME}) are "
                                  "damaged") from None
    return report


def _is_percentiles(p) -> bool:
    return p is None or (isinstance(p, dict) and all(isinstance(p.get(q), (int, float)) for q in ("p50", "p99", "max")))


def _check(r) -> None:
    """The report's shape, every key that is read (a foreign or edited file: one clear line, not a traceback)."""
    ok = (isinstance(r, dict) and isinstance(r["trackers"], list) and all(isinstance(n, str) for n in r["trackers"])
          and isinstance(r["rate_hz"], (int, float)) and r["rate_hz"] > 0 and isinstance(r["correction_math"], str)
          and all(r[k] is None or isinstance(r[k], int) for k in ("first_tick_ns", "last_tick_ns"))
          and isinstance(r["ticks"], int) and isinstance(r["dropped"], int) and isinstance(r["stopped"], str)
          and isinstance(r["late"], dict) and all(isinstance(n, int) for n in r["late"].values())
          and _is_percentiles(r["stages_ms"]) and isinstance(r["per_tracker"], dict))
    for t in r["per_tracker"].values() if ok else ():
        ok = ok and isinstance(t, dict) and isinstance(t["estimates"], int) and isinstance(t["overruns"], int) \
            and isinstance(t["failed"], str) \
            and all(_is_percentiles(t[k]) for k in ("compute_ms", "input_to_publish_ms", "tick_to_publish_ms"))
    if not ok:
        raise ValueError("malformed")


def _fmt(p: dict | None) -> str:
    return "n/a" if p is None else f"{p['p50']:.1f} / {p['p99']:.1f} / {p['max']:.1f}"


def summary_lines(r: dict) -> list[str]:
    """The closing summary's lines for a report (:meth:`LiveTracker.report`)."""
    out = [f"live tracking: {r['ticks']} ticks at {r['rate_hz']:g} Hz, shared stages p50/p99/max "
           f"{_fmt(r['stages_ms'])} ms"]
    for name, t in r["per_tracker"].items():
        line = (f"live {name}: {t['estimates']} estimates; compute {_fmt(t['compute_ms'])} ms, input to publication "
                f"{_fmt(t['input_to_publish_ms'])} ms, tick to publication {_fmt(t['tick_to_publish_ms'])} ms "
                "(p50 / p99 / max)")
        if t["overruns"]:
            line += f"; {t['overruns']} tick(s) over the period"
        if t["failed"]:
            line += f"; stopped: {t['failed']}"
        out.append(line)
    if r["dropped"]:
        out.append(f"live tracking dropped {r['dropped']} input message(s): estimates may differ from playback's")
    if r["late"]:
        out.append("live tracking took late messages (after the hold-back): "
                   + ", ".join(f"{k} {n}" for k, n in sorted(r["late"].items())))
    if r["stopped"]:
        out.append(f"live tracking stopped: {r['stopped']}")
    return out
