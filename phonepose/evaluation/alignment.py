"""Trajectory alignment ``gt ≈ s·R·est + t``: Umeyama (SE(3)/Sim(3)), rpg's yaw-only "posyaw", none.

Formulas as rpg_trajectory_evaluation's ``align_utils``/``align_trajectory`` (evo's
``geometry.umeyama_alignment`` is the same maths with the roles of its arguments swapped):

- Umeyama on the first ``n`` positions (``n = -1``: all): ``C = (1/n) Gᵀ D`` with G, D the
  centred GT and estimate positions, ``σ² = (1/n) Σ‖D_k‖²``, ``U Σ Vᵀ = svd(C)``,
  ``S = diag(1, 1, -1)`` if ``det U · det V < 0``; ``R = U S Vᵀ``, ``s = tr(Σ S)/σ²`` (sim3) or 1,
  ``t = μ_g − s R μ_e``.
- posyaw: ``R = Rz(θ)`` with ``θ = π/2 − atan2(B, A)``, ``A = Cy01 − Cy10``, ``B = Cy00 + Cy11``,
  ``Cy = Dᵀ G``; s = 1.
- ``n = 1`` (rpg's ``alignSE3Single`` / ``alignPositionYawSingle``): se3 ``R = R_gt0 R_es0ᵀ``;
  posyaw ``R = Rz(best_yaw(R_es0 R_gt0ᵀ))``; both ``t = p_gt0 − R p_es0``. sim3 needs n ≥ 2.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.errors import ConfigError
from phonepose.geometry import Pose, rotation_product

METHODS = ("posyaw", "se3", "sim3", "none")


@dataclass(frozen=True)
class Alignment:
    """``p_aligned = s·R·p_est + t``, ``R_aligned = R·R_est`` (scale never touches rotations)."""

    method: str = "none"
    num_frames: int = -1
    scale: float = 1.0
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def apply(self, poses: Pose) -> Pose:
        rot = Rotation.from_matrix(self.rotation)
        p = np.atleast_2d(poses.translation)
        return Pose(rotation_product(rot, poses.rotation), self.scale * (p @ self.rotation.T) + self.translation)

    def apply_positions(self, positions: np.ndarray) -> np.ndarray:
        return self.scale * (np.asarray(positions, dtype=float) @ self.rotation.T) + self.translation

    def to_dict(self) -> dict:
        return {"method": self.method, "num_frames": int(self.num_frames), "scale": float(self.scale),
                "rotation": self.rotation.tolist(), "translation": self.translation.tolist()}


def rot_z(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def best_yaw(c: np.ndarray) -> float:
    """θ maximising ``trace(Rz(θ)·C)`` (rpg's ``get_best_yaw``)."""
    a = c[0, 1] - c[1, 0]
    b = c[0, 0] + c[1, 1]
    return float(np.pi / 2 - np.arctan2(b, a))


DEGENERATE = ("the matched positions lie at one point or on one line, so they do not determine the alignment's "
              "rotation (any value fits): use {align} none, or {align_frames} 1 (first-pose alignment)")


def check_determined(gt_positions: np.ndarray, est_positions: np.ndarray, yaw_only: bool = False) -> None:
    """ConfigError unless the positions fix the rotation of an alignment: evo's rule (fewer than 2 singular values
    of the centred cross-covariance above machine epsilon is "degenerate covariance rank"), and for posyaw the
    same on the yaw's two terms. rpg's Umeyama has no check, and there the SVD returned an arbitrary rotation, so
    ATE rotation and RE silently depended on rounding noise (a trajectory that never moves, or 2 poses)."""
    g = np.asarray(gt_positions, dtype=float)
    d = np.asarray(est_positions, dtype=float)
    c = (g - g.mean(0)).T @ (d - d.mean(0)) / len(g)
    eps = np.finfo(float).eps
    if yaw_only:
        determined = np.hypot(c[0, 1] - c[1, 0], c[0, 0] + c[1, 1]) > eps
    else:
        determined = np.count_nonzero(np.linalg.svd(c, compute_uv=False) > eps) >= 2
    if not determined:
        raise ConfigError(DEGENERATE, parameter="align", also=["align_frames"])


def umeyama(model: np.ndarray, data: np.ndarray, with_scale: bool = False, yaw_only: bool = False):
    """``(s, R, t)`` with ``model ≈ s R data + t`` (model = GT, data = estimate), rpg's align_umeyama."""
    model = np.asarray(model, dtype=float)
    data = np.asarray(data, dtype=float)
    n = model.shape[0]
    if n < 2 and not yaw_only:
        raise ConfigError("alignment needs at least 2 matched poses")
    mu_m, mu_d = model.mean(0), data.mean(0)
    mz, dz = model - mu_m, data - mu_d
    if yaw_only:
        r = rot_z(best_yaw(dz.T @ mz))
        return 1.0, r, mu_m - r @ mu_d
    c = (1.0 / n) * (mz.T @ dz)
    sigma2 = (1.0 / n) * float(np.sum(dz * dz))
    u, d, vt = np.linalg.svd(c)
    s_mat = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt.T) < 0:
        s_mat[2, 2] = -1.0
    r = u @ s_mat @ vt
    if with_scale:
        if sigma2 <= 0:
            raise ConfigError("sim3 alignment: the estimate positions are all equal")
        scale = float(np.trace(np.diag(d) @ s_mat) / sigma2)
    else:
        scale = 1.0
    return scale, r, mu_m - scale * (r @ mu_d)


def align(gt: Pose, est: Pose, method: str = "posyaw", num_frames: int = -1) -> Alignment:
    """Alignment of ``est`` to ``gt`` (already associated, same length) with the first ``num_frames``."""
    if method not in METHODS:
        raise ConfigError(f"{{align}} {method!r}: expected one of {', '.join(METHODS)}", parameter="align",
                          value=method, expected=f"one of {', '.join(METHODS)}")
    n_total = len(gt)
    if method == "none":
        return Alignment("none", num_frames)
    if num_frames == -1 or num_frames is None:
        n = n_total
        num_frames = -1
    else:
        n = int(num_frames)
        if n < 1 or n > n_total:
            raise ConfigError(f"{{align_frames}} {num_frames}: expected -1 or 1..{n_total} (matched poses)",
                              parameter="align_frames", value=num_frames, expected=f"-1 or 1..{n_total}")
    if n_total == 0:
        raise ConfigError("nothing to align: no matched poses")
    p_gt = np.atleast_2d(gt.translation)[:n]
    p_es = np.atleast_2d(est.translation)[:n]
    if n == 1 and method in ("se3", "posyaw"):
        r_gt = gt.rotation[0].as_matrix()
        r_es = est.rotation[0].as_matrix()
        if method == "se3":
            r = r_gt @ r_es.T
        else:
            r = rot_z(best_yaw(r_es @ r_gt.T))
        return Alignment(method, num_frames, 1.0, r, p_gt[0] - r @ p_es[0])
    if method == "sim3" and n < 2:
        raise ConfigError("{align} sim3 needs {align_frames} -1 or >= 2", parameter="align_frames", value=num_frames,
                          expected="-1 or >= 2", also=["align"])
    check_determined(p_gt, p_es, yaw_only=(method == "posyaw"))
    s, r, t = umeyama(p_gt, p_es, with_scale=(method == "sim3"), yaw_only=(method == "posyaw"))
    return Alignment(method, num_frames, s, r, t)


def align_origin(gt: Pose, est: Pose) -> Alignment:
    """evo's ``--align_origin``: ``T = T_gt,0 · T_est,0⁻¹`` applied to every estimate pose."""
    return align(gt, est, "se3", 1)
