"""Our APE/RPE against evo 1.38.1: the stored CLI outputs (tests/data/evo/generated_expected) and, live,
the installed evo Python API (the ``test`` extra pins evo==1.38.1)."""

from __future__ import annotations

import functools
import json
import shlex
from pathlib import Path

import numpy as np
import pytest

from phonepose.evaluation import load_trajectory
from phonepose.evaluation.alignment import align_origin
from phonepose.evaluation.evo_metrics import APE, associate, evaluate_ape, evaluate_rpe, relation

DATA = Path(__file__).parent / "data"
EXPECTED = json.loads((DATA / "evo/generated_expected/expected_evo_1.38.1.json").read_text())["results"]
RPG_CWD = "rpg_trajectory_evaluation/results/euroc_vislam_mono/laptop"
RPG_FILES = {"vislam_rp/laptop_vislam_rp_MH_04/stamped_groundtruth.txt": "rpg/MH_04_stamped_groundtruth.txt",
             "vislam_rp/laptop_vislam_rp_MH_04/stamped_traj_estimate0.txt": "rpg/MH_04_stamped_traj_estimate0.txt",
             "vislam_ba/laptop_vislam_ba_MH_04/stamped_ba_estimate0.txt": "rpg/MH_04_stamped_ba_estimate0.txt"}
RTOL = 1e-6


def local(cwd: str, name: str) -> Path | None:
    if cwd == "evo/test/data":
        p = DATA / "evo" / name
        return p if p.exists() else None
    if cwd == RPG_CWD and name in RPG_FILES:
        return DATA / RPG_FILES[name]
    return None


def parse(command: str) -> dict:
    a = shlex.split(command)
    o = {"tool": a[0], "fmt": a[1], "ref": a[2], "est": a[3], "align": "none", "n": -1, "r": "trans_part",
         "max_diff": 0.01, "d": 1.0, "u": "f", "all_pairs": False, "origin": False}
    k = 4
    while k < len(a):
        x = a[k]
        if x == "-a":
            o["align"] = "se3"
        elif x == "-as":
            o["align"] = "sim3"
        elif x == "--align_origin":
            o["origin"] = True
        elif x == "--all_pairs":
            o["all_pairs"] = True
        else:
            key = {"-r": "r", "--n_to_align": "n", "--t_max_diff": "max_diff", "-d": "d", "-u": "u"}[x]
            o[key] = type(o[key])(a[k + 1]) if key != "n" else int(a[k + 1])
            k += 1
        k += 1
    return o


CASES = [r for r in EXPECTED if local(r["cwd"], parse(r["command"])["ref"]) and local(r["cwd"], parse(r["command"])["est"])]


@functools.cache
def load(path: Path, fmt: str):
    return load_trajectory(path, fmt)


def run(r: dict) -> tuple[dict, int]:
    o = parse(r["command"])
    gt = load(local(r["cwd"], o["ref"]), o["fmt"])
    est = load(local(r["cwd"], o["est"]), "kitti" if o["fmt"] == "kitti" else "tum")
    if o["tool"] == "evo_ape" and o["origin"]:
        i_est, i_gt = associate(gt, est, o["max_diff"])
        al = align_origin(gt.poses[i_gt], est.poses[i_est])
        m = APE(relation(o["r"]))
        m.process_data((gt.poses[i_gt], al.apply(est.poses[i_est])))
        return {**m.get_all_statistics(), "num_samples": m.error.size}, int(i_est.size)
    if o["tool"] == "evo_ape":
        res = evaluate_ape(gt, est, o["r"], o["align"], o["n"], o["max_diff"])
        return res["ape"], res["n_matched"]
    res = evaluate_rpe(gt, est, o["r"], o["d"], o["u"], o["all_pairs"], False, 0.1, o["align"], o["n"], o["max_diff"])
    return res["rpe"], res["n_matched"]


def test_covers_tum_and_euroc():
    cmds = [r["command"] for r in CASES]
    assert sum("fr2_desk" in c for c in cmds) == 16 and sum("V102" in c for c in cmds) == 6
    assert len(CASES) == 31


@pytest.mark.parametrize("r", CASES, ids=[r["command"].replace(" ", "_")[:90] for r in CASES])
def test_equals_evo_cli_outputs(r):
    stats, n_matched = run(r)
    found = int(r["log"][0].split()[1]) if r["log"] and r["log"][0].startswith("Found") else None
    if found is not None:
        assert n_matched == found
    assert stats["num_samples"] == r["n_errors"]
    for k, v in r["stats"].items():
        assert abs(stats[k] - v) <= max(RTOL * abs(v), 1e-12), f"{k}: {stats[k]!r} vs evo {v!r}"


# ----------------------------------------------------------------------------- live evo (Python API)
def _evo_trajs():
    from evo.tools import file_interface  # evo 1.38.1 is in the test extra

    ref = file_interface.read_tum_trajectory_file(str(DATA / "evo/fr2_desk_groundtruth.txt"))
    est = file_interface.read_tum_trajectory_file(str(DATA / "evo/fr2_desk_ORB.txt"))
    return ref, est


def test_live_evo_association_and_sim3_ape_rpe():
    import copy

    from evo.core import metrics, sync

    ref, est = _evo_trajs()
    ref_s, est_s = sync.associate_trajectories(ref, est, max_diff=0.01)
    gt = load(DATA / "evo/fr2_desk_groundtruth.txt", "tum")
    es = load(DATA / "evo/fr2_desk_ORB.txt", "tum")
    i_est, i_gt = associate(gt, es, 0.01)
    np.testing.assert_array_equal(gt.stamps[i_gt], ref_s.timestamps)
    np.testing.assert_array_equal(es.stamps[i_est], est_s.timestamps)

    est_al = copy.deepcopy(est_s)
    r_a, t_a, s_a = est_al.align(ref_s, correct_scale=True)
    ape = metrics.APE(metrics.PoseRelation.rotation_angle_deg)
    ape.process_data((ref_s, est_al))
    ours = evaluate_ape(gt, es, "angle_deg", "sim3")
    assert ours["align"]["scale"] == pytest.approx(s_a, rel=1e-12)
    for k, v in ape.get_all_statistics().items():
        assert ours["ape"][k] == pytest.approx(v, rel=RTOL)

    rpe = metrics.RPE(metrics.PoseRelation.translation_part, 0.5, metrics.Unit.meters, 0.1, all_pairs=True)
    rpe.process_data((ref_s, est_al))
    ours = evaluate_rpe(gt, es, "trans", 0.5, "m", all_pairs=True, align_method="sim3")["rpe"]
    assert ours["num_samples"] == len(rpe.error)
    for k, v in rpe.get_all_statistics().items():
        assert ours[k] == pytest.approx(v, rel=RTOL)

    rpe = metrics.RPE(metrics.PoseRelation.rotation_angle_deg, 2.03, metrics.Unit.meters, 0.2, all_pairs=True,
                      pairs_from_reference=True)
    rpe.process_data((ref_s, est_al))
    ours = evaluate_rpe(gt, es, "angle", 2.03, "m", all_pairs=True, pairs_from_reference=True, rel_delta_tol=0.2,
                        align_method="sim3")["rpe"]
    assert ours["num_samples"] == len(rpe.error)
    for k, v in rpe.get_all_statistics().items():
        assert ours[k] == pytest.approx(v, rel=RTOL)


def _rows(name: str) -> list[list[str]]:
    return [x.split(",") if name.endswith(".csv") else x.split() for x in (DATA / "evo" / name).read_text().splitlines()
            if x and not x.startswith("#")]


def _scaled_quaternion(row: list[str], k: float, first: int) -> list[str]:
    return row[:first] + [repr(float(v) * k) for v in row[first:first + 4]] + row[first + 4:]


# How other tools and people write the same TUM file: each variant must give evo's numbers for the original.
TUM_VARIANTS = {
    "tabs": lambda rows: "\n".join("\t".join(r) for r in rows) + "\n",
    "crlf": lambda rows: "\r\n".join(" ".join(r) for r in rows) + "\r\n",
    "lone-cr (old Mac)": lambda rows: "\r".join(" ".join(r) for r in rows) + "\r",
    "comments mid-file and at line ends": lambda rows: "\n".join(
        " ".join(r) + ("  # a note" if i % 3 else "") + ("\n# a comment line" if i == 10 else "")
        for i, r in enumerate(rows)) + "\n",
    "header without #": lambda rows: "timestamp tx ty tz qx qy qz qw\n" + "\n".join(" ".join(r) for r in rows) + "\n",
    "scientific notation and +": lambda rows: "\n".join(" ".join(f"{float(v):+.17e}" for v in r) for r in rows) + "\n",
    "whitespace and blank lines": lambda rows: "\n\n".join("  " + "   ".join(r) + " \t" for r in rows) + "\n\n",
    "quaternions of norm 2 (evo normalises)": lambda rows: "\n".join(
        " ".join(_scaled_quaternion(r, 2.0, 4)) for r in rows) + "\n",
    "quaternions of norm 0.999 (3-decimal tools)": lambda rows: "\n".join(
        " ".join(_scaled_quaternion(r, 0.999, 4)) for r in rows) + "\n",
}


@pytest.mark.parametrize("variant", list(TUM_VARIANTS))
def test_tum_files_as_other_tools_write_them_give_evos_numbers(variant, tmp_path):
    """evo 1.38.1's `evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam.txt -a` (and -r angle_deg) on
    the original file; evo normalises every quaternion (its reader), so a non-unit one must not drop the pose (we
    skipped those more than 1e-3 off, 375 of 788 poses at norm 0.999, all at norm 2)."""
    est = tmp_path / "est.txt"
    est.write_bytes(TUM_VARIANTS[variant](_rows("freiburg1_xyz-rgbdslam.txt")).encode())
    gt = load_trajectory(DATA / "evo/freiburg1_xyz-groundtruth.txt", "tum")
    for command in ("evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam.txt -a",
                    "evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam.txt -a -r angle_deg"):
        r = next(x for x in EXPECTED if x["command"] == command)
        res = evaluate_ape(gt, load_trajectory(est, "tum"), parse(command)["r"], "se3")
        assert res["n_matched"] == r["n_errors"] == 785
        assert res["ape"]["rmse"] == pytest.approx(r["stats"]["rmse"], rel=RTOL)


@pytest.mark.parametrize("variant", ["header without #", "crlf", "8 columns", "spaces after commas"])
def test_euroc_files_as_other_tools_write_them_give_evos_numbers(variant, tmp_path):
    """`evo_ape euroc V102_groundtruth.csv V102.txt -a` on the original 17-column file with its `#` header."""
    rows = _rows("V102_groundtruth.csv")
    header = (DATA / "evo/V102_groundtruth.csv").read_text().splitlines()[0]
    text = {"header without #": header.lstrip("#") + "\n" + "\n".join(",".join(r) for r in rows) + "\n",
            "crlf": header + "\r\n" + "\r\n".join(",".join(r) for r in rows) + "\r\n",
            "8 columns": "\n".join(",".join(r[:8]) for r in rows) + "\n",
            "spaces after commas": "\n".join(", ".join(r) for r in rows) + "\n"}[variant]
    gt = tmp_path / "gt.csv"
    gt.write_bytes(text.encode())
    command = "evo_ape euroc V102_groundtruth.csv V102.txt -a"
    r = next(x for x in EXPECTED if x["command"] == command)
    res = evaluate_ape(load_trajectory(gt, "euroc"), load(DATA / "evo/V102.txt", "tum"), "trans_part", "se3")
    assert res["n_matched"] == r["n_errors"] == 798
    assert res["ape"]["rmse"] == pytest.approx(r["stats"]["rmse"], rel=RTOL)
