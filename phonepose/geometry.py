"""Rigid poses on top of :class:`scipy.spatial.transform.Rotation`.

A :class:`Pose` ``T_a_b`` maps points from frame ``b`` into frame ``a``:
``p_a = T_a_b.apply(p_b) = R p_b + t``. Composition follows the subscripts:
``T_a_c = T_a_b @ T_b_c``.

Quaternion order, stated once: **x, y, z, w** (scalar last), as scipy, Foxglove and TUM files
use it. A Pose may hold one pose or a stack of N poses (``len(pose)``); every operation
broadcasts like scipy's Rotation.

Raw poses (the end of this module) are plain tuples ``(qx, qy, qz, qw, x, y, z)`` with the same
meaning, for the streams playback keeps thousands of samples of: a scipy Rotation costs tens of
microseconds to build, a tuple nothing (measured: 6 µs vs 229 µs per interpolation).

This module knows no file or message format: phonepose/session/codec.py converts protobuf
messages to and from these types.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

# A quaternion whose norm is further than this from 1 is not a rotation: inputs carrying one are
# skipped (or refused), never normalised into something plausible (docs/format.md, docs/reliability.md).
QUAT_NORM_TOL = 1e-3

RawPose = tuple[float, float, float, float, float, float, float]   # (qx, qy, qz, qw, x, y, z)


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
    def from_raw(cls, raw: RawPose) -> "Pose":
        """From a raw ``(qx, qy, qz, qw, x, y, z)`` tuple (its quaternion is unit already)."""
        return cls(Rotation.from_quat(raw[:4]), np.array(raw[4:], dtype=float))

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

    def as_raw(self) -> RawPose:
        """A single pose as a raw ``(qx, qy, qz, qw, x, y, z)`` tuple of Python floats."""
        q = self.quat_xyzw.tolist()
        t = np.asarray(self.translation, dtype=float).tolist()
        return (q[0], q[1], q[2], q[3], t[0], t[1], t[2])

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


# ----------------------------------------------------------------------------- raw poses
# Written by hand for speed (see the module docstring); tests/test_geometry.py checks every branch
# against scipy. Quaternions are unit, x, y, z, w.
_NEAR_PARALLEL = 0.9999995   # |q0 . q1| above this: linear blend (sin(theta) ~ 1e-3 would lose digits)


def quat_slerp(q0, q1, a: float) -> tuple[float, float, float, float]:
    """Spherical linear interpolation from ``q0`` (a = 0) to ``q1`` (a = 1), the short way round."""
    dot = q0[0] * q1[0] + q0[1] * q1[1] + q0[2] * q1[2] + q0[3] * q1[3]
    if dot < 0.0:
        q1 = (-q1[0], -q1[1], -q1[2], -q1[3])
        dot = -dot
    if dot > _NEAR_PARALLEL:
        w0, w1 = 1.0 - a, a
    else:
        theta = math.acos(min(1.0, dot))
        s = math.sin(theta)
        w0 = math.sin((1.0 - a) * theta) / s
        w1 = math.sin(a * theta) / s
    q = (w0 * q0[0] + w1 * q1[0], w0 * q0[1] + w1 * q1[1], w0 * q0[2] + w1 * q1[2], w0 * q0[3] + w1 * q1[3])
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def quat_mul(a, b) -> tuple[float, float, float, float]:
    """Hamilton product ``a · b`` (rotation ``b`` first, then ``a``)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def quat_rotate(q, v) -> tuple[float, float, float]:
    """The vector ``v`` rotated by the unit quaternion ``q``."""
    x, y, z, w = q
    # v + 2w (q_v x v) + 2 q_v x (q_v x v)
    cx, cy, cz = y * v[2] - z * v[1], z * v[0] - x * v[2], x * v[1] - y * v[0]
    ccx, ccy, ccz = y * cz - z * cy, z * cx - x * cz, x * cy - y * cx
    return (v[0] + 2 * (w * cx + ccx), v[1] + 2 * (w * cy + ccy), v[2] + 2 * (w * cz + ccz))


def raw_interpolate(s0: RawPose, s1: RawPose, a: float) -> RawPose:
    """The raw pose a fraction ``a`` of the way from ``s0`` to ``s1``: slerp rotation, linear translation."""
    q = quat_slerp(s0[:4], s1[:4], a)
    b = 1.0 - a
    return q + (b * s0[4] + a * s1[4], b * s0[5] + a * s1[5], b * s0[6] + a * s1[6])


def raw_compose(a: RawPose, b: RawPose) -> RawPose:
    """Raw ``a · b`` (as ``Pose.__matmul__``), the quaternion renormalised."""
    t = quat_rotate(a[:4], b[4:])
    q = quat_mul(a[:4], b[:4])
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n, t[0] + a[4], t[1] + a[5], t[2] + a[6])


# ----------------------------------------------------------------------------- single rotations, closed form
# For a per-tick path that composes a handful of single rotations (T8: phonepose/pipeline/fusion.py): a
# scipy Rotation costs tens of microseconds per operation through its array-API layer, these cost about
# one. They follow scipy's own formulas (the Taylor branches below 1e-3 rad included), so results agree
# to rounding; tests/test_geometry.py checks each against scipy.
Quat = tuple[float, float, float, float]      # x, y, z, w; unit
_SMALL_ANGLE = 1e-3                            # scipy's switch to the Taylor series (from_rotvec, as_rotvec)


def quat_conj(q: Quat) -> Quat:
    """The inverse of a unit quaternion (as ``Rotation.inv``: the vector part negated)."""
    return (-q[0], -q[1], -q[2], q[3])


def quat_from_rotvec(v) -> Quat:
    """``Rotation.from_rotvec(v).as_quat()`` for one rotation vector (rad)."""
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    angle = math.sqrt(x * x + y * y + z * z)
    if angle <= _SMALL_ANGLE:
        a2 = angle * angle
        s = 0.5 - a2 / 48 + a2 * a2 / 3840
    else:
        s = math.sin(angle / 2) / angle
    return (x * s, y * s, z * s, math.cos(angle / 2))


def quat_as_rotvec(q: Quat) -> tuple[float, float, float]:
    """``Rotation.from_quat(q).as_rotvec()``: the short way round (the quaternion with w >= 0)."""
    x, y, z, w = q
    if w < 0:
        x, y, z, w = -x, -y, -z, -w
    angle = 2 * math.atan2(math.sqrt(x * x + y * y + z * z), w)
    if angle <= _SMALL_ANGLE:
        a2 = angle * angle
        s = 2 + a2 / 12 + 7 * a2 * a2 / 2880
    else:
        s = angle / math.sin(angle / 2)
    return (x * s, y * s, z * s)


def quat_as_matrix(q: Quat) -> np.ndarray:
    """``Rotation.from_quat(q).as_matrix()`` for a unit quaternion."""
    x, y, z, w = q
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    return np.array([[x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw)],
                     [2 * (xy + zw), -x2 + y2 - z2 + w2, 2 * (yz - xw)],
                     [2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2]])


def quat_normalised(q: Quat) -> Quat:
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)
