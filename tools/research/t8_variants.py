"""T8 with other FusionConfig values on recorded sessions, cell by cell against the other trackers.

    python tools/research/t8_variants.py exp2-ex-s0 exp2-ex-s1 exp2-ex-s2 -- \\
        "blend_time_s=0.05" "marker_gain=0.85,blend_time_s=0.05"

Plays every session of the given `experiment exp2` outputs back once, with T8 at its defaults and
one T8 per variant side by side (the shared stages run once per session), scored against the
ground truth the run used (its hand_eye/ files for a `--calibrate-hand-eye` run). Prints, per cell of
tools/exp2_cells.py, each variant's mean over the sequences divided by the best of T1-T7 and T7L in
the runs' exp2.json (<= 1.02: best or tied), the number of cells met, r_ATE total against the best of
T1-T7, and T8's largest boundary jump. A development tool (docs/pipeline.md, "T8 cell by cell on
exp2"): ~3 s per session and variant on one core.
"""

from __future__ import annotations

import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # tools/exp2_cells.py

from exp2_cells import PAPER_ROWS, TIE, cells, load_sequences, mean_cell  # noqa: E402

from phonepose.pipeline.t8 import FusedTracker, FusionConfig  # noqa: E402
from phonepose.playback.engine import run_playback  # noqa: E402


def _play(session: Path, variants: dict[str, dict]) -> dict[str, dict]:
    """One playback of ``session`` with one T8 per variant; their metrics by variant name."""
    configs = {name: FusionConfig.from_dict(values) for name, values in variants.items()}
    calibration = session.parent.parent / "hand_eye" / f"{session.stem}.yaml"
    result = run_playback(session, trackers=["T8"], write_outputs=False,
                          gt_calibration=calibration if calibration.exists() else None,
                          tracker_factory=lambda names, math: [FusedTracker(n, c) for n, c in configs.items()])
    return {name: result.metrics["trackers"][name] for name in variants}


def parse_variants(argv: list[str], usage: str) -> tuple[list[str], dict[str, dict]] | None:
    """``INPUT ... -- name=value[,name=value] ...``: the inputs and the variants by name ("defaults" first),
    each checked by FusionConfig before any playback; None (the usage line printed) without ``--`` or inputs."""
    if "--" not in argv or argv.index("--") == 0:
        print(usage.strip().splitlines()[2].strip(), file=sys.stderr)
        return None
    split = argv.index("--")
    variants = {"defaults": {}} | {spec: dict(kv.split("=") for kv in spec.split(",")) for spec in argv[split + 1:]}
    for values in variants.values():
        FusionConfig.from_dict(values)   # a bad name or value stops here, before any playback
    return argv[:split], variants


def main(argv: list[str]) -> int:
    parsed = parse_variants(argv, __doc__)
    if parsed is None:
        return 2
    folders, variants = parsed
    sequences = load_sequences(folders)
    sessions = [Path(f) / "sessions" / f"{s['name']}.mcap" for f in folders
                for s in load_sequences([f])]
    with ProcessPoolExecutor(max_workers=2) as pool:
        played = list(pool.map(_play, sessions, [variants] * len(sessions)))
    table = {}
    for name in variants:
        seqs = [{**s, "trackers": {**s["trackers"], "T8": p[name]}} for s, p in zip(sequences, played, strict=True)]
        table[name] = (cells(seqs), seqs)
    first = next(iter(table.values()))[0]
    print("cell".ljust(30) + "".join(f"{i:>9}" for i in range(len(variants))))
    for k, row in enumerate(first):
        print(f"{row['paths']} {row['scope']} {row['metric']}".ljust(30)
              + "".join(f"{table[v][0][k]['ratio']:9.3f}" for v in variants))
    print("cells met".ljust(30) + "".join(f"{sum(r['ratio'] <= TIE for r in table[v][0]):9d}" for v in variants))
    paths = ("TRI2", "REC2")
    r_ate = []
    jumps = []
    for v in variants:
        seqs = table[v][1]
        best = min(mean_cell(seqs, paths, t, "total", "r_ate_deg") for t in PAPER_ROWS)
        r_ate.append(mean_cell(seqs, paths, "T8", "total", "r_ate_deg") / best)
        jumps.append(max(s["trackers"]["T8"]["total"]["boundary_jump_max_m"] or 0.0 for s in seqs
                         if s["name"][:4] in paths) * 100)
    print("r_ATE total / best T1-T7".ljust(30) + "".join(f"{x:9.3f}" for x in r_ate))
    print("largest jump cm".ljust(30) + "".join(f"{x:9.2f}" for x in jumps))
    print("mean jump RMS cm".ljust(30) + "".join(
        f"{mean_cell(table[v][1], paths, 'T8', 'total', 'boundary_jump_rms_m') * 100:9.2f}" for v in variants))
    for i, name in enumerate(variants):
        print(f"{i}: {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
