"""A Markdown table of playback metrics.json files: p_ATE, r_ATE, p_RE (inside / outside / total), lag, availability.

    python tools/metrics_md.py pb_fr1_he/metrics.json pb_fr2_he/metrics.json

One row per tracker and file (docs/pipeline.md, "Real hand motion"); the best total of T1-T8 per file in bold.
"""

from __future__ import annotations

import json
import sys


def _f(v, scale: float, digits: int = 2) -> str:
    return "–" if v is None else f"{v * scale:.{digits}f}"


def table(path: str) -> list[str]:
    doc = json.loads(open(path).read())
    trackers = doc["trackers"]
    best = {k: min((m["total"][k] for m in trackers.values() if m["total"][k] is not None), default=None)
            for k in ("p_ate_m", "r_ate_deg", "p_re_m")}
    lines = []
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
        print(f"\n{path}\n")
        print("| tracker | p_ATE cm in / out / total | r_ATE deg | p_RE cm | jump max cm | lag ms | avail. % |")
        print("|---|---|---|---|---:|---:|---:|")
        print("\n".join(table(path)))


if __name__ == "__main__":
    main(sys.argv[1:])
