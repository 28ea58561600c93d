"""Which velocity should T8 carry into the view? The Singer correlation time of FusionConfig.entry_acceleration_time_s.

    python tools/research/entry_velocity.py        # exp2 TRI2 + REC2 trials 1-3, seeds 0-5, and fr1_xyz (~10 s)

Entering the view, T8 moves its output over the switching tick by the VIO velocity carried from the newest
VIO sample (~0.15 s old at the tick) to the tick: v + a tau (1 - exp(-h / tau)), v and a the slope and
acceleration of the quadratic fit through the last 0.3 s of received VIO samples (a first-order Markov,
"Singer", acceleration with correlation time tau; Singer 1970, IEEE Trans. AES 6(4)). The boundary jump at
that tick is the error of that velocity times the tick (0.05 s). This replays the simulator's sessions
(the true motion, the VIO's 1.5 mm white jitter, the stream's arrival times) and prints, per tau, the RMS
and largest velocity error at every tick where the marker enters the view, against the true mean velocity
over the tick. fr2_desk is not included: this replay finds no entry tick in its window (T8's jumps
there are < 0.1 cm with any tau). docs/pipeline.md, "Real hand motion".
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from phonepose.experiments.common import sequence_seed
from phonepose.pipeline.t8.motion import markov_carry_s
from phonepose.record.sim import SimSession, default_config
from phonepose.record.sim.recorded import MotionSpec
from phonepose.record.sim.world import marker_in_view

ROOT = Path(__file__).resolve().parents[2]
TICK_S = 0.05
WINDOW_S = 0.3            # FusionConfig.velocity_window_s
JITTER_M = 0.0015         # [controller_vio] jitter_m
TAUS = (0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.07, 0.1, 0.15, 0.3, np.inf)


def entries(s: SimSession, rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray, float, np.ndarray]]:
    """(fitted velocity, fitted acceleration, h, true mean velocity over the tick) at every entry tick."""
    ticks = np.arange(s.plan.task_start + 0.5, s.plan.task_end, TICK_S)
    inside = marker_in_view(s.world, s.world.T_world_camera.inv() @ s.traj(ticks), s.cfg.marker.size_m)
    t, arrive = s.t_cvio, s.arrive_cvio
    p = s.traj(t).translation + rng.normal(size=(len(t), 3)) * JITTER_M
    out = []
    for i in np.flatnonzero(inside[1:] & ~inside[:-1]) + 1:
        k = int(np.searchsorted(arrive, ticks[i], side="right"))   # samples received by the tick
        t_last = t[k - 1]
        use = t[:k] >= t_last - WINDOW_S
        tt = t[:k][use] - t_last
        A = tt[:, None] ** np.arange(3)
        c = np.linalg.solve(A.T @ A, A.T @ p[:k][use])
        truth = (s.traj(ticks[i:i + 1]).translation[0] - s.traj(ticks[i - 1:i]).translation[0]) / TICK_S
        out.append((c[1], 2 * c[2], float(ticks[i] - t_last), truth))
    return out


def errors(rows: list, tau: float) -> np.ndarray:
    v, a, h, truth = (np.array([r[j] for r in rows]) for j in range(4))
    return np.linalg.norm(truth - v - a * markov_carry_s(h, tau)[:, None], axis=1)


def main() -> int:
    rng = np.random.default_rng(0)
    cfg = default_config()
    groups = {"exp2 TRI2+REC2 s0-5": [], "fr1_xyz": []}
    for seed in range(6):
        for path in ("TRI2", "REC2"):
            for trial in (1, 2, 3):
                groups["exp2 TRI2+REC2 s0-5"] += entries(SimSession("exp2", path, trial,
                                                                    sequence_seed(seed, path, trial), cfg), rng)
    fr1 = MotionSpec(str(ROOT / "tests/data/evo/freiburg1_xyz-groundtruth.txt"), 0.0, 20.0, 1.0)
    groups["fr1_xyz"] = entries(SimSession("exp2", "TRI1", 1, 0, cfg, motion=fr1), rng)
    groups["pooled"] = groups["exp2 TRI2+REC2 s0-5"] + groups["fr1_xyz"]
    print("velocity error at the entry ticks, m/s RMS (largest x 0.05 s, cm)")
    print("tau s    " + "".join(f"{g} (n={len(r)})".rjust(30) for g, r in groups.items()))
    for tau in TAUS:
        cells = []
        for rows in groups.values():
            e = errors(rows, tau)
            cells.append(f"{np.sqrt(np.mean(e ** 2)):.4f} ({e.max() * TICK_S * 100:.2f})".rjust(30))
        print(f"{tau:<9g}" + "".join(cells))
    return 0


if __name__ == "__main__":
    sys.exit(main())
