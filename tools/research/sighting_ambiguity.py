"""How a marker sighting's orientation error grows with its IPPE ambiguity ratio (FusionConfig.rotation_ambiguity_ref).

    printf '[mocap]\\nexact = true\\n' > exact.toml
    phonepose record sim --scenario exp1 --seed 7 --config exact.toml --out exp1x7.mcap
    python tools/research/sighting_ambiguity.py exp1x7.mcap

For every tick with a new camera frame and a recognised marker, the controller's orientation from the marker
(the shared stages' own, as every tracker gets it) against the ground truth at the tick; grouped by the
sighting's ambiguity ratio (the other IPPE solution's reprojection error over the chosen one's), the RMS error
and RMS x sqrt(median ratio) of each group (constant where the error goes as 1 / sqrt(ratio)), and the median
ratio. Use a session with exact ground truth (the simulator's mocap errors off): the default mocap body's 11 deg
offset would be most of the error. A development tool (docs/pipeline.md, "The sighting's ambiguity").
"""

from __future__ import annotations

import argparse
from pathlib import Path

EDGES = [1, 3, 5, 7, 10, 14, 20, 30, 50, 100, float("inf")]


def sightings(session: Path):
    """(ambiguity ratio, orientation error deg) of each new sighting in ``session``."""
    import cv2
    import numpy as np

    from phonepose.pipeline.shared import SharedStages
    from phonepose.playback.scheduler import TickScheduler
    from phonepose.session import SessionReader
    from phonepose.session.context import read_context

    cv2.setNumThreads(1)
    rows = []
    with SessionReader(session) as reader:
        context = read_context(reader)
        stages = SharedStages(context)
        for tick, gt in TickScheduler(reader, context).with_truth():
            m = stages.process(tick).marker
            if m is None or m.T_dvio_controller is None or gt is None or tick.new_frame is None:
                continue
            rows.append((m.ambiguity_ratio, float(np.degrees((m.T_dvio_controller.rotation * gt.rotation.inv()).magnitude()))))
    return np.array(rows).reshape(-1, 2)


def main(argv: list[str] | None = None) -> int:
    import numpy as np

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sessions", type=Path, nargs="+", help="sessions with exact ground truth")
    args = ap.parse_args(argv)
    a = np.concatenate([sightings(s) for s in args.sessions])
    print(f"{len(a)} sightings; ambiguity ratio median {np.median(a[:, 0]):.1f} "
          f"(10 % {np.percentile(a[:, 0], 10):.1f}, 90 % {np.percentile(a[:, 0], 90):.1f})")
    print("ratio          sightings  RMS deg  RMS x sqrt(median ratio)")
    for lo, hi in zip(EDGES[:-1], EDGES[1:], strict=True):
        k = (a[:, 0] >= lo) & (a[:, 0] < hi)
        if k.sum() > 5:
            rms = float(np.sqrt(np.mean(a[k, 1] ** 2)))
            print(f"{lo:>5g} - {hi:<6g} {int(k.sum()):9d}  {rms:7.2f}  {rms * np.sqrt(np.median(a[k, 0])):7.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
