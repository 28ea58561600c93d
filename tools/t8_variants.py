"""T8 with other FusionConfig values on recorded sessions, against the other trackers of an exp2 run.

    python tools/t8_variants.py EXP2_OUT "blend_time_s=0.05" "marker_gain=0.85"

Plays each TRI2/REC2 session of EXP2_OUT (an `experiment exp2` output) back with T8 only, once with the
defaults and once per variant, and prints per cell the variant's mean over the sequences divided by the
best of T1-T7 and T7L in that run's exp2.json (<= 1.02: best or tied), and T8's largest boundary jump.
A development tool (docs/pipeline.md, "T8 cell by cell on exp2"): ~40 s per session and variant.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from phonepose.pipeline.fusion import FusedTracker, FusionConfig
from phonepose.playback.engine import run_playback

OTHERS = ("T1", "T2", "T3", "T4", "T5", "T6", "T7", "T7L")
KEYS = ("p_ate_m", "r_ate_deg", "p_re_m")


def t8_metrics(session: Path, values: dict) -> dict:
    config = FusionConfig.from_dict(values)
    result = run_playback(session, trackers=["T8"], write_outputs=False,
                          tracker_factory=lambda names, math: [FusedTracker("T8", config)])
    return result.metrics["trackers"]["T8"]


def main(argv: list[str]) -> None:
    out = Path(argv[0])
    variants = {"defaults": {}}
    for spec in argv[1:]:
        variants[spec] = dict(kv.split("=") for kv in spec.split(","))
    reference = json.loads((out / "exp2.json").read_text())["sequences"]
    sessions = sorted(p for p in (out / "sessions").glob("*.mcap") if p.stem[:4] in ("TRI2", "REC2"))
    results = {name: {s.stem: t8_metrics(s, values) for s in sessions} for name, values in variants.items()}
    names = [s.stem for s in sessions]
    print("cell".ljust(20) + "".join(n.rjust(22) for n in variants))
    for scope in ("inside", "outside", "total"):
        for key in KEYS:
            best = min(np.mean([reference[n]["trackers"][t][scope][key] for n in names]) for t in OTHERS)
            print(f"{scope} {key}".ljust(20) + "".join(
                f"{np.mean([results[v][n][scope][key] for n in names]) / best:22.3f}" for v in variants))
    print("jump max cm".ljust(20) + "".join(
        f"{max(results[v][n]['total']['boundary_jump_max_m'] for n in names) * 100:22.2f}" for v in variants))


if __name__ == "__main__":
    main(sys.argv[1:])
