"""T8 against every other tracker, cell by cell, from `phonepose experiment exp2` outputs.

    python tools/exp2_cells.py exp2-he-s0 exp2-he-s1 exp2-he-s2      # --calibrate-hand-eye runs, seeds 0-2
    python tools/exp2_cells.py exp2-ex-s0 exp2-ex-s1 exp2-ex-s2      # --exact-gt runs

Reads each folder's exp2.json and averages the per-sequence RMSE values over every sequence of the
given runs, as Tables 5 and 6 do: TRI2 + REC2 (inside / outside / total) and TRI1 + REC1 (total,
all in view). Each cell prints T8, the best of T1-T7 and T7L with its name, and the ratio T8 / best;
"ok" marks T8 best or tied within 2 %. The last lines give r_ATE total against the best of T1-T7
(the goal: <= 0.6x with calibrated ground truth) and T8's largest boundary jump (< 1 cm).
Exit 1 when a cell misses, so a script can use it.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

OTHERS = ("T1", "T2", "T3", "T4", "T5", "T6", "T7", "T7L")
PAPER_ROWS = ("T1", "T2", "T3", "T4", "T5", "T6", "T7")
METRICS = (("p_ate_m", "p_ATE cm", 100.0), ("r_ate_deg", "r_ATE deg", 1.0), ("p_re_m", "p_RE cm", 100.0))
GROUPS = ((("TRI2", "REC2"), ("inside", "outside", "total")), (("TRI1", "REC1"), ("total",)))
TIE = 1.02


def load_sequences(folders: list[str]) -> list[dict]:
    sequences = []
    for folder in folders:
        summary = json.loads((Path(folder) / "exp2.json").read_text())
        sequences += [{"name": name, "seed": summary["seed"], **m} for name, m in summary["sequences"].items()]
    return sequences


def mean_cell(sequences: list[dict], paths: tuple[str, ...], tracker: str, scope: str, key: str) -> float | None:
    values = [s["trackers"][tracker][scope].get(key) for s in sequences
              if s["name"].split("_")[0] in paths and tracker in s["trackers"]]
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def cells(sequences: list[dict]) -> list[dict]:
    rows = []
    for paths, scopes in GROUPS:
        n = sum(s["name"].split("_")[0] in paths for s in sequences)
        for scope in scopes:
            for key, label, scale in METRICS:
                t8 = mean_cell(sequences, paths, "T8", scope, key)
                others = {t: v for t in OTHERS if (v := mean_cell(sequences, paths, t, scope, key)) is not None}
                best = min(others, key=others.get)
                rows.append({"paths": "+".join(paths), "n": n, "scope": scope, "metric": label, "t8": t8 * scale,
                             "best": best, "best_value": others[best] * scale, "ratio": t8 / others[best],
                             "ok": t8 <= others[best] * TIE})
    return rows


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__.strip().splitlines()[0] + "\nusage: python tools/exp2_cells.py EXP2_OUT...", file=sys.stderr)
        return 2
    sequences = load_sequences(argv)
    rows = cells(sequences)
    print(f"{'paths':<10} {'n':>2} {'scope':<8} {'metric':<10} {'T8':>7} {'best other':>14} {'ratio':>6}")
    for r in rows:
        print(f"{r['paths']:<10} {r['n']:>2} {r['scope']:<8} {r['metric']:<10} {r['t8']:>7.3f} "
              f"{r['best']:>5} {r['best_value']:>8.3f} {r['ratio']:>6.3f} {'ok' if r['ok'] else 'MISS'}")
    paths = ("TRI2", "REC2")
    t8 = mean_cell(sequences, paths, "T8", "total", "r_ate_deg")
    paper = {t: mean_cell(sequences, paths, t, "total", "r_ate_deg") for t in PAPER_ROWS}
    best = min(paper, key=paper.get)
    jumps = [s["trackers"]["T8"]["total"].get("boundary_jump_max_m") for s in sequences
             if s["name"].split("_")[0] in paths]
    jump = max(j for j in jumps if j is not None)
    print(f"r_ATE total (TRI2+REC2): T8 {t8:.3f} deg = {t8 / paper[best]:.3f}x the best of T1-T7 ({best} "
          f"{paper[best]:.3f} deg)")
    print(f"T8 largest boundary jump: {jump * 100:.2f} cm")
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
