"""Shared helpers for the reliability tests: a synthetic multi-second session (no tests here).

The session is written through SessionWriter like a recording: 30 Hz JPEG camera frames of
noise (incompressible, so several chunks per second), 400 Hz IMU, 60 Hz controller/display VIO.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
from pathlib import Path

import cv2
import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

from phonepose.geometry import Pose
from phonepose.schemas import phonepose_pb2 as pb
from phonepose.schemas.topics import Frame, Topic
from phonepose.session import SessionReader, SessionWriter
from phonepose.session.codec import pose_in_frame
from phonepose.testing.sample import T0_NS

IMU_HZ, CAM_HZ, VIO_HZ = 400, 30, 60


def session_messages(seconds: float = 6.0, t0_ns: int = T0_NS, seed: int = 0, image_px: int = 200):
    """(topic, message, log_time_ns) in log-time order; every JPEG differs (~40 KB each)."""
    rng = np.random.default_rng(seed)
    out = []
    step_ns = 1_000_000_000 // 1200  # common grid of 400/60/30 Hz
    for k in range(int(seconds * 1200)):
        t = t0_ns + k * step_ns
        if k % (1200 // IMU_HZ) == 0:
            imu = pb.Imu(frame_id=Frame.CONTROLLER, gyro_x=float(k), accel_z=9.81)
            imu.timestamp.FromNanoseconds(t)
            out.append((Topic.CONTROLLER_IMU, imu, t))
        if k % (1200 // VIO_HZ) == 0:
            p = Pose.from_xyzw([0.001 * k, 0.0, 0.5], [0.0, 0.0, 0.0, 1.0])
            out.append((Topic.CONTROLLER_VIO_POSE, pose_in_frame(p, Frame.CONTROLLER_VIO, t), t))
            out.append((Topic.DISPLAY_VIO_POSE, pose_in_frame(p.inv(), Frame.DISPLAY_VIO, t), t))
        if k % (1200 // CAM_HZ) == 0:
            noise = rng.integers(0, 255, (image_px, image_px), dtype=np.uint8)
            jpeg = cv2.imencode(".jpg", noise, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()
            img = CompressedImage(frame_id=Frame.DISPLAY_CAMERA, format="jpeg", data=jpeg)
            img.timestamp.FromNanoseconds(t)
            out.append((Topic.CAMERA_IMAGE, img, t))
    return out


def write_session(path, seconds: float = 6.0, **kw) -> list:
    msgs = session_messages(seconds, **kw)
    with SessionWriter(path) as w:
        for topic, msg, t in msgs:
            w.write(topic, msg, t)
    return msgs


def read_keys(path) -> list[tuple[str, int, int, bytes]]:
    """(topic, log_time, sequence, data) of every message, in reading order."""
    with SessionReader(path) as r:
        return [(c.topic, m.log_time, m.sequence, m.data) for _, c, m in r.raw_messages()]


@contextlib.contextmanager
def mounted_tmpfs(where: Path, options: str):
    """A real tmpfs mounted at ``where`` (``mount -o options``), unmounted afterwards. Mounting needs
    root with mount permission: elsewhere the test is skipped (its ENOSPC / read-only doubles run
    everywhere)."""
    where.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)],
                                           capture_output=True).returncode != 0:
        import pytest
        pytest.skip(f"cannot mount a tmpfs ({options}) here: needs root and mount permission")
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=False)
