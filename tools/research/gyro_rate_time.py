"""The correlation time T8 estimates for its gyro's held rate (FusionConfig.gyro_rate_*), per session.

    python tools/research/gyro_rate_time.py fr1_exact.mcap fr2_exact.mcap exp2-ex-s0/TRI2_01.mcap ...

Each session is played back with T8 alone (no outputs written); after every tick the estimator's tau is
kept, and the median and the 10-90 % range over the last three quarters of the ticks are printed (the first
quarter includes the minimum history, before which tau is the configured initial value). docs/pipeline.md,
"The gyro's held rate", quotes these for the real-motion sessions and exp2's. A development tool.
"""

from __future__ import annotations

import sys

import numpy as np

from phonepose.pipeline.t8 import FusedTracker
from phonepose.playback.engine import run_playback


class _Traced(FusedTracker):
    def reset(self) -> None:
        super().reset()
        self.taus: list[float] = []

    def step(self, obs):
        out = super().step(obs)
        self.taus.append(self._rate_correlation.tau)
        return out


def main(sessions: list[str]) -> None:
    for session in sessions:
        tracker = _Traced("T8")
        run_playback(session, trackers=["T8"], write_outputs=False, tracker_factory=lambda names, math, t=tracker: [t])
        taus = np.array(tracker.taus[len(tracker.taus) // 4:])
        print(f"{session}: tau median {np.median(taus):.3f} s, 10-90 % {np.percentile(taus, 10):.3f}-"
              f"{np.percentile(taus, 90):.3f} s over {taus.size} ticks")


if __name__ == "__main__":
    if len(sys.argv) < 2 or sys.argv[1] in ("-h", "--help"):
        print(__doc__)
        sys.exit(0 if len(sys.argv) > 1 else 2)
    main(sys.argv[1:])
