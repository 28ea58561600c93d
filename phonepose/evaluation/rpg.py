"""Zhang & Scaramuzza's evaluation as rpg_trajectory_evaluation runs it: associate, align, ATE, RE.

:func:`evaluate_rpg` returns the ``--json`` document of ``phonepose evaluate --metric rpg``::

    {"n_matched": n, "align": {...}, "ate": {"trans_m": stats, "rot_deg": stats, "scale_perc": stats},
     "re": {"<length>": {"trans_m", "trans_perc", "rot_deg", "yaw_deg", "gravity_deg", "rot_deg_per_m"}}}

where ``stats`` is ``{"rmse", "mean", "median", "std", "min", "max", "num_samples"}``.
"""

from __future__ import annotations

from phonepose.errors import ConfigError, SessionContentError
from phonepose.evaluation.alignment import align
from phonepose.evaluation.association import associate_index, associate_rpg
from phonepose.evaluation.ate import absolute_errors, scale_errors_perc
from phonepose.evaluation.relative import RelativeErrors, accumulated_distances, default_lengths, relative_errors_at
from phonepose.evaluation.stats import statistics
from phonepose.evaluation.trajectory import Trajectory


def length_key(length: float) -> str:
    return repr(float(length))


def associate(gt: Trajectory, est: Trajectory, max_diff: float = 0.02):
    if gt.stamps is None or est.stamps is None:
        if len(gt) != len(est):
            raise ConfigError(f"index-matched (KITTI) trajectories need the same length: {len(gt)} vs {len(est)}")
        return associate_index(len(est), len(gt))
    return associate_rpg(est.stamps, gt.stamps, max_diff)


def evaluate_rpg(gt: Trajectory, est: Trajectory, align_method: str = "posyaw", align_frames: int = -1,
                 lengths=None, max_diff: float = 0.02, index_shift_quirk: bool = False,
                 scale_quirk: bool = False, details: bool = False) -> dict:
    i_est, i_gt = associate(gt, est, max_diff)
    if i_est.size == 0:
        raise SessionContentError(f"no matching stamps between {gt.source or 'GT'} and {est.source or 'estimate'} "
                          f"(|dt| < {max_diff} s)")
    if lengths is None:
        lengths = default_lengths(gt.positions)
        if not all(x > 0 for x in lengths):     # what is wrong is the trajectory, not a --lengths the user gave
            raise SessionContentError(
                f"{gt.source or 'the ground truth'}: its path is {gt.path_length():.3g} m long, too short for the "
                "default RE lengths (10-50 % of it, whole cm): give {lengths} in m, or use {metric} ape",
                parameter="lengths", also=["metric"])
    lengths = [float(x) for x in lengths]
    if any(not (x > 0) for x in lengths):
        raise ConfigError(f"{{lengths}} {lengths}: sub-trajectory lengths must be > 0 m", parameter="lengths",
                          value=lengths, expected="> 0 m")
    g, e = gt.poses[i_gt], est.poses[i_est]
    al = align(g, e, align_method, align_frames)
    e_al = al.apply(e)
    e_trans, e_rot = absolute_errors(g, e_al)
    e_scale = scale_errors_perc(g.translation, e_al.translation, rpg_quirk=scale_quirk)
    re: dict[str, dict] = {}
    out = {
        "n_matched": int(i_est.size),
        "align": al.to_dict(),
        "ate": {"trans_m": statistics(e_trans), "rot_deg": statistics(e_rot), "scale_perc": statistics(e_scale)},
        "re": re,
    }
    # one length at a time, its per-pair errors dropped once summed up (all of them at once were ~6 arrays of a
    # million pairs per length), unless the caller asks for them
    rel: dict[float, RelativeErrors] = {}
    distances = accumulated_distances(g.translation)
    for L in lengths:
        r = relative_errors_at(g, e, L, al.scale, index_shift_quirk, distances)
        re[length_key(L)] = {
            "num_pairs": len(r),
            "trans_m": statistics(r.trans),
            "trans_perc": statistics(r.trans_perc),
            "rot_deg": statistics(r.rot_deg),
            "yaw_deg": statistics(r.yaw_deg),
            "gravity_deg": statistics(r.gravity_deg),
            "rot_deg_per_m": statistics(r.rot_deg_per_m),
        }
        if details:
            rel[L] = r
    if details:
        out["_matches"] = (i_est, i_gt)
        out["_relative"] = rel
        out["_ate"] = (e_trans, e_rot)
    return out
