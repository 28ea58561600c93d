"""Rigid poses on top of :class:`scipy.spatial.transform.Rotation`.

A :class:`Pose` ``T_a_b`` maps points from frame ``b`` into frame ``a``:
``p_a = T_a_b.apply(p_b) = R p_b + t``. Composition follows the subscripts:
``T_a_c = T_a_b @ T_b_c``.

Quaternion order, stated once: **x, y, z, w** (scalar last), as scipy, Foxglove and TUM files
use it. A Pose may hold one pose or a stack of N poses (``len(pose)``); every operation
broadcasts like scipy's Rotation.

Raw poses (the end of this module) are plain tuples ``(qx, qy, qz, qw, x, y, z)`` with the same
meaning, for the streams playback keeps thousands of samples of: a scipy Rotation costs tens of
microseconds to build, a tuple nothing.

This module knows no file or message format: phonepose/session/codec.py converts protobuf
messages to and from these types.
"""

from __future__ import annotations

import math
from typing import TypeGuard

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from phonepose.series import interp_columns

# A quaternion whose norm is further than this from 1 is not a rotation: inputs carrying one are
# skipped (or refused), never normalised into something plausible (docs/format.md, docs/reliability.md).
QUAT_NORM_TOL = 1e-3

RawPose = tuple[float, float, float, float, float, float, float]   # (qx, qy, qz, qw, x, y, z)


Quat = tuple[float, float, float, float]   # (qx, qy, qz, qw), unit


class Pose:
    """One rigid pose or a stack of N (``rotation``: a scipy Rotation, ``translation``: (3,) or (N, 3)).

    Treat it as immutable. A single pose keeps its quaternion as a tuple of floats and builds the
    scipy Rotation only when ``rotation`` is read: every operation below on single poses runs the
    scalar code at the end of this module instead of scipy's (see "single poses" there). Stacks go
    through scipy as they always did.
    """

    __slots__ = ("_rotation", "_quat", "translation")

    def __init__(self, rotation: Rotation, translation) -> None:
        self._rotation: Rotation | None = rotation
        self._quat: Quat | None = None
        self.translation = translation

    @classmethod
    def _of(cls, quat: Quat, translation: np.ndarray) -> Pose:
        """A single pose from a unit quaternion tuple, no check, no scipy object."""
        pose = cls.__new__(cls)
        pose._rotation = None
        pose._quat = quat
        pose.translation = translation
        return pose

    @property
    def rotation(self) -> Rotation:
        rotation = self._rotation
        if rotation is None:
            rotation = self._rotation = Rotation(np.array(self._quat), normalize=False, copy=False)
        return rotation

    def _q(self) -> Quat | None:
        """The quaternion tuple of a single pose, None for a stack."""
        quat = self._quat
        if quat is None and self._rotation is not None and self._rotation.single:
            quat = self._quat = tuple(self._rotation.as_quat().tolist())
        return quat

    def __reduce__(self):
        return (Pose, (self.rotation, self.translation))

    def __repr__(self) -> str:
        return f"Pose(quat_xyzw={self.quat_xyzw!r}, translation={self.translation!r})"

    # ----------------------------------------------------------------- constructors
    @classmethod
    def identity(cls, n: int | None = None) -> Pose:
        if n is None:
            return cls._of((0.0, 0.0, 0.0, 1.0), np.zeros(3))
        return cls(Rotation.identity(n), np.zeros((n, 3)))

    @classmethod
    def from_xyzw(cls, translation, quat_xyzw) -> Pose:
        """From translation(s) and x,y,z,w quaternion(s); quaternions are normalised."""
        quat = np.asarray(quat_xyzw, dtype=float)
        if quat.shape == (4,):
            return cls._of(quat_normalised(quat.tolist()), np.asarray(translation, dtype=float))
        return cls(Rotation.from_quat(quat), np.asarray(translation, dtype=float))

    @classmethod
    def from_matrix(cls, matrix) -> Pose:
        m = np.asarray(matrix, dtype=float)
        return cls(Rotation.from_matrix(m[..., :3, :3]), m[..., :3, 3].copy())

    @classmethod
    def from_rotvec(cls, translation, rotvec) -> Pose:
        rv = np.asarray(rotvec, dtype=float)
        if rv.shape == (3,):
            return cls._of(quat_from_rotvec(rv.tolist()), np.asarray(translation, dtype=float))
        return cls(Rotation.from_rotvec(rv), np.asarray(translation, dtype=float))

    @classmethod
    def from_cv(cls, rvec, tvec) -> Pose:
        """From OpenCV's rvec/tvec (as returned by solvePnP): the object frame in the camera frame."""
        return cls.from_rotvec(np.asarray(tvec, dtype=float).reshape(3), np.asarray(rvec, dtype=float).reshape(3))

    @classmethod
    def from_raw(cls, raw: RawPose) -> Pose:
        """From a raw ``(qx, qy, qz, qw, x, y, z)`` tuple (normalised once more, as scipy's from_quat would)."""
        return cls._of(quat_normalised(raw),
                       np.array(raw[4:], dtype=float))

    @classmethod
    def concatenate(cls, poses: list[Pose]) -> Pose:
        rots = Rotation.concatenate([p.rotation for p in poses])
        trans = np.vstack([np.atleast_2d(p.translation) for p in poses])
        return cls(rots, trans)

    # ----------------------------------------------------------------- conversions
    @property
    def quat_xyzw(self) -> np.ndarray:
        q = self._q()
        if q is not None:
            return np.array(q)
        return self.rotation.as_quat(canonical=False)

    def as_matrix(self) -> np.ndarray:
        m = np.zeros(self.translation.shape[:-1] + (4, 4))
        m[..., :3, :3] = self.rotation.as_matrix()
        m[..., :3, 3] = self.translation
        m[..., 3, 3] = 1.0
        return m

    def as_cv(self) -> tuple[np.ndarray, np.ndarray]:
        """(rvec, tvec) as float64 column vectors for OpenCV."""
        q = self._q()
        rvec = np.array(quat_as_rotvec(q)) if q is not None else self.rotation.as_rotvec()
        return rvec.reshape(3, 1), self.translation.reshape(3, 1).astype(float)

    def as_raw(self) -> RawPose:
        """A single pose as a raw ``(qx, qy, qz, qw, x, y, z)`` tuple of Python floats."""
        q = self._q()
        if q is None:
            q = tuple(self.rotation.as_quat(canonical=False).tolist())  # raises as scipy does for a stack
        t = np.asarray(self.translation, dtype=float).tolist()
        return (q[0], q[1], q[2], q[3], t[0], t[1], t[2])

    def with_translation(self, translation) -> Pose:
        """The same rotation at another position."""
        q = self._q()
        if q is not None:
            return Pose._of(q, translation)
        return Pose(self.rotation, translation)

    # ----------------------------------------------------------------- algebra
    def __matmul__(self, other: Pose) -> Pose:
        qa, qb = self._q(), other._q()
        if qa is not None and qb is not None and np.ndim(other.translation) == 1:
            return Pose._of(quat_compose(qa, qb), quat_apply(qa, other.translation) + self.translation)
        return Pose(rotation_product(self.rotation, other.rotation),
                    self.rotation.apply(other.translation) + self.translation)

    def inv(self) -> Pose:
        q = self._q()
        if q is not None and np.ndim(self.translation) == 1:
            q_inv = quat_inv(q)
            return Pose._of(q_inv, -quat_apply(q_inv, self.translation))
        r_inv = rotation_inverse(self.rotation)
        return Pose(r_inv, -r_inv.apply(self.translation))

    def rotate(self, vectors) -> np.ndarray:
        """The vector(s) rotated by this pose's rotation only (``rotation.apply``)."""
        q = self._q()
        vectors = np.asarray(vectors, dtype=float)
        if q is not None and vectors.ndim == 1:
            return quat_apply(q, vectors)
        return self.rotation.apply(vectors)

    def apply(self, points) -> np.ndarray:
        q = self._q()
        points = np.asarray(points, dtype=float)
        if q is not None and points.ndim == 1:
            return quat_apply(q, points) + self.translation
        return self.rotation.apply(points) + self.translation

    def relative_to(self, other: Pose) -> Pose:
        """``other⁻¹ · self``: this pose expressed in the frame of ``other``."""
        return other.inv() @ self

    def __len__(self) -> int:
        return len(self.rotation)

    def __getitem__(self, index) -> Pose:
        # the stored quaternions indexed directly: scipy's __getitem__ is slow on large stacks
        q = self.rotation.as_quat()
        if q.ndim == 1:
            raise TypeError("Single rotation is not subscriptable.")
        return Pose(Rotation(q[index], normalize=False, copy=False), self.translation[index])

    @property
    def single(self) -> bool:
        return self._q() is not None

    def angle_to(self, other: Pose) -> np.ndarray | np.float64:
        """Rotation angle (rad) between the two orientations (a scalar for single poses)."""
        qa, qb = self._q(), other._q()
        if qa is not None and qb is not None:
            return np.float64(quat_magnitude(quat_compose(quat_inv(qa), qb)))
        return rotation_product(rotation_inverse(self.rotation), other.rotation).magnitude()

    def distance_to(self, other: Pose) -> np.ndarray:
        return np.linalg.norm(self.translation - other.translation, axis=-1)

    def allclose(self, other: Pose, atol: float = 1e-9) -> bool:
        return bool(np.all(self.distance_to(other) <= atol) and np.all(self.angle_to(other) <= atol))


def rotation_product(a: Rotation, b: Rotation) -> Rotation:
    """``a * b`` of scipy Rotations (single or stacks, broadcast), vectorised in numpy with scipy's
    arithmetic (so the same bits): scipy's compiled loop allocates per rotation."""
    p, q = a.as_quat(), b.as_quat()
    if p.ndim > 2 or q.ndim > 2:
        return a * b
    p0, p1, p2, p3 = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    q0, q1, q2, q3 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.stack([p3 * q0 + q3 * p0 + (p1 * q2 - p2 * q1),
                  p3 * q1 + q3 * p1 + (p2 * q0 - p0 * q2),
                  p3 * q2 + q3 * p2 + (p0 * q1 - p1 * q0),
                  p3 * q3 - p0 * q0 - p1 * q1 - p2 * q2], axis=-1)
    x, y, z, w = r[..., 0], r[..., 1], r[..., 2], r[..., 3]
    n = np.sqrt(x * x + y * y + z * z + w * w)
    if not np.all(n > 0):
        raise ValueError("Found zero norm quaternions in `quat`.")
    return Rotation(r / n[..., None], normalize=False, copy=False)


def rotation_inverse(r: Rotation) -> Rotation:
    """``r.inv()`` (the vector part negated), without scipy's per-call cost for stacks."""
    q = r.as_quat()
    return Rotation(q * np.array([-1.0, -1.0, -1.0, 1.0]), normalize=False, copy=False)


def compose_rotations(a: Pose, b: Pose, translation, invert_second: bool = False) -> Pose:
    """The pose with rotation ``R_a · R_b`` (``R_a · R_b⁻¹`` with ``invert_second``) at ``translation``:
    the rotation half of ``a @ b`` for the corrections, whose translation is computed apart."""
    qa, qb = a._q(), b._q()
    if qa is not None and qb is not None:
        return Pose._of(quat_compose(qa, quat_inv(qb) if invert_second else qb), translation)
    return Pose(a.rotation * (b.rotation.inv() if invert_second else b.rotation), translation)


def is_finite(pose: Pose | None) -> TypeGuard[Pose]:
    """A pose with no NaN/inf anywhere (None is not finite): broken inputs are skipped, never used."""
    if pose is None:
        return False
    q = pose._q()
    if q is not None:
        return all(map(math.isfinite, q)) and bool(np.isfinite(pose.translation).all())
    return bool(np.isfinite(pose.translation).all() and np.isfinite(pose.rotation.as_quat()).all())


def interpolate(t0: float, pose0: Pose, t1: float, pose1: Pose, t: float) -> Pose:
    """Pose at time ``t`` between two single poses: linear translation, slerp rotation."""
    if t1 == t0:
        return pose0
    a = (t - t0) / (t1 - t0)
    translation = (1.0 - a) * pose0.translation + a * pose1.translation
    q0, q1 = pose0._q(), pose1._q()
    if q0 is not None and q1 is not None:
        # the same steps as the scipy expression below, in the scalar code
        rx, ry, rz = quat_as_rotvec(quat_compose(quat_inv(q0), q1))
        step = (a * rx, a * ry, a * rz) if isinstance(a, float) else tuple((a * np.array([rx, ry, rz])).tolist())
        return Pose._of(quat_compose(q0, quat_from_rotvec(step)), translation)
    # slerp of two rotations as scipy composes it, without building a Slerp object (a third of the cost)
    rot = pose0.rotation * Rotation.from_rotvec(a * (pose0.rotation.inv() * pose1.rotation).as_rotvec())
    return Pose(rot, translation)


def interpolate_many(times: np.ndarray, poses: Pose, query: np.ndarray) -> Pose:
    """Poses at ``query`` times from a stamped stack (times ascending, query within range)."""
    slerp = Slerp(np.asarray(times, dtype=float), poses.rotation)
    q = np.asarray(query, dtype=float)
    trans = np.atleast_2d(interp_columns(q, times, np.atleast_2d(poses.translation)))
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


# ----------------------------------------------------------------------------- single poses
# scipy's Rotation costs microseconds per call on a single rotation (its array-API dispatch and
# validation), the arithmetic nanoseconds; playback makes dozens of such calls per tick. These functions
# repeat what scipy 1.17's compiled backend computes, operation for operation (the same products
# summed in the same order, the same libm functions, normalisation where scipy normalises), so their
# results are bit-identical to scipy's: tests/test_geometry.py checks that with hypothesis. Rotating a
# vector goes through np.matmul on the 3x3 matrix, as scipy's does: the BLAS kernel behind it
# rounds differently from a Python sum of products.

def quat_normalised(q) -> Quat:
    """``Rotation.from_quat``'s normalisation (ValueError for a zero or NaN norm, as scipy)."""
    x, y, z, w = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if n == 0.0 or n != n:
        raise ValueError("Found zero norm quaternions in `quat`.")
    return (x / n, y / n, z / n, w / n)


def quat_compose(p: Quat, q: Quat) -> Quat:
    """``p * q`` of scipy Rotations (q first, then p), normalised as scipy does."""
    p0, p1, p2, p3 = p
    q0, q1, q2, q3 = q
    return quat_normalised((p3 * q0 + q3 * p0 + (p1 * q2 - p2 * q1),
                            p3 * q1 + q3 * p1 + (p2 * q0 - p0 * q2),
                            p3 * q2 + q3 * p2 + (p0 * q1 - p1 * q0),
                            p3 * q3 - p0 * q0 - p1 * q1 - p2 * q2))


def quat_inv(q: Quat) -> Quat:
    return (-q[0], -q[1], -q[2], q[3])


def quat_matrix(q: Quat) -> list[list[float]]:
    """``Rotation.as_matrix()`` of one unit quaternion, row by row."""
    x, y, z, w = q
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    return [[x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw)],
            [2 * (xy + zw), -x2 + y2 - z2 + w2, 2 * (yz - xw)],
            [2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2]]


def quat_apply_rows(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``Rotation.from_quat(q).apply(v)`` row by row: quaternions (n, 4) x y z w, any norm, and vectors (n, 3).
    To rounding, not to the bit: ((w^2 - |u|^2) v + 2 (u.v) u + 2 w (u x v)) / |q|^2 with u = (x, y, z).
    Only elementwise operations, no BLAS product: a row's result depends on that row alone, not on how many rows
    are turned together nor on which matrix kernel the CPU selects (docs/playback.md, "Determinism")."""
    x, y, z, w = q[:, 0:1], q[:, 1:2], q[:, 2:3], q[:, 3:4]
    a, b, c = v[:, 0:1], v[:, 1:2], v[:, 2:3]
    uu = x * x + y * y + z * z
    ww = w * w
    uv2 = 2 * (x * a + y * b + z * c)
    w2 = 2 * w
    cross = np.concatenate((y * c - z * b, z * a - x * c, x * b - y * a), axis=1)
    return ((ww - uu) * v + uv2 * q[:, :3] + w2 * cross) / (ww + uu)


def quat_apply(q: Quat, v) -> np.ndarray:
    """``Rotation.apply(v)`` of one rotation to one vector (3,)."""
    v = np.asarray(v, dtype=float)
    m = np.array(quat_matrix(q))
    # ndarray.dot reaches the same BLAS gemv call as np.matmul at half its overhead; a strided vector
    # keeps np.matmul, scipy's own call (the kernel for strided input may round differently)
    return m.dot(v) if v.flags.c_contiguous else np.matmul(m, v)


def quat_magnitude(q: Quat) -> float:
    """``Rotation.magnitude()``: the rotation angle in [0, pi]."""
    return 2 * math.atan2(math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]), abs(q[3]))


def quat_from_rotvec(v) -> Quat:
    """``Rotation.from_rotvec`` of one rotation vector (not normalised afterwards, as in scipy)."""
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    angle = math.sqrt(x * x + y * y + z * z)
    if angle <= 1e-3:   # scipy's small-angle series
        angle2 = angle * angle
        scale = 0.5 - angle2 / 48 + angle2 * angle2 / 3840
    else:
        scale = math.sin(angle / 2) / angle
    return (scale * x, scale * y, scale * z, math.cos(angle / 2))


def quat_as_rotvec(q: Quat) -> tuple[float, float, float]:
    """``Rotation.as_rotvec()`` of one quaternion (made canonical first, as scipy does)."""
    x, y, z, w = q
    if w < 0 or (w == 0 and (x < 0 or (x == 0 and (y < 0 or (y == 0 and z < 0))))):
        x, y, z, w = -x, -y, -z, -w
    angle = 2 * math.atan2(math.sqrt(x * x + y * y + z * z), w)
    if angle <= 1e-3:   # scipy's small-angle series
        angle2 = angle * angle
        scale = 2 + angle2 / 12 + 7 * angle2 * angle2 / 2880
    else:
        scale = angle / math.sin(angle / 2)
    return (scale * x, scale * y, scale * z)
