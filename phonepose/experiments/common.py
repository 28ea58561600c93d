"""Shared pieces of the experiment runners: one sequence = record (simulator) + playback."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from phonepose.workers import worker_pool


@dataclass(frozen=True)
class SequenceJob:
    name: str              # e.g. "TRI2_01"
    scenario: str          # exp1 | exp2
    path: str | None       # TRI1.. for exp2
    trial: int
    seed: int
    out_dir: str
    config: str | None = None
    correction_math: str = "paper"
    rerun: bool = False
    hand_eye: bool = False   # calibrate the session's hand-eye from itself and score in the phone's frame
    calibrate_gt: bool = False   # calibrate-gt the session from itself: clock, world and grip (docs/calibration.md)
    final_dir: str | None = None   # where out_dir (a temporary) lands when the experiment is complete
    exact_gt: bool = False   # [mocap] exact = true: ground truth = the phone's true pose (docs/simulation.md)
    trackers: tuple[str, ...] = ()   # a user's trackers beside T1-T8 (package.module:Class or an entry point)


def user_trackers(refs: Iterable[str]) -> tuple[tuple[str, ...], list[str]]:
    """The user's trackers an experiment runs beside T1-T8: their references and their names (the
    table rows), each built once here so a wrong one fails before the first sequence."""
    from phonepose.errors import ConfigError
    from phonepose.pipeline.trackers import check_unique_names, is_user_tracker, make_tracker, split_names

    refs = tuple(split_names(list(refs)))
    builtin = [r for r in refs if not is_user_tracker(r)]
    if builtin:
        raise ConfigError(f"{{trackers}} {builtin[0]}: the experiments always run T1-T8; {{trackers}} adds your own "
                          "(package.module:ClassName or an installed entry point)", parameter="trackers",
                          value=builtin[0])
    names = [make_tracker(r).name for r in refs]   # each name checked (docs/writing-a-tracker.md)
    check_unique_names(names, refs)
    return refs, names


def sequence_seed(base_seed: int, path: str | None, trial: int) -> int:
    """A distinct, reproducible seed per sequence (stable across runs and Python versions)."""
    code = sum((i + 1) * ord(c) for i, c in enumerate(path or "exp1"))
    return int(base_seed) * 100_003 + code * 31 + int(trial)


def run_sequence(job: SequenceJob, record_progress: Callable[[int, int | None], None] | None = None,
                 playback_progress: Callable[[int, int], None] | None = None) -> dict:
    """Record one simulated session and play it back with T1-T7 and ours (T7L, T8); returns what the tables need.

    Everything goes into ``job.out_dir`` (the experiment's temporary folder, phonepose.files);
    ``job.final_dir`` is where that folder will be, for the paths written into the outputs."""
    from phonepose.playback.engine import run_playback
    from phonepose.record.sim import record_sim

    out = Path(job.out_dir)
    subs = ("sessions", "playback") + (("rerun",) if job.rerun else ()) + (("hand_eye",) if job.hand_eye else ()) \
        + (("gt_calibration",) if job.calibrate_gt else ())
    for sub in subs:
        (out / sub).mkdir(exist_ok=True)
    session = out / "sessions" / f"{job.name}.mcap"
    config = job.config
    if job.exact_gt:   # the same session (every sensor stream unchanged), scored against the true pose
        from phonepose.record.sim import load_config
        config = load_config(job.config, overrides={"mocap": {"exact": True}})
    record_sim(session, scenario=job.scenario, path=job.path, trial=job.trial, seed=job.seed, config=config,
               config_file=job.config, progress=record_progress)
    rrd = out / "rerun" / f"{job.name}.rrd" if job.rerun else None
    gt_calibration = gt_calibration_name = None
    if job.hand_eye:
        from phonepose.calibration.hand_eye import hand_eye_from_session, save_hand_eye
        gt_calibration = out / "hand_eye" / f"{job.name}.yaml"
        gt_calibration_name = str(Path(job.final_dir or job.out_dir) / "hand_eye" / gt_calibration.name)
        save_hand_eye(gt_calibration, hand_eye_from_session(session))
    if job.calibrate_gt:
        from phonepose.calibration.calibrate_gt import calibrate_gt_session
        from phonepose.calibration.gt_calibration import save_gt_calibration
        gt_calibration = out / "gt_calibration" / f"{job.name}.yaml"
        gt_calibration_name = str(Path(job.final_dir or job.out_dir) / "gt_calibration" / gt_calibration.name)
        save_gt_calibration(gt_calibration, calibrate_gt_session(session))
    result = run_playback(session, trackers=["all", *job.trackers], out_dir=out / "playback" / job.name,
                          correction_math=job.correction_math, rerun_path=rrd, gt_calibration=gt_calibration,
                          gt_calibration_name=gt_calibration_name, progress=playback_progress)
    return {"name": job.name, "path": job.path, "trial": job.trial, "seed": job.seed,
            **sequence_arrays(result, session), "rerun": None if rrd is None else str(rrd)}


def sequence_arrays(result, session: str | Path) -> dict:
    """A PlaybackResult as plain arrays (picklable across processes; what the tables and plots read)."""
    trajectories = {
        name: {"stamps_ns": tr.stamps_ns, "translation": None if tr.poses is None else tr.poses.translation,
               "quat": None if tr.poses is None else tr.poses.quat_xyzw, "inside": tr.inside}
        for name, tr in result.trajectories.items()
    }
    gt = None
    if result.has_gt:
        gt = {"stamps_ns": result.gt_stamps_ns, "translation": result.gt.translation, "quat": result.gt.quat_xyzw}
    return {"session": str(session), "metrics": result.metrics, "trajectories": trajectories, "gt": gt}


def run_jobs(jobs: list[SequenceJob], jobs_in_parallel: int = 1,
             progress: Callable[[str], None] | None = None) -> list[dict]:
    """Run sequences, in parallel processes if asked; results come back in job order."""
    if jobs_in_parallel <= 1 or len(jobs) == 1:
        out = []
        for job in jobs:
            out.append(run_sequence(job))
            if progress:
                progress(job.name)
        return out
    with worker_pool(jobs_in_parallel) as pool:    # workers die with the experiment (phonepose.workers)
        futures = [pool.submit(run_sequence, job) for job in jobs]
        out = []
        for job, fut in zip(jobs, futures, strict=True):
            out.append(fut.result())
            if progress:
                progress(job.name)
        return out


def default_jobs() -> int:
    return max(1, min(2, os.cpu_count() or 1))


def mean_or_none(values: Iterable[float | None]) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None


def fmt(value: float | None, scale: float = 1.0, digits: int = 1) -> str:
    return "–" if value is None else f"{value * scale:.{digits}f}"
