"""Every conversion between a session's protobuf messages and phonepose's own types, in one place.

Decoding (playback, hand-eye calibration, experiments, the recorder's Rerun view) and encoding
(the simulator, the live recorder, playback's ``trackers.mcap``) of poses go through here;
phonepose.geometry knows no message format.

The rules for a pose in a message (docs/format.md, "Poses in messages"), stated once:

* A quaternion is x, y, z, w and must be of unit length within ``geometry.QUAT_NORM_TOL``. It is
  normalised only within that tolerance, never made plausible from something else.
* An **all-zero quaternion** is how protobuf encodes an orientation nobody set: in a session it
  reads as **identity**, wherever it appears (pose streams, static poses, calibration events).
  Formats without an "unset" (TUM files, the phone page's JSON) have no such rule: all zeros
  there is a non-unit quaternion.
* A pose must be there: a ``foxglove.Pose`` with neither ``position`` nor ``orientation`` set (a
  PoseInFrame or an event without its pose, or another message's bytes decoded under this schema)
  is broken, as is one with NaN/inf values or a non-unit quaternion. Static poses whose default
  means something (a FrameTransform, the marker's pose on the body) may be left unset: identity.
* What is broken raises :class:`BrokenPose`. Playback skips a broken sample of a stream and counts
  it per (topic, ``reason``) for one warning line; broken static content is an error.
"""

from __future__ import annotations

import math

import numpy as np
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Pose_pb2 import Pose as FgPose
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

from phonepose.geometry import QUAT_NORM_TOL, Pose, RawPose

# The reasons a sample is skipped, as playback's warning line names them.
BAD_VALUE = "NaN/inf value or non-unit quaternion"
NO_POSE = "no pose in the message (neither position nor orientation set)"


class BrokenPose(ValueError):
    """A pose that cannot be used. ``reason`` groups samples for the warning line (BAD_VALUE,
    NO_POSE); ``detail`` completes a sentence about one message ("... has NaN/inf values")."""

    def __init__(self, reason: str, detail: str):
        super().__init__(detail)
        self.reason = reason
        self.detail = detail


def _broken_values(x: float, y: float, z: float, qx: float, qy: float, qz: float, qw: float) -> BrokenPose:
    """Why values that failed the fast check are broken (the slow path: only for broken samples)."""
    if not all(math.isfinite(v) for v in (x, y, z, qx, qy, qz, qw)):
        return BrokenPose(BAD_VALUE, "has NaN/inf values")
    n = math.hypot(qx, qy, qz, qw)   # finite components whose squares overflowed
    return BrokenPose(BAD_VALUE, f"quaternion is not unit length (|q| = {n:.6g})")


def _check(x: float, y: float, z: float, qx: float, qy: float, qz: float, qw: float) -> float:
    """The quaternion's norm, 0.0 for an unset (all-zero) one; raises BrokenPose for bad values."""
    n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    if not (math.isfinite(n) and math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise _broken_values(x, y, z, qx, qy, qz, qw)
    if n != 0.0 and abs(n - 1.0) > QUAT_NORM_TOL:
        raise BrokenPose(BAD_VALUE, f"quaternion is not unit length (|q| = {n:.6g})")
    return n


def _check_present(pose: FgPose) -> None:
    if not (pose.HasField("position") or pose.HasField("orientation")):
        raise BrokenPose(NO_POSE, "has no pose (neither position nor orientation set)")


# ----------------------------------------------------------------------------- decoding
def raw_pose(pose: FgPose) -> RawPose:
    """A ``foxglove.Pose`` as a raw ``(qx, qy, qz, qw, x, y, z)`` tuple, the quaternion normalised
    (the fast path for streams: playback decodes every sample). Raises BrokenPose."""
    q, p = pose.orientation, pose.position
    qx, qy, qz, qw = q.x, q.y, q.z, q.w
    x, y, z = p.x, p.y, p.z
    n = _check(x, y, z, qx, qy, qz, qw)
    if n == 0.0:
        _check_present(pose)    # only an all-zero pose can be an absent one
        return (0.0, 0.0, 0.0, 1.0, x, y, z)
    return (qx / n, qy / n, qz / n, qw / n, x, y, z)


def pose_of(pose: FgPose, *, required: bool = True) -> Pose:
    """A ``foxglove.Pose`` (an event's, a target's or a static pose) as a Pose. Raises BrokenPose.

    ``required=False`` for a static pose with a meaningful default (the marker at the body's
    origin): there, an unset pose is identity instead of broken."""
    q, p = pose.orientation, pose.position
    if _check(p.x, p.y, p.z, q.x, q.y, q.z, q.w) == 0.0:
        if required:
            _check_present(pose)
        return Pose.from_xyzw([p.x, p.y, p.z], [0.0, 0.0, 0.0, 1.0])
    return Pose.from_xyzw([p.x, p.y, p.z], [q.x, q.y, q.z, q.w])


def transform_of(msg: FrameTransform) -> Pose:
    """A ``foxglove.FrameTransform`` as the pose of its child frame in its parent. Raises BrokenPose.

    An identity transform may leave both fields unset, so a FrameTransform has no presence rule."""
    t, q = msg.translation, msg.rotation
    if _check(t.x, t.y, t.z, q.x, q.y, q.z, q.w) == 0.0:
        return Pose.from_xyzw([t.x, t.y, t.z], [0.0, 0.0, 0.0, 1.0])
    return Pose.from_xyzw([t.x, t.y, t.z], [q.x, q.y, q.z, q.w])


# ----------------------------------------------------------------------------- times
# Every time phonepose reads from a file (a message's log time, a header stamp, the task window) is int64
# nanoseconds since 1970, 1677-09-21..2262-04-11: what numpy, rerun and the TUM files hold. protobuf's Timestamp
# (years 1..9999) and MCAP's uint64 log times reach beyond it.
MIN_TIME_NS, MAX_TIME_NS = -(1 << 63), (1 << 63) - 1
TIME_RANGE = "int64 nanoseconds, 1677-09-21..2262-04-11"


def time_problem(seconds: int, nanos: int) -> str | None:
    """Why a ``google.protobuf.Timestamp`` is no time phonepose reads, or None."""
    if not 0 <= nanos < 1_000_000_000:
        return f"seconds={seconds} nanos={nanos}: nanos outside 0..999999999"
    if not MIN_TIME_NS <= seconds * 1_000_000_000 + nanos <= MAX_TIME_NS:
        return f"seconds={seconds} nanos={nanos}: outside the times phonepose reads ({TIME_RANGE})"
    return None


def timestamp_ns(ts) -> int:
    """A ``google.protobuf.Timestamp`` in ns, the one conversion of a stamp; ValueError naming the value when out
    of range (a message from :class:`SessionReader` was checked by :func:`times_problem`)."""
    problem = time_problem(ts.seconds, ts.nanos)
    if problem is not None:
        raise ValueError(problem)
    return ts.seconds * 1_000_000_000 + ts.nanos


def stamp_ns(msg, fallback_ns: int) -> int:
    """A message's header ``timestamp`` in ns; an unset stamp (0) is ``fallback_ns`` (its log time)."""
    return timestamp_ns(msg.timestamp) or fallback_ns


_TIMESTAMP = "google.protobuf.Timestamp"
_plans: dict[str, list] = {}


def _plan(descriptor) -> list:
    """(field name, repeated, sub-plan or None for a Timestamp) for every field of ``descriptor`` that is or
    holds a Timestamp; computed once a message type."""
    plan = _plans.get(descriptor.full_name)
    if plan is None:
        _plans[descriptor.full_name] = []         # a recursive type: its own fields hold no Timestamp of another
        plan = []
        for f in descriptor.fields:
            if f.message_type is None:
                continue
            if f.message_type.full_name == _TIMESTAMP:
                plan.append((f.name, f.is_repeated, None))
            else:
                sub = _plan(f.message_type)
                if sub:
                    plan.append((f.name, f.is_repeated, sub))
        _plans[descriptor.full_name] = plan
    return plan


def times_problem(msg) -> str | None:
    """The first Timestamp anywhere in a decoded message that :func:`time_problem` refuses, as "FIELD
    seconds=.. nanos=..: why"; None when all are times phonepose reads. A few attribute reads a message."""
    return _times_problem(msg, _plan(msg.DESCRIPTOR), "")


def _times_problem(msg, plan: list, prefix: str) -> str | None:
    for name, repeated, sub in plan:
        values = getattr(msg, name)
        for i, v in enumerate(values if repeated else (values,)):
            where = f"{prefix}{name}[{i}]" if repeated else f"{prefix}{name}"
            problem = time_problem(v.seconds, v.nanos) if sub is None else _times_problem(v, sub, where + ".")
            if problem is not None:
                return problem if sub is not None else f"{where} {problem}"
    return None


# No phone IMU measures beyond these (gyroscopes saturate near 35 rad/s, accelerometers near 16 g): a
# larger finite value is a broken sample, and one like 1e200 overflows the fusion's integration.
MAX_GYRO_RAD_S = 1000.0
MAX_ACCEL_M_S2 = 10000.0
IMU_NOT_FINITE = "NaN/inf value"
IMU_OUT_OF_RANGE = f"value outside any IMU's range (|gyro| > {MAX_GYRO_RAD_S:g} rad/s or |accel| > {MAX_ACCEL_M_S2:g} m/s^2)"


def imu_problem(row: tuple[float, ...]) -> str | None:
    """Why an :func:`imu_row` cannot be used (the reason playback's warning line names), or None."""
    if not all(math.isfinite(v) for v in row):
        return IMU_NOT_FINITE
    if max(abs(v) for v in row[1:4]) > MAX_GYRO_RAD_S or max(abs(v) for v in row[4:7]) > MAX_ACCEL_M_S2:
        return IMU_OUT_OF_RANGE
    return None


def imu_row(msg, log_time_ns: int) -> tuple[float, float, float, float, float, float, float]:
    """A ``phonepose.Imu`` as ``(t_s, gx, gy, gz, ax, ay, az)``; ``t_s`` its stamp (or log time)."""
    return (stamp_ns(msg, log_time_ns) / 1e9, msg.gyro_x, msg.gyro_y, msg.gyro_z,
            msg.accel_x, msg.accel_y, msg.accel_z)


# ----------------------------------------------------------------------------- encoding
def encode_pose(pose: Pose, out: FgPose | None = None) -> FgPose:
    """A single Pose into ``out`` (a new ``foxglove.Pose`` if None); both fields are always set."""
    msg = FgPose() if out is None else out
    # tolist() gives Python floats in one call (playback writes one per tracker per tick)
    p, o = msg.position, msg.orientation
    p.x, p.y, p.z = np.asarray(pose.translation, dtype=float).tolist()
    o.x, o.y, o.z, o.w = pose.quat_xyzw.tolist()
    return msg


def pose_in_frame(pose: Pose, frame: str, t_ns: int) -> PoseInFrame:
    """A ``foxglove.PoseInFrame``: ``pose`` in ``frame``, stamped ``t_ns``."""
    msg = PoseInFrame(frame_id=frame)
    msg.timestamp.FromNanoseconds(int(t_ns))
    encode_pose(pose, msg.pose)
    return msg


def frame_transform(pose: Pose, parent: str, child: str, t_ns: int) -> FrameTransform:
    """A ``foxglove.FrameTransform``: the ``child`` frame at ``pose`` in ``parent``, stamped ``t_ns``."""
    msg = FrameTransform(parent_frame_id=parent, child_frame_id=child)
    msg.timestamp.FromNanoseconds(int(t_ns))
    msg.translation.x, msg.translation.y, msg.translation.z = (float(v) for v in pose.translation)
    q = pose.quat_xyzw
    msg.rotation.x, msg.rotation.y, msg.rotation.z, msg.rotation.w = (float(v) for v in q)
    return msg
