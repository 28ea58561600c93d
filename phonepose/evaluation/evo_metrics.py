"""evo-compatible APE and RPE (evo 1.38.1 ``evo.core.metrics``), whole-array numpy.

Same shape of API as evo: a metric object per metric, configured by enums, with one verb
``process_data((ref, est))`` and ``get_statistic`` / ``get_all_statistics``; ``ref`` and ``est``
are associated :class:`~phonepose.geometry.Pose` stacks of equal length. evo loops in Python over
4x4 matrices per pose; here every pose (pair) is one row of an array.

- APE: ``E_i = P_est,i⁻¹ · P_ref,i``; ``translation_part`` = ``‖t_est − t_ref‖``,
  ``rotation_angle_*`` = angle of R_E, ``rotation_part`` = ``‖R_E − I‖_F``, ``full`` = ``‖E − I‖_F``.
- RPE: ``E_ij = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)`` (Q reference, P estimate), pairs by
  :func:`id_pairs_from_delta` on the estimate (or the reference) poses, as evo ≥ 1.37.1.
- Alignment (``-a``/``-as``): Umeyama of the estimate onto the reference with the first n poses,
  the estimate translations scaled by s first, then ``[R|t]`` on the left.
"""

from __future__ import annotations

from enum import Enum

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.errors import ConfigError, SessionContentError
from phonepose.evaluation.alignment import Alignment, align, check_determined, umeyama
from phonepose.evaluation.association import associate_evo, associate_index
from phonepose.evaluation.stats import statistics
from phonepose.evaluation.trajectory import Trajectory
from phonepose.geometry import Pose, rotation_inverse, rotation_product


class PoseRelation(Enum):
    full_transformation = "full transformation"
    translation_part = "translation part"
    rotation_part = "rotation part"
    rotation_angle_rad = "rotation angle in radians"
    rotation_angle_deg = "rotation angle in degrees"
    point_distance = "point distance"
    point_distance_error_ratio = "point distance error ratio"


class Unit(Enum):
    frames = "frames"
    meters = "m"
    degrees = "deg"
    radians = "rad"


RELATION_NAMES = {
    "trans": PoseRelation.translation_part, "trans_part": PoseRelation.translation_part,
    "angle": PoseRelation.rotation_angle_deg, "angle_deg": PoseRelation.rotation_angle_deg,
    "angle_rad": PoseRelation.rotation_angle_rad, "rot_part": PoseRelation.rotation_part,
    "full": PoseRelation.full_transformation, "point_distance": PoseRelation.point_distance,
    "point_distance_error_ratio": PoseRelation.point_distance_error_ratio,
}
UNIT_NAMES = {"f": Unit.frames, "m": Unit.meters, "d": Unit.degrees, "r": Unit.radians}


def relation(name: str | PoseRelation) -> PoseRelation:
    if isinstance(name, PoseRelation):
        return name
    if name not in RELATION_NAMES:
        raise ConfigError(f"{{pose_relation}} {name!r}: expected one of {', '.join(RELATION_NAMES)}",
                          parameter="pose_relation", value=name, expected=f"one of {', '.join(RELATION_NAMES)}")
    return RELATION_NAMES[name]


def _errors_from_relative(rel: PoseRelation, r_e: np.ndarray, t_e: np.ndarray) -> np.ndarray:
    if rel == PoseRelation.translation_part:
        return np.sqrt(np.sum(t_e * t_e, axis=1))
    dr = r_e - np.eye(3)
    rot_f2 = np.sum(dr * dr, axis=(1, 2))
    if rel == PoseRelation.rotation_part:
        return np.sqrt(rot_f2)
    if rel == PoseRelation.full_transformation:
        return np.sqrt(rot_f2 + np.sum(t_e * t_e, axis=1))
    angle = np.linalg.norm(Rotation.from_matrix(r_e).as_rotvec(), axis=1)
    if rel == PoseRelation.rotation_angle_deg:
        return np.rad2deg(angle)
    if rel == PoseRelation.rotation_angle_rad:
        return angle
    raise ConfigError(f"pose relation {rel.value} not supported here")


class _PE:
    error: np.ndarray

    def get_statistic(self, name: str) -> float | None:
        return statistics(self.error, sse=True)[name]

    def get_all_statistics(self) -> dict:
        s = statistics(self.error, sse=True)
        s.pop("num_samples")
        return s


class APE(_PE):
    def __init__(self, pose_relation: PoseRelation = PoseRelation.translation_part):
        self.pose_relation = relation(pose_relation)
        self.error = np.zeros(0)

    def process_data(self, data: tuple[Pose, Pose]) -> None:
        ref, est = data
        if len(ref) != len(est):
            raise ConfigError("APE: trajectories must have the same number of poses")
        rel = self.pose_relation
        pr, pe = np.atleast_2d(ref.translation), np.atleast_2d(est.translation)
        if rel in (PoseRelation.translation_part, PoseRelation.point_distance):
            d = pe - pr
            self.error = np.sqrt(np.sum(d * d, axis=1))
            return
        re_ = est.rotation.as_matrix()
        rr = ref.rotation.as_matrix()
        r_e = np.einsum("kji,kjl->kil", re_, rr)
        t_e = np.einsum("kji,kj->ki", re_, pr - pe)
        self.error = _errors_from_relative(rel, r_e, t_e)


# ----------------------------------------------------------------------------- pair selection
def _first_crossings(steps: np.ndarray, delta: float) -> list[int]:
    """evo's consecutive accumulation with reset: ids where the running sum since the last id reaches
    ``delta``, summed left to right as evo does. A loop over Python floats: far cheaper per step than a
    numpy call per emitted pair."""
    ids = [0]
    acc = 0.0
    for k, step in enumerate(steps.tolist(), start=1):
        acc += step
        if acc >= delta:
            ids.append(k)
            acc = 0.0
    return ids


def _all_pairs_by_path(d: np.ndarray, delta: float, tol: float) -> np.ndarray:
    n = d.size
    if n < 2:
        return np.zeros((0, 2), np.int64)
    i = np.arange(n - 1)
    k = np.searchsorted(d, d[i] + delta, side="left")
    cand = np.stack([k - 2, k - 1, k, k + 1], axis=1)
    valid = (cand >= (i + 1)[:, None]) & (cand < n)
    cc = np.clip(cand, 0, n - 1)
    err = np.abs((d[cc] - d[i][:, None]) - delta)
    err = np.where(valid, err, np.inf)
    a = np.argmin(err, axis=1)
    best = cc[i, a]
    best_err = err[i, a]
    best = np.maximum(np.searchsorted(d, d[best], side="left"), i + 1)  # first j on a plateau
    ok = best_err <= tol
    return np.stack([i[ok], best[ok]], axis=1).astype(np.int64)


def id_pairs_from_delta(poses: Pose, delta: float, delta_unit: Unit, rel_tol: float = 0.1,
                        all_pairs: bool = False) -> np.ndarray:
    """evo 1.38.1's ``id_pairs_from_delta`` as a (K, 2) int array."""
    n = len(poses)
    if delta_unit == Unit.frames:
        step = int(delta)
        if step < 1:
            raise ConfigError(f"{{delta}} {delta}: frames must be >= 1", parameter="delta", value=delta, expected=">= 1")
        if all_pairs:
            i = np.arange(max(n - step, 0))
            pairs = np.stack([i, i + step], axis=1)
        else:
            ids = np.arange(0, n, step)
            pairs = np.stack([ids[:-1], ids[1:]], axis=1)
    elif delta_unit == Unit.meters:
        p = np.atleast_2d(poses.translation)
        dp = p[:-1] - p[1:]
        steps = np.sqrt(np.sum(dp * dp, axis=1))
        if all_pairs:
            d = np.concatenate(([0.0], np.cumsum(steps)))
            pairs = _all_pairs_by_path(d, delta, delta * rel_tol)
        else:
            ids = np.asarray(_first_crossings(steps, delta))
            pairs = np.stack([ids[:-1], ids[1:]], axis=1)
    elif delta_unit in (Unit.degrees, Unit.radians):
        degrees = delta_unit == Unit.degrees
        if not (0 <= delta <= (180.0 if degrees else np.pi)):
            raise ConfigError(f"{{delta}} {delta}: an angle must be within [0, {180 if degrees else 'pi'}]",
                              parameter="delta", value=delta, expected=f"within [0, {180 if degrees else 'pi'}]")
        d_rad = np.deg2rad(delta) if degrees else delta
        tol = np.deg2rad(delta * rel_tol) if degrees else delta * rel_tol
        rot = poses.rotation
        if all_pairs:
            q = rot.as_quat()
            chunks = []
            for a in range(0, n - 1, 256):  # chunks of start poses (O(n^2) pairs as evo)
                ii = np.arange(a, min(a + 256, n - 1))
                dots = np.abs(np.clip(q[ii] @ q.T, -1.0, 1.0))
                ang = 2.0 * np.arccos(np.clip(dots, 0.0, 1.0))
                ok = (ang >= d_rad - tol) & (ang <= d_rad + tol) & (np.arange(n)[None, :] > ii[:, None])
                r, c = np.nonzero(ok)
                chunks.append(np.stack([ii[r], c], axis=1))
            pairs = np.concatenate(chunks) if chunks else np.zeros((0, 2), np.int64)
        else:
            steps = rotation_product(rotation_inverse(rot[:-1]), rot[1:]).magnitude() if n >= 2 else np.zeros(0)
            ids = _first_crossings(np.atleast_1d(steps), d_rad)
            pairs = np.stack([np.asarray(ids[:-1]), np.asarray(ids[1:])], axis=1)
    else:  # pragma: no cover
        raise ConfigError(f"unsupported delta unit {delta_unit}")
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if pairs.shape[0] == 0:
        raise ConfigError(f"{{delta}} {delta} ({delta_unit.value}) produced no pairs: try a lower value",
                          parameter="delta", value=delta)
    return pairs


class RPE(_PE):
    def __init__(self, pose_relation: PoseRelation = PoseRelation.translation_part, delta: float = 1.0,
                 delta_unit: Unit = Unit.frames, rel_delta_tol: float = 0.1, all_pairs: bool = False,
                 pairs_from_reference: bool = False):
        if delta < 0:
            raise ConfigError("{delta} must be a positive number", parameter="delta", value=delta, expected="> 0")
        if delta_unit == Unit.frames and not float(delta).is_integer():
            raise ConfigError(f"{{delta}} {delta}: must be an integer for frames", parameter="delta", value=delta,
                              expected="an integer")
        self.pose_relation = relation(pose_relation)
        self.delta = int(delta) if delta_unit == Unit.frames else float(delta)
        self.delta_unit = delta_unit
        self.rel_delta_tol = rel_delta_tol
        self.all_pairs = all_pairs
        self.pairs_from_reference = pairs_from_reference
        self.error = np.zeros(0)
        self.id_pairs = np.zeros((0, 2), np.int64)

    def process_data(self, data: tuple[Pose, Pose]) -> None:
        ref, est = data
        if len(ref) != len(est):
            raise ConfigError("RPE: trajectories must have the same number of poses")
        pairs = id_pairs_from_delta(ref if self.pairs_from_reference else est, self.delta, self.delta_unit,
                                    self.rel_delta_tol, self.all_pairs)
        i, j = pairs[:, 0], pairs[:, 1]
        pr, pe = np.atleast_2d(ref.translation), np.atleast_2d(est.translation)
        rel = self.pose_relation
        if rel in (PoseRelation.point_distance, PoseRelation.point_distance_error_ratio):
            dr = np.linalg.norm(pr[i] - pr[j], axis=1)
            de = np.linalg.norm(pe[i] - pe[j], axis=1)
            err = np.abs(dr - de)
            if rel == PoseRelation.point_distance_error_ratio:
                nz = dr != 0
                err, pairs = err[nz] / dr[nz] * 100, pairs[nz]
            self.error, self.id_pairs = err, pairs
            return
        rq, rp = ref.rotation.as_matrix(), est.rotation.as_matrix()
        r_q = np.einsum("kji,kjl->kil", rq[i], rq[j])
        t_q = np.einsum("kji,kj->ki", rq[i], pr[j] - pr[i])
        r_p = np.einsum("kji,kjl->kil", rp[i], rp[j])
        t_p = np.einsum("kji,kj->ki", rp[i], pe[j] - pe[i])
        r_e = np.einsum("kji,kjl->kil", r_q, r_p)
        t_e = np.einsum("kji,kj->ki", r_q, t_p - t_q)
        self.error = _errors_from_relative(rel, r_e, t_e)
        self.id_pairs = pairs


# ----------------------------------------------------------------------------- drivers
def evo_align(ref: Pose, est: Pose, method: str = "none", n_to_align: int = -1) -> Alignment:
    """evo's ``-a`` (se3) / ``-as`` (sim3) Umeyama on the first n poses; also posyaw/none (ours)."""
    if method in ("se3", "sim3"):
        if len(ref) < 2:
            raise ConfigError(f"{{align}} {method} needs at least 2 matched poses, there is {len(ref)}: use {{align}} "
                              "none", parameter="align", value=method)
        n = len(ref) if n_to_align in (-1, None) else int(n_to_align)
        if n < 2 or n > len(ref):
            raise ConfigError(f"{{align_frames}} {n_to_align}: evo's Umeyama needs -1 or 2..{len(ref)} poses",
                              parameter="align_frames", value=n_to_align, expected=f"-1 or 2..{len(ref)}")
        p_ref = np.atleast_2d(ref.translation)[:n]
        p_est = np.atleast_2d(est.translation)[:n]
        check_determined(p_ref, p_est)     # evo's "degenerate covariance rank"
        s, r, t = umeyama(p_ref, p_est, with_scale=(method == "sim3"))
        return Alignment(method, -1 if n_to_align in (-1, None) else n, s, r, t)
    return align(ref, est, method, n_to_align)


def associate(gt: Trajectory, est: Trajectory, max_diff: float = 0.01):
    if gt.stamps is None or est.stamps is None:
        if len(gt) != len(est):
            raise ConfigError(f"index-matched (KITTI) trajectories need the same length: {len(gt)} vs {len(est)}")
        return associate_index(len(est), len(gt))
    i_est, i_gt = associate_evo(est.stamps, gt.stamps, max_diff)
    if i_est.size == 0:
        raise SessionContentError(f"no matching stamps between {gt.source or 'GT'} and {est.source or 'estimate'} "
                          f"(|dt| <= {max_diff} s)")
    return i_est, i_gt


def _matched(poses: Pose, index: np.ndarray) -> Pose:
    """``poses[index]``, without the copy when the index takes every pose in order (KITTI)."""
    if index.size == len(poses) and (index.size == 0 or (index[0] == 0 and np.all(np.diff(index) == 1))):
        return poses
    return poses[index]


def evaluate_ape(gt: Trajectory, est: Trajectory, pose_relation="trans", align_method: str = "none",
                 align_frames: int = -1, max_diff: float = 0.01, matches=None) -> dict:
    i_est, i_gt = associate(gt, est, max_diff) if matches is None else matches
    ref, e = _matched(gt.poses, i_gt), _matched(est.poses, i_est)
    al = evo_align(ref, e, align_method, align_frames)
    m = APE(relation(pose_relation))
    m.process_data((ref, al.apply(e)))
    return {"n_matched": int(i_est.size), "align": al.to_dict(),
            "ape": {"pose_relation": m.pose_relation.value, "num_samples": int(m.error.size),
                    **m.get_all_statistics()}}


def evaluate_rpe(gt: Trajectory, est: Trajectory, pose_relation="trans", delta: float = 1.0,
                 delta_unit: str | Unit = "f", all_pairs: bool = False, pairs_from_reference: bool = False,
                 rel_delta_tol: float = 0.1, align_method: str = "none", align_frames: int = -1,
                 max_diff: float = 0.01, matches=None) -> dict:
    unit = delta_unit if isinstance(delta_unit, Unit) else UNIT_NAMES.get(delta_unit)
    if unit is None:
        raise ConfigError(f"{{delta_unit}} {delta_unit!r}: expected one of {', '.join(UNIT_NAMES)}",
                          parameter="delta_unit", value=delta_unit, expected=f"one of {', '.join(UNIT_NAMES)}")
    i_est, i_gt = associate(gt, est, max_diff) if matches is None else matches
    ref, e = _matched(gt.poses, i_gt), _matched(est.poses, i_est)
    al = evo_align(ref, e, align_method, align_frames)
    m = RPE(relation(pose_relation), delta, unit, rel_delta_tol, all_pairs, pairs_from_reference)
    m.process_data((ref, al.apply(e)))
    return {"n_matched": int(i_est.size), "align": al.to_dict(),
            "rpe": {"pose_relation": m.pose_relation.value, "delta": m.delta, "delta_unit": unit.value,
                    "all_pairs": all_pairs, "pairs_from_reference": pairs_from_reference,
                    "num_samples": int(m.error.size), **m.get_all_statistics()}}
