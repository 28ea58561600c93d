"""The experiment runners: table aggregation (exact), exp1 target scoring (exact), and the CLIs end to end."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from phonepose.experiments import paper
from phonepose.experiments.common import sequence_seed
from phonepose.experiments.exp1 import summarise, target_errors
from phonepose.experiments.exp2 import table5_rows, table6_rows


def _metrics(base: float) -> dict:
    out = {"trackers": {}}
    for k, name in enumerate(paper.TRACKERS):
        v = base + k / 100
        out["trackers"][name] = {s: {"frames": 10, "p_ate_m": v, "r_ate_deg": 10 * v, "p_re_m": v / 2}
                                 for s in ("inside", "outside", "total")}
    out["trackers"]["T4"]["outside"] = {"frames": 0, "p_ate_m": None, "r_ate_deg": None, "p_re_m": None}
    return out


def _sequences():
    seqs = []
    for p, base in (("TRI1", 0.01), ("REC1", 0.03), ("TRI2", 0.05), ("REC2", 0.07)):
        for t in (1, 2):
            seqs.append({"name": f"{p}_{t:02d}", "path": p, "trial": t, "metrics": _metrics(base + t / 1000)})
    return seqs


def test_table5_is_the_mean_of_per_sequence_totals_next_to_the_paper():
    rows = table5_rows(_sequences())
    t1 = [r for r in rows if r["tracker"] == "T1" and r["key"] == "p_ate_m"][0]
    assert t1["values"] == {"TRI1_01": 0.011, "TRI1_02": 0.012, "REC1_01": 0.031, "REC1_02": 0.032}
    assert t1["average"] == pytest.approx((0.011 + 0.012 + 0.031 + 0.032) / 4, rel=1e-12)
    assert t1["paper"] == 6.6
    t6 = [r for r in rows if r["tracker"] == "T6" and r["key"] == "r_ate_deg"][0]
    assert t6["average"] == pytest.approx(10 * ((0.011 + 0.012 + 0.031 + 0.032) / 4 + 0.05), rel=1e-12)
    assert t6["paper"] == 12.6


def test_table6_averages_per_path_and_overall_and_skips_unavailable():
    rows = table6_rows(_sequences())
    r = [x for x in rows if x["tracker"] == "T2" and x["scope"] == "outside" and x["key"] == "p_re_m"][0]
    assert r["per_path"]["TRI2"] == pytest.approx((0.061 + 0.062) / 4, rel=1e-12)
    assert r["per_path"]["REC2"] == pytest.approx((0.081 + 0.082) / 4, rel=1e-12)
    assert r["average"] == pytest.approx((0.061 + 0.062 + 0.081 + 0.082) / 8, rel=1e-12)
    assert r["paper"] == 4.6
    none = [x for x in rows if x["tracker"] == "T4" and x["scope"] == "outside" and x["key"] == "p_ate_m"][0]
    assert none["average"] is None and none["per_path"] == {"TRI2": None, "REC2": None}


def test_sequence_seeds_are_distinct_and_stable():
    seeds = {sequence_seed(0, p, t) for p in ("TRI1", "TRI2", "REC1", "REC2") for t in (1, 2, 3)}
    assert len(seeds) == 12
    assert sequence_seed(0, "TRI2", 1) == sequence_seed(0, "TRI2", 1)
    assert sequence_seed(1, "TRI2", 1) != sequence_seed(0, "TRI2", 1)


def test_exp1_target_scoring_exact():
    n = 100
    t = np.arange(n, dtype=np.int64) * 50_000_000
    gt_p = np.zeros((n, 3))
    gt_p[:, 2] = 0.3
    gt_q = Rotation.identity(n).as_quat()
    est_p = gt_p + [0.01, 0.0, 0.0]          # 1 cm off everywhere
    est_p[50:] += [0.0, 0.02, 0.0]           # sqrt(5) cm off in the second hold
    est_q = Rotation.from_rotvec(np.tile([0, 0, np.radians(3.0)], (n, 1))).as_quat()
    traj = {"stamps_ns": t, "translation": est_p, "quat": est_q, "inside": np.ones(n, bool)}
    seq = {"gt": {"stamps_ns": t, "translation": gt_p, "quat": gt_q},
           "trajectories": {name: traj for name in paper.TRACKERS}}
    targets = [{"index": 0, "inside": True, "position": np.array([0.0, 0.0, 0.3]), "start_ns": 0, "end_ns": t[49]},
               {"index": 1, "inside": False, "position": np.array([0.0, 0.0, 0.3]), "start_ns": t[50], "end_ns": t[-1]}]
    rows = target_errors(seq, targets, 0.02)
    r0 = [r for r in rows if r["tracker"] == "T1" and r["target"] == 0][0]
    r1 = [r for r in rows if r["tracker"] == "T1" and r["target"] == 1][0]
    assert r0["frames"] == 50 and r1["frames"] == 50
    assert r0["pos_m"] == pytest.approx(0.01, abs=1e-12)
    assert r1["pos_m"] == pytest.approx(np.sqrt(0.01 ** 2 + 0.02 ** 2), abs=1e-12)
    assert r0["rot_deg"] == pytest.approx(3.0, abs=1e-9)
    assert r0["selected"] is True and r1["selected"] is False   # 2.24 cm > 2 cm
    s = summarise(rows)
    assert s["T7"]["inside"] == {"targets": 1, "pos_m": pytest.approx(0.01), "rot_deg": pytest.approx(3.0), "selected": 1}
    assert s["T7"]["outside"]["selected"] == 0


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "phonepose", *args], capture_output=True, text=True, cwd=cwd)


@pytest.mark.slow
@pytest.mark.long
def test_exp2_one_trial_end_to_end(tmp_path):
    r = run("experiment", "exp2", "--trials", "1", "--out", str(tmp_path / "x"), "--workers", "2")
    assert r.returncode == 0, r.stderr
    out = tmp_path / "x"
    with open(out / "table5.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["tracker"] for r in rows[::3]] == paper.REPORTED       # T1-T7, then ours (T7L, T8)
    assert {"TRI1_01", "REC1_01"} <= set(rows[0])
    t1 = float(rows[0]["average"])   # T1 p_ATE in cm: anchor-mapped VIO is centimetres off
    t4 = float(rows[9]["average"])   # T4 p_ATE: marker-based
    assert 2.0 < t1 < 15.0 and t4 < t1
    summary = json.loads((out / "exp2.json").read_text())
    assert set(summary["sequences"]) == {"TRI1_01", "TRI2_01", "REC1_01", "REC2_01"}
    assert summary["sequences"]["TRI2_01"]["trackers"]["T7"]["outside"]["frames"] > 0
    with open(out / "table6.csv") as f:
        jumps = {r["tracker"]: r for r in csv.DictReader(f) if r["metric"] == "boundary jump max (cm)"}
    assert list(jumps) == paper.REPORTED
    # T4 switches from the marker to uncorrected VIO: centimetres; T8 keeps its output continuous
    assert float(jumps["T8"]["average"]) < float(jumps["T4"]["average"])
    assert (out / "fig11_TRI2_01.png").stat().st_size > 10_000
    assert "Table 6" in r.stdout


@pytest.mark.slow
def test_exp2_hand_eye_sequence_scores_in_the_phone_frame(tmp_path):
    """`experiment exp2 --calibrate-hand-eye`: each sequence is calibrated from itself before playback."""
    from phonepose.experiments.common import run_sequence
    from phonepose.experiments.exp2 import HAND_EYE_NOTE, _write_table6, make_jobs

    jobs = make_jobs(tmp_path, trials=1, seed=0, config=None, correction_math="paper", paths=("TRI1",), hand_eye=True)
    assert [(j.name, j.hand_eye) for j in jobs] == [("TRI1_01", True)]
    seq = run_sequence(jobs[0])
    assert (tmp_path / "hand_eye" / "TRI1_01.yaml").is_file()
    note = seq["metrics"]["ground_truth"]
    assert abs(note["body_rotation_deg"] - 11.0) < 0.3 and abs(note["time_offset_s"] - 0.03) <= 0.002
    on_disk = json.loads((tmp_path / "playback" / "TRI1_01" / "metrics.json").read_text())
    assert on_disk["ground_truth"] == note
    # inside the view the marker trackers' r_ATE is their own (~1-2 deg), not the 11 deg rigid-body offset
    assert on_disk["trackers"]["T4"]["inside"]["r_ate_deg"] < 4.0
    md, _ = _write_table6(table6_rows(_sequences()), tmp_path, [HAND_EYE_NOTE])
    assert HAND_EYE_NOTE in md.read_text()


def test_experiment_bad_options_are_one_line(cli):
    r = cli("experiment", "exp2", "--trials", "7")
    assert r.returncode == 5 and "--trials 7: expected an integer in [1, 3]" in r.stderr and "Traceback" not in r.stderr
    r = cli("experiment", "exp2", "--correction-math", "quaternion")
    assert r.returncode == 5 and "Traceback" not in r.stderr


@pytest.mark.slow
def test_demo_runs_with_no_arguments_and_leaves_its_outputs(tmp_path):
    r = run("demo", cwd=tmp_path)   # the README's first command, with its default output directory
    assert r.returncode == 0, r.stderr
    out = tmp_path / "phonepose-demo"
    metrics = json.loads((out / "playback" / "metrics.json").read_text())
    assert list(metrics["trackers"]) == paper.REPORTED                  # T1-T7, then ours (T7L, T8)
    assert metrics["trackers"]["T7"]["outside"]["frames"] > 0          # TRI2 leaves the view
    assert metrics["trackers"]["T8"]["total"]["boundary_jump_max_m"] < metrics["trackers"]["T4"]["total"]["boundary_jump_max_m"]
    assert metrics["trackers"]["T4"]["inside"]["p_ate_m"] < metrics["trackers"]["T1"]["inside"]["p_ate_m"]
    assert sorted(p.name for p in (out / "playback" / "trajectories").iterdir()) == sorted(f"{t}.tum" for t in paper.REPORTED)
    assert (out / "demo.rrd").stat().st_size > 100_000 and (out / "fig11_TRI2_01.png").exists()
    assert "rerun " in r.stdout and "demo.rrd" in r.stdout
    # the hint it prints about r_ATE holds: the session's rigid body is 11 deg off the phone
    assert "calibrate-hand-eye" in r.stdout and "--gt-calibration he.yaml" in r.stdout
    he = run("calibrate-hand-eye", str(out / "TRI2_01.mcap"), "-o", "he.yaml", cwd=tmp_path)
    assert he.returncode == 0 and "rigid body turned 11." in he.stdout, he.stderr


@pytest.mark.slow
def test_exp1_reports_progress_while_it_records_and_plays_back(tmp_path, short_exp1):
    """`experiment exp1` shows a bar for its ~40 s of work (it printed nothing before): both phases report
    (here on 4 of its targets, a ~27 s session)."""
    from phonepose.experiments.exp1 import run_exp1

    recorded, played = [], []
    result = run_exp1(tmp_path / "e1", record_progress=lambda done, total: recorded.append((done, total)),
                      playback_progress=lambda done, total: played.append((done, total)))
    assert len(result.per_target) == len(short_exp1) * len(result.summary)           # a row per target and tracker
    assert len(recorded) > 100 and recorded[-1][0] == recorded[-1][1] > 20e9       # 0.1 s steps of the session
    assert [d for d, _ in played] == list(range(1, len(played) + 1)) and played[-1][0] == played[-1][1]
    assert result.files["exp1.json"] == str(tmp_path / "e1" / "exp1.json") and (tmp_path / "e1" / "exp1.json").is_file()
