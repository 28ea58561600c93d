"""T8's outputs and cost on recorded sessions: keep them, or compare them with kept ones (speed work).

    python tools/t8_outputs.py save   BASE_DIR s1.mcap s2.mcap ...   # the outputs of this checkout
    python tools/t8_outputs.py compare BASE_DIR s1.mcap s2.mcap ...  # max difference to them, ms per tick
    python tools/t8_outputs.py compare BASE_DIR --code OLD s1.mcap   # the phonepose package in OLD instead

The shared stages run once per session (as `bench/bench_fusion.py` builds its Observations); T8 then steps
over every tick three times, the best time kept. Each output (quaternion x y z w, position; NaN where
T8 gave none) is saved as BASE_DIR/<session stem>.npy; `compare` prints, per session, whether the outputs
are the same to the byte and their largest difference. `--code OLD` imports phonepose from OLD (e.g.
`git archive <rev> phonepose | tar -x -C OLD`), to time two versions side by side in alternating runs.
docs/performance.md, "Issue 23, fifth round", used it on exp1, TRI2, REC2, an exact-GT TRI1, fr1_xyz and
fr2_desk sessions (`phonepose record sim ...`).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def _outputs(session: Path) -> tuple[object, float, int]:
    import cv2
    import numpy as np

    from phonepose.pipeline.shared import SharedStages
    from phonepose.pipeline.t8 import FusedTracker
    from phonepose.playback.scheduler import TickScheduler
    from phonepose.session import SessionReader
    from phonepose.session.context import read_context

    cv2.setNumThreads(1)
    with SessionReader(session) as reader:
        context = read_context(reader)
        stages = SharedStages(context)
        stages.map_vio_samples = True
        obs = [stages.process(tick) for tick in TickScheduler(reader, context)]
    tracker, best, out = FusedTracker(), float("inf"), []
    for _ in range(3):
        tracker.reset()
        t0 = time.perf_counter()
        out = [tracker.step(o) for o in obs]
        best = min(best, time.perf_counter() - t0)
    rows = np.array([np.r_[p.quat_xyzw, p.translation] if p is not None else np.full(7, np.nan) for p in out])
    return rows, best / max(len(obs), 1) * 1e3, len(obs)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=("save", "compare"))
    ap.add_argument("base", type=Path, help="folder of the kept outputs")
    ap.add_argument("sessions", type=Path, nargs="+")
    ap.add_argument("--code", type=Path, help="import phonepose from this folder instead of the checkout's")
    args = ap.parse_args(argv)
    if args.code is not None:
        sys.path.insert(0, str(args.code.resolve()))
    import numpy as np

    import phonepose
    print(f"phonepose from {Path(phonepose.__file__).parent}")
    args.base.mkdir(parents=True, exist_ok=True)
    worst = 0.0
    for session in args.sessions:
        rows, ms, ticks = _outputs(session)
        kept = args.base / f"{session.stem}.npy"
        if args.mode == "save":
            np.save(kept, rows)
            print(f"{session.stem}: {ticks} ticks, T8 {ms:.3f} ms per tick; kept in {kept}")
            continue
        base = np.load(kept)
        same = base.shape == rows.shape and base.tobytes() == rows.tobytes()
        diff = float(np.nanmax(np.abs(base - rows))) if base.shape == rows.shape else float("inf")
        worst = max(worst, diff)
        print(f"{session.stem}: {ticks} ticks, T8 {ms:.3f} ms per tick; same bytes: {same}, largest difference {diff:.3g}")
    if args.mode == "compare":
        print(f"largest difference over all sessions: {worst:.3g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
