"""T8 with other FusionConfig values on single sessions (the real-motion ones), beside T6 and T7L.

    python tools/research/t8_motion_variants.py fr1.mcap:fr1_he.yaml fr1_exact.mcap fr2.mcap:fr2_he.yaml fr2_exact.mcap \\
        -- entry_acceleration_time_s=0 "pull_prediction_deg_per_s=20"

Each SESSION[:CALIBRATION] is played back once (a calibration file from `calibrate-hand-eye`: scored
against that ground truth; none: the session's own) with T6, T7L, T8 at its defaults and one T8 per
variant; prints each one's largest boundary jump and total p_ATE, r_ATE (inside in brackets) and p_RE.
The sessions are those of docs/pipeline.md, "Real hand motion"; tools/research/t8_variants.py does the same on
`experiment exp2` outputs, cell by cell. A development tool.
"""

from __future__ import annotations

import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from t8_variants import parse_variants  # noqa: E402

from phonepose.pipeline.t8 import FusedTracker, FusionConfig  # noqa: E402
from phonepose.pipeline.trackers import make_trackers  # noqa: E402

OTHERS = ["T6", "T7L"]


def _play(arg: str, variants: dict[str, dict]) -> dict:
    from phonepose.playback.engine import run_playback

    session, _, calibration = arg.partition(":")
    configs = {name: FusionConfig.from_dict(values) for name, values in variants.items()}
    result = run_playback(session, trackers=OTHERS, write_outputs=False,
                          gt_calibration=Path(calibration) if calibration else None,
                          tracker_factory=lambda names, math: make_trackers(names, math)
                          + [FusedTracker(n, c) for n, c in configs.items()])
    return result.metrics["trackers"]


def _row(label: str, m: dict) -> str:
    t = m["total"]
    return (f"  {label:>4} jump {t['boundary_jump_max_m'] * 100:5.2f} cm  p_ATE {t['p_ate_m'] * 100:.3f} cm  "
            f"r_ATE {t['r_ate_deg']:.3f} ({m['inside']['r_ate_deg']:.3f}) deg  p_RE {t['p_re_m'] * 100:.3f} cm")


def main(argv: list[str]) -> int:
    parsed = parse_variants(argv, __doc__)
    if parsed is None:
        return 2
    sessions, variants = parsed
    with ProcessPoolExecutor(max_workers=2) as pool:
        played = list(pool.map(_play, sessions, [variants] * len(sessions)))
    for session, metrics in zip(sessions, played, strict=True):
        print(Path(session.partition(":")[0]).name)
        for i, name in enumerate(variants):
            print(_row(str(i), metrics[name]))
        for name in OTHERS:
            print(_row(name, metrics[name]))
    for i, name in enumerate(variants):
        print(f"{i}: {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
