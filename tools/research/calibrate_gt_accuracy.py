#!/usr/bin/env python
"""How close ``calibrate-gt`` comes to the simulator's truth: the figures in docs/calibration.md.

    python tools/research/calibrate_gt_accuracy.py --sessions DIR [--trials 3] [--seed 0]

Records (once; kept in DIR) the exp2 sessions TRI1/TRI2/REC1/REC2 x trials, runs
``calibrate_gt_session`` on each and prints, per session and as the maximum over all, the error
of the clock offset (ms), of world->camera and of grip->body (deg, mm) against the simulator's
truth (mocap.clock_offset_s, World.T_world_camera, World.hand_eye), each beside its estimated 1σ.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

PATHS = ("TRI1", "TRI2", "REC1", "REC2")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sessions", type=Path, required=True, help="folder for the simulated sessions")
    parser.add_argument("--trials", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    from phonepose.calibration.calibrate_gt import calibrate_gt_session
    from phonepose.record.sim import SimSession, default_config, record_sim

    offset = default_config().mocap.clock_offset_s
    args.sessions.mkdir(exist_ok=True)
    header = ("session", "dt ms", "±", "cam deg", "±", "cam mm", "±", "body deg", "±", "body mm", "±", "sightings")
    print(" | ".join(header))
    rows = []
    for path in PATHS:
        for trial in range(1, args.trials + 1):
            session = args.sessions / f"{path}_{trial:02d}.mcap"
            if not session.exists():
                record_sim(session, scenario="exp2", path=path, trial=trial, seed=args.seed)
            world = SimSession("exp2", path, trial, seed=args.seed).world
            cal = calibrate_gt_session(session)
            s = cal.sigma
            row = (abs(cal.time_offset_s - offset) * 1e3, s["sigma_time_offset_ms"],
                   np.degrees(cal.T_world_camera.angle_to(world.T_world_camera)), s["sigma_world_rotation_deg"],
                   1e3 * cal.T_world_camera.distance_to(world.T_world_camera), s["sigma_world_translation_mm"],
                   np.degrees(cal.T_controller_gt.angle_to(world.hand_eye)), s["sigma_body_rotation_deg"],
                   1e3 * cal.T_controller_gt.distance_to(world.hand_eye), s["sigma_body_translation_mm"])
            rows.append(row)
            print(" | ".join([session.stem, *(f"{float(v):.2f}" for v in row), str(cal.samples)]), flush=True)
    worst = np.max(np.array(rows, dtype=float), axis=0)
    print(" | ".join(["max", *(f"{v:.2f}" for v in worst), ""]))


if __name__ == "__main__":
    main()
