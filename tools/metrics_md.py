"""A Markdown table of playback metrics.json files: p_ATE, r_ATE, p_RE (inside / outside / total), jump, lag, availability.

    python tools/metrics_md.py pb_fr1_he/metrics.json pb_fr2_he/metrics.json

One table per file, one row per tracker, the best total of T1-T8 per column in bold. tools/docs_results.py renders
docs/pipeline.md's "Real hand motion" tables with the same function, so the two cannot differ.
"""

from __future__ import annotations

import json
import sys

HEADER = ("| tracker | p_ATE cm in / out / total | r_ATE deg in / out / total | p_RE cm in / out / total "
          "| jump max cm | lag ms | avail. % |",
          "|---|---|---|---|---:|---:|---:|")


def _f(v, scale: float, digits: int = 2) -> str:
    return "–" if v is None else f"{v * scale:.{digits}f}"


def table(doc: dict) -> list[str]:
    """The whole table (header included: a caller adds nothing) of a metrics.json document's trackers."""
    trackers = doc["trackers"]
    best = {k: min((m["total"][k] for m in trackers.values() if m["total"][k] is not None), default=None)
            for k in ("p_ate_m", "r_ate_deg", "p_re_m")}
    lines = list(HEADER)
    for name, m in trackers.items():
        cells = []
        for key, scale in (("p_ate_m", 100), ("r_ate_deg", 1), ("p_re_m", 100)):
            parts = [_f(m[s][key], scale) for s in ("inside", "outside", "total")]
            if m["total"][key] is not None and m["total"][key] == best[key]:
                parts[2] = f"**{parts[2]}**"
            cells.append(" / ".join(parts))
        t = m["total"]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {_f(t.get('boundary_jump_max_m'), 100)} | "
                     f"{_f(t.get('lag_s'), 1000, 0)} | {_f(t.get('availability'), 100, 1)} |")
    return lines


def main(paths: list[str]) -> None:
    for path in paths:
        with open(path) as f:
            doc = json.load(f)
        print(f"\n{path}\n")
        print("\n".join(table(doc)))


if __name__ == "__main__":
    main(sys.argv[1:])
