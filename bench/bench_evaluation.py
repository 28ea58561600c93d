"""Our trajectory evaluation against evo's Python API on the same long trajectory (TUM fr2/desk: ORB-SLAM
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


def main() -> dict:
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
