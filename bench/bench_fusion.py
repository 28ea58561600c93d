"""T8 (the fused tracker) per-tick cost, beside T7 and the shared stages, in one run.

A simulated TRI2 session (trial 1, seed 0) is recorded once; its Observations (decode, marker
recognition, anchor mapping, stamped VIO samples) are built once by the shared stages, then
each tracker steps over all of them, three times, best run kept. Reported as ratios to T7 and to the
shared stages of the same run (a loaded machine scales all of them). Target: T8 <= 0.4 ms per
tick (docs/performance.md#per-tick-cost-of-the-trackers).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import cv2


def _observations(session: Path) -> tuple[list, float]:
    from phonepose.pipeline.shared import SharedStages
    from phonepose.playback.scheduler import TickScheduler
    from phonepose.session import SessionReader
    from phonepose.session.context import read_context

    with SessionReader(session) as reader:
        context = read_context(reader)
        stages = SharedStages(context)
        stages.map_vio_samples = True
        t0 = time.perf_counter()
        obs = [stages.process(tick) for tick in TickScheduler(reader, context)]
        return obs, (time.perf_counter() - t0) / max(len(obs), 1)


def _per_tick(tracker, obs: list, repeats: int = 3) -> float:
    best = float("inf")
    for _ in range(repeats):
        tracker.reset()
        t0 = time.perf_counter()
        for o in obs:
            tracker.step(o)
        best = min(best, (time.perf_counter() - t0) / len(obs))
    return best


def main() -> dict:
    from phonepose.pipeline.trackers import make_tracker
    from phonepose.record.sim import record_sim

    cv2.setNumThreads(1)
    with tempfile.TemporaryDirectory() as tmp:
        session = Path(tmp) / "TRI2_01.mcap"
        record_sim(session, scenario="exp2", path="TRI2", trial=1, seed=0)
        obs, shared_s = _observations(session)
    out = {"ticks": len(obs), "shared_stages_ms_per_tick": shared_s * 1e3}
    for name in ("T7", "T7L", "T8"):
        out[f"{name}_ms_per_tick"] = _per_tick(make_tracker(name), obs) * 1e3
    out["t8_vs_t7"] = out["T8_ms_per_tick"] / out["T7_ms_per_tick"]
    out["t8_vs_shared_stages"] = out["T8_ms_per_tick"] / out["shared_stages_ms_per_tick"]
    print(f"fusion: {out['ticks']} ticks; shared stages {out['shared_stages_ms_per_tick']:.2f} ms/tick; "
          f"T7 {out['T7_ms_per_tick']:.3f}, T7L {out['T7L_ms_per_tick']:.3f}, T8 {out['T8_ms_per_tick']:.3f} ms/tick "
          f"(T8 = {out['t8_vs_t7']:.1f}x T7, {out['t8_vs_shared_stages']:.2f}x the shared stages)")
    return out


if __name__ == "__main__":
    main()
