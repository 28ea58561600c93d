"""Rigid poses on top of :class:`scipy.spatial.transform.Rotation`.

A :class:`Pose` ``T_a_b`` maps points from frame ``b`` into frame ``a``:
``p_a = T_a_b.apply(p_b) = R p_b + t``. Composition follows the subscripts:
``T_a_c = T_a_b @ T_b_c``.

Quaternion order, stated once: **x, y, z, w** (scalar last), as scipy, Foxglove and TUM files
use it. A Pose may hold one pose or a stack of N poses (``len(pose)``); every operation
broadcasts like scipy's Rotation.
"""

from __future__ import annotations

from dataclasses import dataclass
import numpy as np
from foxglove_schemas_protobuf.Pose_pb2 import Pose as FgPose
from scipy.spatial.transform import Rotation, Slerp


@dataclass(frozen=True)
class Pose:
    rotation: Rotation
    translation: np.ndarray  # (3,) or (N, 3)

    # ----------------------------------------------------------------- constructors
    @classmethod
    def identity(cls, n: int | None = None) -> "Pose":
        if n is None:
            return cls(Rotation.identity(), np.zeros(3))
        return cls(Rotation.identity(n), np.zeros((n, 3)))

    @classmethod
    def from_xyzw(cls, translation, quat_xyzw) -> "Pose":
        """From translation(s) and x,y,z,w quaternion(s); quaternions are normalised."""
        return cls(Rotation.from_quat(np.asarray(quat_xyzw, dtype=float)), np.asarray(translation, dtype=float))

    @classmethod
    def from_matrix(cls, matrix) -> "Pose":
        m = np.asarray(matrix, dtype=float)
        return cls(Rotation.from_matrix(m[..., :3, :3]), m[..., :3, 3].copy())

    @classmethod
    def from_rotvec(cls, translation, rotvec) -> "Pose":
        return cls(Rotation.from_rotvec(np.asarray(rotvec, dtype=float)), np.asarray(translation, dtype=float))

    @classmethod
    def from_cv(cls, rvec, tvec) -> "Pose":
        """From OpenCV's rvec/tvec (as returned by solvePnP): the object frame in the camera frame."""
        return cls.from_rotvec(np.asarray(tvec, dtype=float).reshape(3), np.asarray(rvec, dtype=float).reshape(3))

    @classmethod
    def from_foxglove(cls, pose: FgPose) -> "Pose":
        p, q = pose.position, pose.orientation
        return cls.from_xyzw([p.x, p.y, p.z], [q.x, q.y, q.z, q.w])

    @classmethod
    def concatenate(cls, poses: "list[Pose]") -> "Pose":
        rots = Rotation.concatenate([p.rotation for p in poses])
        trans = np.vstack([np.atleast_2d(p.translation) for p in poses])
        return cls(rots, trans)

    # ----------------------------------------------------------------- conversions
    @property
    def quat_xyzw(self) -> np.ndarray:
        return self.rotation.as_quat(canonical=False)

    def as_matrix(self) -> np.ndarray:
        m = np.zeros(self.translation.shape[:-1] + (4, 4))
        m[..., :3, :3] = self.rotation.as_matrix()
        m[..., :3, 3] = self.translation
        m[..., 3, 3] = 1.0
        return m

    def as_cv(self) -> tuple[np.ndarray, np.ndarray]:
        """(rvec, tvec) as float64 column vectors for OpenCV."""
        return self.rotation.as_rotvec().reshape(3, 1), self.translation.reshape(3, 1).astype(float)

    def to_foxglove(self, out: FgPose | None = None) -> FgPose:
        msg = FgPose() if out is None else out
        # tolist() gives Python floats in one call (playback writes one per tracker per tick)
        p, o = msg.position, msg.orientation
        p.x, p.y, p.z = np.asarray(self.translation, dtype=float).tolist()
        o.x, o.y, o.z, o.w = self.quat_xyzw.tolist()
        return msg

    # ----------------------------------------------------------------- algebra
    def __matmul__(self, other: "Pose") -> "Pose":
        return Pose(self.rotation * other.rotation, self.rotation.apply(other.translation) + self.translation)

    def inv(self) -> "Pose":
        r_inv = self.rotation.inv()
        return Pose(r_inv, -r_inv.apply(self.translation))

    def apply(self, points) -> np.ndarray:
        return self.rotation.apply(np.asarray(points, dtype=float)) + self.translation

    def relative_to(self, other: "Pose") -> "Pose":
        """``other⁻¹ · self``: this pose expressed in the frame of ``other``."""
        return other.inv() @ self

    def __len__(self) -> int:
        return len(self.rotation)

    def __getitem__(self, index) -> "Pose":
        return Pose(self.rotation[index], self.translation[index])

    @property
    def single(self) -> bool:
        return self.rotation.single

    def angle_to(self, other: "Pose") -> np.ndarray:
        """Rotation angle (rad) between the two orientations."""
        return (self.rotation.inv() * other.rotation).magnitude()

    def distance_to(self, other: "Pose") -> np.ndarray:
        return np.linalg.norm(self.translation - other.translation, axis=-1)

    def allclose(self, other: "Pose", atol: float = 1e-9) -> bool:
        return bool(np.all(self.distance_to(other) <= atol) and np.all(self.angle_to(other) <= atol))


def is_finite(pose: Pose | None) -> bool:
    """A pose with no NaN/inf anywhere (None is not finite): broken inputs are skipped, never used."""
    return pose is not None and bool(np.isfinite(pose.translation).all() and np.isfinite(pose.rotation.as_quat()).all())


def interpolate(t0: float, pose0: Pose, t1: float, pose1: Pose, t: float) -> Pose:
    """Pose at time ``t`` between two single poses: linear translation, slerp rotation."""
    if t1 == t0:
        return pose0
    a = (t - t0) / (t1 - t0)
    # slerp of two rotations as scipy composes it, without building a Slerp object (a third of the cost)
    rot = pose0.rotation * Rotation.from_rotvec(a * (pose0.rotation.inv() * pose1.rotation).as_rotvec())
    return Pose(rot, (1.0 - a) * pose0.translation + a * pose1.translation)


def interpolate_many(times: np.ndarray, poses: Pose, query: np.ndarray) -> Pose:
    """Poses at ``query`` times from a stamped stack (times ascending, query within range)."""
    slerp = Slerp(np.asarray(times, dtype=float), poses.rotation)
    q = np.asarray(query, dtype=float)
    trans = np.column_stack([np.interp(q, times, poses.translation[:, k]) for k in range(3)])
    return Pose(slerp(q), trans)
