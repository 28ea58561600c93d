"""How well can any tracker know the orientation at a tick, when the controller's streams arrive late?

    python tools/research/prediction_bound.py            # exp2 TRI2 + REC2, trials 1-3, seeds 0-2 (18 sessions)

The controller's IMU (like its VIO) reaches the display ~0.12 s plus Wi-Fi jitter after capture
(`[network]`), so at a tick the newest gyro sample is ~0.15 s old. This replays the simulator's
sessions with exact knowledge (the true orientation at the newest received gyro sample, no VIO
or marker error) and predicts to the tick the way T8 does outside the view (the mean gyro rate
of the last 0.15 s, held, and decaying with the correlation time T8 estimates: FusionConfig.gyro_rate_*),
and with the *true* angular rate held instead. The RMS angle to the truth over
the task's ticks, inside / outside the view / total, is a floor for T8's r_ATE outside the view,
where nothing fresher than the gyro exists (docs/pipeline.md, "Why r_ATE stops at ~0.7x").
"""

from __future__ import annotations

import sys

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.experiments.common import sequence_seed
from phonepose.pipeline.t8 import FusionConfig
from phonepose.pipeline.t8.motion import RateCorrelation, markov_carry_s
from phonepose.record.sim import SimSession, default_config
from phonepose.record.sim.world import marker_in_view

GYRO_WINDOW_S = 0.15     # FusionConfig.gyro_window_s
TICK_HZ = 20.0


def session_errors(path: str, trial: int, seed: int) -> dict[str, np.ndarray]:
    s = SimSession("exp2", path, trial, sequence_seed(seed, path, trial),
                   default_config().replace(mocap={"exact": True}))
    ticks = np.arange(s.plan.task_start, s.plan.task_end, 1 / TICK_HZ)
    order = np.argsort(s.arrive_imu, kind="stable")
    arrive, stamps, gyro = s.arrive_imu[order], s.t_imu[order], s.gyro[order]
    newest = np.maximum.accumulate(stamps)            # the newest stamp received by each arrival
    k = np.searchsorted(arrive, ticks, side="right") - 1
    ok = k >= 0
    ticks, t_g = ticks[ok], newest[k[ok]]
    truth_tick, truth_g = s.traj(ticks).rotation, s.traj(t_g).rotation
    h = (ticks - t_g)[:, None]
    held = np.array([gyro[(stamps >= tg - GYRO_WINDOW_S) & (stamps <= tg)].mean(axis=0) for tg in t_g])
    # the true body rate at the newest sample (finite difference of the true orientation)
    eps = 1e-3
    true_rate = (s.traj(t_g - eps).rotation.inv() * s.traj(t_g + eps).rotation).as_rotvec() / (2 * eps)
    inside = marker_in_view(s.world, s.world.T_world_camera.inv() @ s.traj(ticks), s.cfg.marker.size_m)

    def err(rate: np.ndarray) -> np.ndarray:
        return np.degrees((truth_g * Rotation.from_rotvec(rate * h)).inv().__mul__(truth_tick).magnitude())

    # the mean rate decaying with the correlation time T8 estimates online (FusionConfig.gyro_rate_*), fed the
    # same mean rates tick by tick
    cfg = FusionConfig()
    est = RateCorrelation(cfg.gyro_window_s, cfg.gyro_rate_adapt_s, cfg.gyro_rate_adapt_min_s, cfg.gyro_rate_time_s)
    carried = np.empty_like(h)      # how long the rate acts over each tick's h (T8's markov_carry_s)
    for i, (tg, rate) in enumerate(zip(t_g, held, strict=True)):
        tau = est.update(float(tg), rate) if i == 0 or tg != t_g[i - 1] else est.tau   # once per new sample
        carried[i] = markov_carry_s(float(h[i, 0]), tau)
    return {"held_gyro": err(held), "decaying_gyro": err(held * carried / np.where(h > 0, h, 1.0)),
            "true_rate": err(true_rate), "inside": inside, "age": h.ravel()}


def main(seeds: list[int]) -> None:
    rows: dict[str, dict[str, list[float]]] = {kind: {"inside": [], "outside": [], "total": []}
                                               for kind in ("held_gyro", "decaying_gyro", "true_rate")}
    ages = []
    for seed in seeds:
        for path in ("TRI2", "REC2"):
            for trial in (1, 2, 3):
                e = session_errors(path, trial, seed)
                ages.append(e["age"])
                for kind in rows:
                    for scope, use in (("inside", e["inside"]), ("outside", ~e["inside"]),
                                       ("total", np.ones_like(e["inside"]))):
                        if use.any():
                            rows[kind][scope].append(float(np.sqrt(np.mean(e[kind][use] ** 2))))
    age = np.concatenate(ages)
    print(f"{len(rows['held_gyro']['total'])} sessions; newest gyro sample at a tick is {age.mean() * 1e3:.0f} ms old "
          f"on average ({np.percentile(age, 5) * 1e3:.0f}-{np.percentile(age, 95) * 1e3:.0f} ms, 5-95 %)")
    print("mean per-session RMS orientation error at the tick, deg: inside / outside / total")
    for kind, label in (("held_gyro", "exact orientation at the newest gyro sample + mean rate of 0.15 s"),
                        ("decaying_gyro", "the same, the rate decaying with T8's estimated correlation time"),
                        ("true_rate", "exact orientation and the exact instantaneous rate (tremor included), held")):
        print(f"  {label}: " + " / ".join(f"{np.mean(rows[kind][s]):.2f}" for s in ("inside", "outside", "total")))


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]] or [0, 1, 2])
