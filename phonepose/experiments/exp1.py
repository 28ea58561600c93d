"""Experiment 1 of the paper (discrete data): pointing at 16 targets, Tables 2 and 3.

One simulated exp1 session (8 targets at 25 cm and 8 at 35 cm depth, half inside the display
camera's view), played back with T1-T7. For every target and tracker, over the 5 s hold:
- position / rotation error: RMSE of the tracker against ground truth over the hold's ticks;
- selected: the tracker's median position over the hold lies within the paper's 2 cm of the
  target centre (the paper's selection rule; in the paper the user steered the estimate onto the
  target, in the simulation the true phone goes there, so this counts estimates within 2 cm).
Tables 2 (targets inside the view) and 3 (outside) average the per-target errors.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.table import Table

from phonepose.experiments import paper
from phonepose.experiments.common import SequenceJob, fmt, mean_or_none, run_sequence, sequence_seed, user_trackers
from phonepose.geometry import Pose
from phonepose.session import codec


@dataclass
class Exp1Result:
    out_dir: Path
    per_target: list[dict]
    summary: dict            # tracker -> {"inside"|"outside": {"pos_m", "rot_deg", "selected", "targets"}}
    files: dict[str, str]


def read_targets(session: str) -> tuple[list[dict], float]:
    from phonepose.schemas.topics import Topic
    from phonepose.session import SessionReader

    with SessionReader(session) as reader:
        msg = reader.first(Topic.EXPERIMENT_TARGETS)
    if msg is None:
        return [], 0.02
    out = [{"index": t.index, "inside": bool(t.inside_view), "position": codec.pose_of(t.pose).translation,
            "start_ns": t.hold_start.ToNanoseconds(), "end_ns": t.hold_end.ToNanoseconds()} for t in msg.targets]
    return out, float(msg.select_radius_m or 0.02)


def target_errors(seq: dict, targets: list[dict], radius: float, names: list[str] = paper.REPORTED) -> list[dict]:
    gt = seq["gt"]
    rows = []
    gt_t = np.asarray(gt["stamps_ns"])
    gt_pose = Pose.from_xyzw(gt["translation"], gt["quat"])
    for name in names:
        tr = seq["trajectories"].get(name)
        if tr is None or tr["translation"] is None:
            continue
        t = np.asarray(tr["stamps_ns"])
        common, i_est, i_gt = np.intersect1d(t, gt_t, return_indices=True)
        est = Pose.from_xyzw(np.asarray(tr["translation"])[i_est], np.asarray(tr["quat"])[i_est])
        ref = gt_pose[i_gt]
        e_pos = np.linalg.norm(est.translation - ref.translation, axis=1)
        e_rot = np.degrees((est.rotation.inv() * ref.rotation).magnitude())
        for tg in targets:
            m = (common >= tg["start_ns"]) & (common <= tg["end_ns"])
            if not m.any():
                rows.append({"tracker": name, "target": tg["index"], "inside": tg["inside"], "pos_m": None,
                             "rot_deg": None, "selected": False, "frames": 0})
                continue
            median = np.median(est.translation[m], axis=0)
            rows.append({"tracker": name, "target": tg["index"], "inside": tg["inside"],
                         "pos_m": float(np.sqrt(np.mean(e_pos[m] ** 2))), "rot_deg": float(np.sqrt(np.mean(e_rot[m] ** 2))),
                         "selected": bool(np.linalg.norm(median - tg["position"]) <= radius), "frames": int(m.sum())})
    return rows


def summarise(rows: list[dict], names: list[str] = paper.REPORTED) -> dict:
    out: dict[str, dict] = {}
    for name in names:
        out[name] = {}
        for scope, flag in (("inside", True), ("outside", False)):
            sel = [r for r in rows if r["tracker"] == name and r["inside"] == flag]
            out[name][scope] = {"targets": len(sel), "pos_m": mean_or_none(r["pos_m"] for r in sel),
                                "rot_deg": mean_or_none(r["rot_deg"] for r in sel),
                                "selected": sum(r["selected"] for r in sel)}
    return out


def exp1_tables(result: Exp1Result) -> list[Table]:
    tables = []
    for scope, ref, title in (("inside", paper.TABLE2_INSIDE, "Table 2 (targets inside the view)"),
                              ("outside", paper.TABLE3_OUTSIDE, "Table 3 (targets outside the view)")):
        t = Table(title=f"{title}: ours / paper")
        t.add_column("tracker", style="bold")
        t.add_column("pos cm", justify="right")
        t.add_column("rot deg", justify="right")
        t.add_column("selected (2 cm)", justify="right")
        for name in result.summary:
            d = result.summary[name][scope]
            p = ref.get(name, (paper.NO_VALUE, paper.NO_VALUE))
            t.add_row(name, f"{fmt(d['pos_m'], 100)} / {p[0]}", f"{fmt(d['rot_deg'])} / {p[1]}",
                      f"{d['selected']}/{d['targets']}")
        tables.append(t)
    return tables


def _write(result: Exp1Result) -> None:
    out = result.out_dir
    with open(out / "exp1_targets.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["tracker", "target", "inside_view", "frames", "pos_cm", "rot_deg", "selected"])
        for r in result.per_target:
            w.writerow([r["tracker"], r["target"], int(r["inside"]), r["frames"], fmt(r["pos_m"], 100, 2),
                        fmt(r["rot_deg"], 1, 2), int(r["selected"])])
    lines = ["# Tables 2 and 3 equivalent: experiment 1 (16 targets)", "",
             "Ours: mean over targets of the per-target RMSE during the 5 s hold; `paper` = Park & Ogawa 2024.", "",
             "| tracker | scope | pos cm | paper | rot deg | paper | selected (≤ 2 cm) |", "|---|---|---:|---:|---:|---:|---:|"]
    for name in result.summary:
        for scope, ref in (("inside", paper.TABLE2_INSIDE), ("outside", paper.TABLE3_OUTSIDE)):
            d = result.summary[name][scope]
            p = ref.get(name, (paper.NO_VALUE, paper.NO_VALUE))
            lines.append(f"| {name} | {scope} | {fmt(d['pos_m'], 100)} | {p[0]} | {fmt(d['rot_deg'])} | "
                         f"{p[1]} | {d['selected']}/{d['targets']} |")
    (out / "exp1_tables.md").write_text("\n".join(lines) + "\n")
    (out / "exp1.json").write_text(json.dumps(result.summary, indent=2, sort_keys=True))
    result.files.update({"exp1_tables.md": str(out / "exp1_tables.md"), "exp1_targets.csv": str(out / "exp1_targets.csv"),
                         "exp1.json": str(out / "exp1.json")})


def run_exp1(out_dir: str | Path, seed: int = 0, config: str | None = None, correction_math: str = "paper",
             record_progress: Callable[[int, int | None], None] | None = None,
             playback_progress: Callable[[int, int], None] | None = None,
             trackers: Iterable[str] = ()) -> Exp1Result:
    """The exp1 session recorded, played back and scored into ``out_dir`` (phonepose.files: checked first,
    a temporary folder put in place whole at the end); the progress callbacks are record_sim's and
    run_playback's."""
    from phonepose.files import OutputPlan

    plan = OutputPlan(inputs=[config] if config else [])
    folder = plan.dir(out_dir, "out", command="experiment exp1")
    refs, extra = user_trackers(trackers)
    names = paper.REPORTED + extra
    with plan:
        out = folder.tmp
        assert out is not None   # the plan's block made it
        job = SequenceJob(name="exp1", scenario="exp1", path=None, trial=1, seed=sequence_seed(seed, None, 1),
                          out_dir=str(out), config=config, correction_math=correction_math, final_dir=str(folder.path),
                          trackers=refs)
        seq = run_sequence(job, record_progress, playback_progress)
        targets, radius = read_targets(seq["session"])
        rows = target_errors(seq, targets, radius, names) if seq["gt"] is not None else []
        result = Exp1Result(out, rows, summarise(rows, names), {"session": seq["session"]})
        _write(result)
    result.out_dir = folder.path
    result.files = {k: str(folder.final(v)) for k, v in result.files.items()}
    return result
