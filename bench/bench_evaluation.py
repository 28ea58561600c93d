"""Our trajectory evaluation against evo's Python API, on every input format, then in depth on TUM.

Part 1, per format: TUM fr2/desk (ORB estimate, association by stamps), EuRoC V1_02 (csv GT with a
TUM estimate, association) and KITTI (index-matched: the fr2/desk associated pairs written as two
KITTI 3x4 files, since no KITTI sequence is among the fixtures; 2174 poses). The work on both sides:
association (TUM, EuRoC), SE(3) Umeyama, APE translation and RPE translation over 1 m (evo's
defaults: consecutive pairs on the estimate), after loading; numbers asserted equal (1e-9 relative),
best of N, ours then evo's. Target: >= 10x on every format.

Part 2: our trajectory evaluation against evo's Python API on the same long trajectory (TUM fr2/desk: ORB-SLAM
estimate, 2893 poses, against 20957 GT poses → 2174 associated).

Both sides do the same work with the same association (evo's, 0.01 s) and the same SE(3) Umeyama alignment:
APE translation + rotation angle (= rpg's ATE), and RPE translation + angle with all pairs from the reference,
delta in metres, tolerance 0.2 (= rpg's RE pairing, up to rpg's strict "<") at rpg's 5 default lengths.
The numbers are asserted equal (1e-9 relative), then timed (best of N). Also: rpg's pure-Python O(N²) pair
search (its algorithm, re-typed here as a loop; rpg itself is not installed) against our vectorised one.
"""

from __future__ import annotations

import copy
import time
from pathlib import Path

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "evo"
GT, EST = DATA / "fr2_desk_groundtruth.txt", DATA / "fr2_desk_ORB.txt"
REPEATS = 5


def best_of(fn, repeats=REPEATS):
    out, best = None, float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return out, best


def ours_pipeline(gt_traj=None, est_traj=None, lengths=None):
    from phonepose.evaluation import load_tum
    from phonepose.evaluation.evo_metrics import APE, RPE, PoseRelation, Unit, associate, evo_align

    gt = gt_traj or load_tum(GT)
    est = est_traj or load_tum(EST)
    i_est, i_gt = associate(gt, est, 0.01)
    ref, e = gt.poses[i_gt], est.poses[i_est]
    e = evo_align(ref, e, "se3").apply(e)
    res = {}
    for rel in (PoseRelation.translation_part, PoseRelation.rotation_angle_deg):
        m = APE(rel)
        m.process_data((ref, e))
        res[f"ape {rel.name}"] = m.get_all_statistics()
        for L in lengths:
            m = RPE(rel, L, Unit.meters, 0.2, all_pairs=True, pairs_from_reference=True)
            m.process_data((ref, e))
            res[f"rpe {rel.name} {L}"] = m.get_all_statistics()
    return res


def evo_pipeline(ref_traj=None, est_traj=None, lengths=None):
    from evo.core import metrics, sync
    from evo.tools import file_interface

    ref = ref_traj or file_interface.read_tum_trajectory_file(str(GT))
    est = est_traj or file_interface.read_tum_trajectory_file(str(EST))
    ref, est = sync.associate_trajectories(copy.deepcopy(ref), copy.deepcopy(est), max_diff=0.01)
    est.align(ref, correct_scale=False)
    res = {}
    for rel in (metrics.PoseRelation.translation_part, metrics.PoseRelation.rotation_angle_deg):
        m = metrics.APE(rel)
        m.process_data((ref, est))
        res[f"ape {rel.name}"] = m.get_all_statistics()
        for L in lengths:
            m = metrics.RPE(rel, L, metrics.Unit.meters, 0.2, all_pairs=True, pairs_from_reference=True)
            m.process_data((ref, est))
            res[f"rpe {rel.name} {L}"] = m.get_all_statistics()
    return res


def rpg_pair_search_loop(d, dist, max_dist_diff):
    """rpg's compute_comparison_indices_length, as written there (pure Python, O(N²))."""
    comparisons = []
    for idx, x in enumerate(d):
        best_idx, error = -1, max_dist_diff
        for i in range(idx, len(d)):
            if abs(d[i] - (x + dist)) < error:
                best_idx, error = i, abs(d[i] - (x + dist))
        if best_idx != -1:
            comparisons.append(best_idx)
    return comparisons


EUROC_GT, EUROC_EST = DATA / "V102_groundtruth.csv", DATA / "V102.txt"
FORMAT_DELTA_M = 1.0


def _kitti_files(tmp: Path) -> tuple[Path, Path]:
    import numpy as np

    from phonepose.evaluation import load_tum
    from phonepose.evaluation.evo_metrics import associate

    gt, est = load_tum(GT), load_tum(EST)
    i_est, i_gt = associate(gt, est, 0.01)
    out = []
    for name, poses in (("gt", gt.poses[i_gt]), ("est", est.poses[i_est])):
        path = tmp / f"{name}_kitti.txt"
        np.savetxt(path, poses.as_matrix()[:, :3, :].reshape(-1, 12), fmt="%.12e")
        out.append(path)
    return out[0], out[1]


def _ours_format(gt, est) -> dict:
    from phonepose.evaluation.evo_metrics import associate, evaluate_ape, evaluate_rpe

    matches = associate(gt, est, 0.01)
    ape = evaluate_ape(gt, est, "trans", align_method="se3", matches=matches)["ape"]
    rpe = evaluate_rpe(gt, est, "trans", delta=FORMAT_DELTA_M, delta_unit="m", align_method="se3",
                       matches=matches)["rpe"]
    return {"ape": ape, "rpe": rpe}


def _evo_format(ref, est) -> dict:
    from evo.core import metrics, sync
    from evo.core.trajectory import PoseTrajectory3D

    ref, est = copy.deepcopy(ref), copy.deepcopy(est)
    if isinstance(ref, PoseTrajectory3D) and isinstance(est, PoseTrajectory3D):
        ref, est = sync.associate_trajectories(ref, est, max_diff=0.01)
    est.align(ref, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, FORMAT_DELTA_M, metrics.Unit.meters)
    rpe.process_data((ref, est))
    return {"ape": ape.get_all_statistics(), "rpe": rpe.get_all_statistics()}


def formats() -> dict:
    """Part 1: APE + RPE on a TUM, a EuRoC and a KITTI pair, ours against evo's API."""
    import tempfile

    from evo.tools import file_interface

    from phonepose.evaluation import load_euroc, load_kitti, load_tum

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        kitti_gt, kitti_est = _kitti_files(Path(tmp))
        cases = {
            "tum": ((load_tum(GT), load_tum(EST)), (file_interface.read_tum_trajectory_file(str(GT)),
                                                    file_interface.read_tum_trajectory_file(str(EST)))),
            "euroc": ((load_euroc(EUROC_GT), load_tum(EUROC_EST)),
                      (file_interface.read_euroc_csv_trajectory(str(EUROC_GT)),
                       file_interface.read_tum_trajectory_file(str(EUROC_EST)))),
            "kitti": ((load_kitti(kitti_gt), load_kitti(kitti_est)),
                      (file_interface.read_kitti_poses_file(str(kitti_gt)),
                       file_interface.read_kitti_poses_file(str(kitti_est)))),
        }
        for name, ((g, e), (rg, re_)) in cases.items():
            ours, t_ours = best_of(lambda g=g, e=e: _ours_format(g, e))
            theirs, t_evo = best_of(lambda rg=rg, re_=re_: _evo_format(rg, re_))
            worst = 0.0
            for metric in ("ape", "rpe"):
                for stat, v in theirs[metric].items():
                    worst = max(worst, abs(ours[metric][stat] - v) / max(abs(v), 1e-300))
            assert worst < 1e-9, (name, worst)
            out[f"{name}_ours_s"], out[f"{name}_evo_s"] = t_ours, t_evo
            out[f"{name}_speedup"], out[f"{name}_max_rel_diff"] = t_evo / t_ours, worst
            out[f"{name}_poses"] = int(ours["ape"]["num_samples"])
            print(f"{name:6s} {out[f'{name}_poses']:5d} matched poses: ours {1e3 * t_ours:7.2f} ms, evo "
                  f"{1e3 * t_evo:8.2f} ms -> {t_evo / t_ours:5.1f}x (same numbers: max rel. diff {worst:.1e})")
    out["min_format_speedup"] = min(out[f"{n}_speedup"] for n in cases)
    return out


def main() -> dict:
    print("part 1: every format, APE + RPE (translation, SE(3) alignment, 1 m), after loading")
    part1 = formats()
    print("part 2: TUM fr2/desk in depth")
    return {**part1, **depth()}


def depth() -> dict:
    import evo
    from evo.tools import file_interface

    from phonepose.evaluation import load_tum
    from phonepose.evaluation.evo_metrics import associate
    from phonepose.evaluation.relative import accumulated_distances, default_lengths, find_pairs
    from phonepose.evaluation.rpg import evaluate_rpg

    gt, est = load_tum(GT), load_tum(EST)
    lengths = default_lengths(gt.positions)
    ref_e = file_interface.read_tum_trajectory_file(str(GT))
    est_e = file_interface.read_tum_trajectory_file(str(EST))

    ours, t_ours = best_of(lambda: ours_pipeline(gt, est, lengths))
    theirs, t_evo = best_of(lambda: evo_pipeline(ref_e, est_e, lengths))
    assert ours.keys() == theirs.keys()
    worst = 0.0
    for k in ours:
        for s, v in theirs[k].items():
            worst = max(worst, abs(ours[k][s] - v) / max(abs(v), 1e-300))
    assert worst < 1e-9, worst

    _, t_ours_e2e = best_of(lambda: ours_pipeline(None, None, lengths))
    _, t_evo_e2e = best_of(lambda: evo_pipeline(None, None, lengths))
    _, t_rpg_full = best_of(lambda: evaluate_rpg(gt, est, "se3"))

    i_est, i_gt = associate(gt, est, 0.01)
    d = accumulated_distances(gt.positions[i_gt])
    t = time.perf_counter()
    loop = rpg_pair_search_loop(d.tolist(), lengths[0], 0.2 * lengths[0])
    t_loop = time.perf_counter() - t
    (starts, ends), t_vec = best_of(lambda: find_pairs(d, lengths[0]))
    assert ends.tolist() == loop

    result = {
        "trajectory": f"fr2_desk ORB: {len(est)} est / {len(gt)} GT poses, {i_est.size} associated",
        "evo_version": evo.__version__,
        "work": f"SE(3) Umeyama, APE trans+angle, RPE trans+angle all pairs from reference at {lengths} m",
        "max_rel_diff_vs_evo": worst,
        "ours_metrics_s": t_ours, "evo_metrics_s": t_evo, "speedup_metrics": t_evo / t_ours,
        "ours_incl_loading_s": t_ours_e2e, "evo_incl_loading_s": t_evo_e2e,
        "speedup_incl_loading": t_evo_e2e / t_ours_e2e,
        "ours_rpg_ate_re_full_s": t_rpg_full,
        "rpg_pair_search_loop_s": t_loop, "ours_pair_search_s": t_vec, "speedup_pair_search": t_loop / t_vec,
    }
    for k, v in result.items():
        print(f"{k:28s} {v:.4g}" if isinstance(v, float) else f"{k:28s} {v}")
    return result


if __name__ == "__main__":
    main()
