"""T8 (the fused tracker) per-tick cost, beside T7 and the shared stages, in one run.

A simulated TRI2 session (trial 1, seed 0) is recorded once; its Observations (decode, marker
recognition, anchor mapping, stamped VIO samples) are built once by the shared stages, then
each tracker steps over all of them, three times, best run kept. Reported as ratios to T7 and to the
shared stages of the same run (a loaded machine scales all of them). Target: T8 <= 0.2 ms CPU per
tick, judged by `python -m bench ticks` (docs/performance.md#per-tick-cost-of-the-trackers).

Where T8's time goes, in the same run: T8 with its accelerometer prediction off (``accel_prediction``
False: the VIO fit alone), and the accelerometer fit itself (``fit_accel_motion``, the smoothing and
double integral over the window) on the arguments of every fit of a run, against the same fits on the
newest third of each window: what an integral kept between ticks, recomputed only over new samples, could
save at most.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import cv2
import numpy as np


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


def _fit_calls(obs: list) -> list[tuple]:
    """The arguments of every accelerometer fit of one T8 run (copied: they are views of its rings)."""
    import phonepose.pipeline.t8.tracker as t8
    from phonepose.pipeline.trackers import make_tracker

    calls: list[tuple] = []
    fit = t8.fit_accel_motion

    def recording(*args):
        calls.append(tuple(a.copy() if isinstance(a, np.ndarray) else a for a in args))
        return fit(*args)

    t8.fit_accel_motion = recording
    try:
        tracker = make_tracker("T8")
        for o in obs:
            tracker.step(o)
    finally:
        t8.fit_accel_motion = fit
    return calls


def _newest_third(call: tuple) -> tuple | None:
    """A fit's arguments cut to the newest third of its IMU samples and the VIO samples they cover."""
    cfg, ts, positions, t_k, a_k = call
    k = len(t_k) * 2 // 3
    lo = int(ts.searchsorted(t_k[k], side="left"))
    if len(ts) - lo < cfg.accel_fit_degree + 2:
        return None
    return cfg, ts[lo:], positions[lo:], t_k[k:], a_k[k:]


def _fit_us(calls: list, repeats: int = 5) -> float:
    from phonepose.pipeline.t8.motion import fit_accel_motion

    best = float("inf")
    for _ in range(repeats):
        c0 = time.thread_time()
        for call in calls:
            fit_accel_motion(*call)
        best = min(best, (time.thread_time() - c0) / len(calls))
    return best * 1e6


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
    import dataclasses

    from phonepose.pipeline.t8 import FusedTracker, FusionConfig

    without = FusedTracker(config=dataclasses.replace(FusionConfig(), accel_prediction=False))
    out["T8_no_accel_ms_per_tick"] = _per_tick(without, obs) * 1e3
    out["t8_accel_share"] = 1 - out["T8_no_accel_ms_per_tick"] / out["T8_ms_per_tick"]
    calls = _fit_calls(obs)
    pairs = [(c, short) for c in calls if (short := _newest_third(c)) is not None]
    out["accel_fits"] = len(calls)
    out["accel_fit_us"] = _fit_us([c for c, _ in pairs])
    out["accel_fit_third_us"] = _fit_us([short for _, short in pairs])
    out["accel_fit_third_vs_full"] = out["accel_fit_third_us"] / out["accel_fit_us"]
    out["t8_vs_t7"] = out["T8_ms_per_tick"] / out["T7_ms_per_tick"]
    out["t8_vs_shared_stages"] = out["T8_ms_per_tick"] / out["shared_stages_ms_per_tick"]
    print(f"fusion: {out['ticks']} ticks; shared stages {out['shared_stages_ms_per_tick']:.2f} ms/tick; "
          f"T7 {out['T7_ms_per_tick']:.3f}, T7L {out['T7L_ms_per_tick']:.3f}, T8 {out['T8_ms_per_tick']:.3f} ms/tick "
          f"(T8 = {out['t8_vs_t7']:.1f}x T7, {out['t8_vs_shared_stages']:.2f}x the shared stages)")
    print(f"fusion: T8 without the accelerometer {out['T8_no_accel_ms_per_tick']:.3f} ms/tick (the accelerometer "
          f"{out['t8_accel_share']:.0%} of T8); {out['accel_fits']} accelerometer fits, {out['accel_fit_us']:.1f} us "
          f"each, {out['accel_fit_third_us']:.1f} us on the newest third of each window "
          f"({out['accel_fit_third_vs_full']:.2f}x)")
    return out


if __name__ == "__main__":
    main()
