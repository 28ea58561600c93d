"""Bad input at the command line: one line on stderr, the documented exit code, no traceback.

Each case builds its input from a small valid session (phonepose.testing.playback_session), runs the
CLI in-process (``phonepose.cli.main``) and checks the exit code and message. The same CASES
generate the table in docs/reliability.md: ``python tests/test_reliability_cli.py``.
Warnings (skipped samples) are checked through a real subprocess, where logging prints them.
"""

from __future__ import annotations

import itertools
import math
import os
import re
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap.writer import Writer
from mcap_protobuf.schema import build_file_descriptor_set
from test_reliability_data import mounted_tmpfs

from phonepose.schemas import phonepose_pb2 as pb
from phonepose.schemas.topics import Topic
from phonepose.session import SessionReader, SessionWriter
from phonepose.testing.playback_session import write_test_session


# ----------------------------------------------------------------------------- inputs
def rewrite(src: Path, dst: Path, fn) -> Path:
    """Copy a session message by message; ``fn(topic, msg, log_time)`` returns the messages to write."""
    with SessionReader(src) as r, SessionWriter(dst) as w:
        for m in r.messages():
            for topic, msg, t in fn(m.topic, m.msg, m.log_time_ns) or []:
                w.write(topic, msg, t)
    return dst


def with_channel(src: Path, dst: Path, topic: str, schema_name: str | None, schema_encoding: str, schema_data: bytes,
                 message_encoding: str, data=lambda b: b) -> Path:
    """Copy a session with ``topic`` re-registered under another schema/encoding (raw mcap); ``schema_name`` None:
    no schema (id 0)."""
    with SessionReader(src) as r, open(dst, "wb") as f:
        w = Writer(f)
        w.start()
        cids = {}
        for schema, ch, m in r.raw_messages():
            if ch.topic not in cids:
                if ch.topic == topic:
                    sid = 0 if schema_name is None else w.register_schema(schema_name, schema_encoding, schema_data)
                    cids[ch.topic] = w.register_channel(topic, message_encoding, sid)
                else:
                    sid = w.register_schema(schema.name, schema.encoding, schema.data)
                    cids[ch.topic] = w.register_channel(ch.topic, ch.message_encoding, sid)
            w.add_message(cids[ch.topic], m.log_time, data(m.data) if ch.topic == topic else m.data,
                          m.publish_time, m.sequence)
        w.finish()
    return dst


def _drop(*prefixes):
    return lambda topic, msg, t: [] if topic.startswith(prefixes) else [(topic, msg, t)]


def _bad_dictionary(topic, msg, t):
    if topic == Topic.CONTROLLER_MARKER:
        msg.dictionary = "DICT_NOPE_99"
    return [(topic, msg, t)]


def _duplicate_vio(topic, msg, t):
    return [(topic, msg, t)] * (2 if topic == Topic.CONTROLLER_VIO_POSE else 1)


def _backwards_vio():
    k = itertools.count()

    def fn(topic, msg, t):
        if topic == Topic.CONTROLLER_VIO_POSE and next(k) % 5 == 4:
            msg.timestamp.FromNanoseconds(msg.timestamp.ToNanoseconds() - 200_000_000)
        return [(topic, msg, t)]
    return fn


def _bad_quaternions():
    k = itertools.count()

    def fn(topic, msg, t):
        if topic == Topic.CONTROLLER_VIO_POSE:
            i = next(k)
            if i % 6 == 1:
                msg.pose.orientation.x = math.nan
            elif i % 6 == 3:
                msg.pose.orientation.w = 5.0          # non-unit
            elif i % 6 == 5:
                msg.pose.position.y = math.inf
        return [(topic, msg, t)]
    return fn


def _foreign_payloads():
    """Every other controller VIO payload is another message's bytes (an IMU sample) under PoseInFrame."""
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
    k = itertools.count()

    def fn(topic, msg, t):
        if topic == Topic.CONTROLLER_VIO_POSE and next(k) % 2 == 1:
            imu = pb.Imu(frame_id=msg.frame_id, gyro_x=0.5, accel_z=9.81)
            imu.timestamp.CopyFrom(msg.timestamp)
            msg = PoseInFrame.FromString(imu.SerializeToString())
        return [(topic, msg, t)]
    return fn


def _static(topic, fn):
    def apply(t, msg, log_time):
        if t == topic:
            fn(msg)
        return [(t, msg, log_time)]
    return apply


def _marker_nan(m):
    m.pose_in_body.orientation.x = math.nan


def _gt_q5(m):
    m.rotation.w = 5.0


def _k_tiny(m):
    m.K[0] = 1e-30
    m.K[4] = 1e-30


def _size0(m):
    m.size_m = 0.0


def _fisheye(m):
    m.distortion_model = "kannala_brandt"


def _rational(m):
    m.distortion_model = "rational_polynomial"
    m.D.extend([0.3, 0.1, 0.02])


def _size_huge(m):
    m.size_m = 1e200


def _id50(m):
    m.id = 50


def _json_vio_only(path: Path) -> Path:
    """What another program records: only /controller/vio/pose, in JSON (no marker spec: it once failed on that
    first, as an unknown marker dictionary '')."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        schema = w.register_schema("Pose", "jsonschema", b"{}")
        channel = w.register_channel(Topic.CONTROLLER_VIO_POSE, "json", schema)
        for k in range(50):
            w.add_message(channel, log_time=k * 10**8, publish_time=k * 10**8, data=b'{"x": %d}' % k)
        w.finish()
    return path


def _extreme_imu():
    """Finite but impossible IMU values (gyro 1e200 rad/s, accel -1e300 m/s^2) in every other sample:
    these overflowed T8's integration (`zero norm quaternions`)."""
    k = itertools.count()

    def fn(topic, msg, t):
        if topic == Topic.CONTROLLER_IMU:
            i = next(k)
            if i % 4 == 1:
                msg.gyro_x = 1e200
            elif i % 4 == 3:
                msg.accel_y = -1e300
        return [(topic, msg, t)]
    return fn


def _garbage_image(m):
    m.data = b"this is not a jpeg"


def _claiming(width: int, height: int):
    """Camera frames whose JPEG header (SOF0) claims ``width`` x ``height`` px."""
    def fn(m):
        i = m.data.index(b"\xff\xc0")
        m.data = m.data[:i + 5] + height.to_bytes(2, "big") + width.to_bytes(2, "big") + m.data[i + 9:]
    return fn


def _cut_image(m):
    m.data = m.data[:len(m.data) // 2] + b"\xff\xd9"


def _half_size_image(m):
    gray = cv2.imdecode(np.frombuffer(m.data, np.uint8), cv2.IMREAD_GRAYSCALE)
    m.data = cv2.imencode(".jpg", cv2.resize(gray, (gray.shape[1] // 2, gray.shape[0] // 2)))[1].tobytes()


def _truncate(src: Path, dst: Path) -> Path:
    data = src.read_bytes()
    dst.write_bytes(data[: len(data) // 2])
    return dst


def _middle_chunk_offset(src: Path) -> int:
    """Where the session's middle chunk starts: it moves with the compressed sizes, i.e. with the JPEG and
    compression libraries' versions, so the expected message is made from the file, not written down."""
    from mcap.reader import make_reader

    with open(src, "rb") as f:
        chunks = sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    return chunks[len(chunks) // 2].chunk_start_offset


def _zero_chunk_header(src: Path, dst: Path) -> Path:
    b = bytearray(src.read_bytes())
    at = _middle_chunk_offset(src)
    b[at:at + 20] = bytes(20)
    dst.write_bytes(bytes(b))
    return dst


def _corrupt_middle(src: Path, dst: Path) -> Path:
    b = bytearray(src.read_bytes())
    for k in range(100):
        b[len(b) // 2 + 13 * k] ^= 0xFF
    dst.write_bytes(bytes(b))
    return dst


# ----------------------------------------------------------------------------- cases
def _gt(d: Path) -> str:
    return str(_write(d / "gt.txt", TUM_ROWS))


# Every numeric option with a hostile value: NaN, inf (or an overflowing 1e400), huge, negative, zero.
# (id, command, valid arguments without the option, option, value, as the message shows it, expected range)
HOSTILE_NUMBERS = [
    ("rate-inf", "playback", lambda g, d: ["playback", str(g), "--out", str(d / "o")], "--rate", "inf", "inf",
     r"a finite number in \[0\.1, 1000\] Hz"),
    ("rate-huge", "playback", lambda g, d: ["playback", str(g), "--out", str(d / "o")], "--rate", "1e9", "1000000000",
     r"a finite number in \[0\.1, 1000\] Hz"),
    ("rate-tiny", "playback", lambda g, d: ["playback", str(g), "--out", str(d / "o")], "--rate", "5e-324", "4.94066e-324",
     r"a finite number in \[0\.1, 1000\] Hz"),
    ("start-nan", "playback", lambda g, d: ["playback", str(g), "--out", str(d / "o")], "--start", "nan", "nan",
     r"a finite number in \[0, 1000000\] s"),
    ("end-overflow", "playback", lambda g, d: ["playback", str(g), "--out", str(d / "o")], "--end", "1e400", "inf",
     r"a finite number in \[0, 1000000\] s"),
    ("seed-negative", "record sim", lambda g, d: ["record", "sim", "--out", str(d / "s.mcap")], "--seed", "-1", "-1",
     r"an integer in \[0, 4294967295\]"),
    ("seed-huge", "demo", lambda g, d: ["demo", "--out", str(d / "demo")], "--seed", str(2**70), str(2**70),
     r"an integer in \[0, 4294967295\]"),
    ("workers-zero", "experiment exp2", lambda g, d: ["experiment", "exp2", "--out", str(d / "e")], "--workers", "0", "0",
     r"an integer in \[1, 256\]"),
    ("trial-huge", "record sim", lambda g, d: ["record", "sim", "--out", str(d / "s.mcap")], "--trial", "99999", "99999",
     r"an integer in \[1, 3\]"),
    ("camera-negative", "calibrate-camera", lambda g, d: ["calibrate-camera", "--out", str(d / "c.yaml")], "--camera",
     "-1", "-1", r"an integer in \[0, 1023\]"),
    ("camera-huge", "calibrate-camera", lambda g, d: ["calibrate-camera", "--out", str(d / "c.yaml")], "--camera",
     "99999999999", "99999999999", r"an integer in \[0, 1023\]"),
    ("seconds-inf", "calibrate-camera", lambda g, d: ["calibrate-camera", "--camera", "0", "--out", str(d / "c.yaml")],
     "--seconds", "inf", "inf", r"a finite number in \(0, 86400\] s"),
    ("dpi-zero", "board", lambda g, d: ["board", "--out", str(d / "b.png")], "--dpi", "0", "0",
     r"an integer in \[50, 1200\]"),
    ("pixels-huge", "marker", lambda g, d: ["marker", "--out", str(d / "m.png")], "--pixels", "1000000000",
     "1000000000", r"an integer in \[1, 20000\]"),
    ("workers-huge", "batch", lambda g, d: ["batch", str(g), "--out", str(d / "r.parquet")], "--workers", "100000",
     "100000", r"an integer in \[1, 256\]"),
    ("unit-timeout-nan", "batch", lambda g, d: ["batch", str(g), "--out", str(d / "r.parquet")], "--unit-timeout",
     "nan", "nan", r"a finite number in \(0, 1000000\] s"),
    ("tick-timeout-zero", "playback", lambda g, d: ["playback", str(g), "--out", str(d / "o")], "--tick-timeout",
     "0", "0", r"a finite number in \(0, 1000000\] s"),
    ("delta-inf", "evaluate", lambda g, d: ["evaluate", "--gt", _gt(d), "--est", str(d / "gt.txt")], "--delta", "inf",
     "inf", r"a finite number in \(0, 1000000000\]"),
    ("max-diff-nan", "evaluate", lambda g, d: ["evaluate", "--gt", _gt(d), "--est", str(d / "gt.txt")], "--max-diff",
     "nan", "nan", r"a finite number in \(0, 1000000\] s"),
    ("align-frames-zero", "evaluate", lambda g, d: ["evaluate", "--gt", _gt(d), "--est", str(d / "gt.txt")],
     "--align-frames", "0", "0", r"an integer >= 1 or -1"),
]


# Board spec values beyond what a printable board can be: (id, --board, other options, the docs' text, the line)
BOARD_CASES = [
    ("page-209-gib", "squares=10x10 square_mm=500 dictionary=DICT_5X5_100", ["--paper", "fit", "--dpi", "1200"],
     "`board --paper fit --dpi 1200` of 10x10 squares of 500 mm (1000 mm asked for 209 GiB)",
     r"^phonepose: error: the page would be 237638 x 238299 px \(5030 x 5044 mm at 1200 dpi\), more than the 300 Mpx "
     r"phonepose draws: use a lower --dpi, smaller squares or fewer of them$"),
    ("square-1000", "squares=10x10 square_mm=1000", ["--paper", "fit", "--dpi", "1200"], "",
     r"board square_mm=1000: expected a side in \[1, 500\] mm \(what a printer or plotter prints\)$"),
    ("square-1e-300", "square_mm=1e-300 marker_mm=1e-301", [], "`board --board 'square_mm=1e-300 marker_mm=1e-301'` "
     "(a SystemError in OpenCV)",
     r"board square_mm=1e-300: expected a side in \[1, 500\] mm"),
    ("marker-subpixel", "square_mm=1 marker_mm=0.005", ["--paper", "fit"],
     "`board --board 'square_mm=1 marker_mm=0.005'` (an OpenCV assertion)",
     r"board marker_mm=0\.005 is 0\.059 px at 300 dpi, less than its 7 cells: use markers of at least 0\.59 mm or a "
     r"higher --dpi$"),
    ("squares-huge", f"squares={10**300}x3", [], "`board --board squares=Nx3` with N of 301 digits",
     r"board squares 1e\+300x3: expected 2 to 100 squares a side, at least 6 in all$"),
]


@dataclass
class Case:
    id: str
    what: str                                   # the bad input, for the docs table
    argv: Callable[[Path, Path], list[str]]     # (good session, tmp dir) -> arguments
    code: int
    message: str | Callable[[Path], str]        # regex the stderr line must match (or made from the good session)


def _p(f):
    return f


def _empty(good, d):
    with SessionWriter(d / "empty.mcap"):
        pass
    return d / "empty.mcap"


CASES = [
    Case("missing", "session file does not exist", lambda g, d: ["info", str(d / "nope.mcap")], 2,
         r"nope\.mcap: no such file$"),
    Case("directory", "a directory instead of a file", lambda g, d: ["info", str(d)], 2, r"is a directory"),
    Case("zero-bytes", "empty (0-byte) file", lambda g, d: ["info", str(_write(d / "z.mcap", b""))], 2,
         r"z\.mcap: empty file$"),
    Case("not-mcap", "not an MCAP file (a PNG)",
         lambda g, d: ["info", str(_write(d / "x.mcap", b"\x89PNG\r\n\x1a\n" + b"\0" * 100))], 2,
         r"x\.mcap: not an MCAP file$"),
    Case("truncated-info", "truncated session (recording killed), `info`",
         lambda g, d: ["info", str(_truncate(g, d / "cut.mcap"))], 3,
         r"cut\.mcap: damaged MCAP file: it ends without its footer \(truncated: a recording killed, or a copy cut "
         r"short\); run `phonepose recover .*cut\.mcap --out FIXED\.mcap`$"),
    Case("truncated-playback", "truncated session, `playback`",
         lambda g, d: ["playback", str(_truncate(g, d / "cut.mcap")), "-q", "--out", str(d / "o")], 3,
         r"cut\.mcap: damaged MCAP file: it ends without its footer \(truncated: a recording killed, or a copy cut "
         r"short\); run `phonepose recover .*cut\.mcap --out FIXED\.mcap`$"),
    Case("corrupt-chunk", "flipped bits inside a chunk, `playback` (info still reads the summary)",
         lambda g, d: ["playback", str(_corrupt_middle(g, d / "bad.mcap")), "-q", "--out", str(d / "o")], 3,
         r"bad\.mcap: damaged MCAP file: the chunk at byte 40 \(log time 0\.00-1\.00 s\) does not decompress; run "
         r"`phonepose recover .*bad\.mcap --out FIXED\.mcap`$"),
    Case("corrupt-chunk-info", "flipped bits inside a chunk, `info --verify` (plain `info` reads only the summary)",
         lambda g, d: ["info", "--verify", str(_corrupt_middle(g, d / "bad.mcap"))], 3,
         r"bad\.mcap: damaged MCAP file: the chunk at byte 40 \(log time 0\.00-1\.00 s\) does not decompress; run "
         r"`phonepose recover .*bad\.mcap --out FIXED\.mcap`$"),
    Case("chunk-header-info", "a chunk's header overwritten, `info` (checks every chunk is where the index says)",
         lambda g, d: ["info", str(_zero_chunk_header(g, d / "hdr.mcap"))], 3,
         lambda g: rf"hdr\.mcap: damaged MCAP file: the data at byte {_middle_chunk_offset(g)} is not an MCAP record "
                   r"\(overwritten\?\); run `phonepose recover .*hdr\.mcap --out FIXED\.mcap`$"),
    Case("empty-session", "valid MCAP without messages",
         lambda g, d: ["playback", str(_empty(g, d)), "-q", "--out", str(d / "o")], 4,
         r"empty\.mcap: empty session \(no messages\)$"),
    Case("no-vio", "session without controller VIO",
         lambda g, d: ["playback", str(rewrite(g, d / "novio.mcap", _drop(Topic.CONTROLLER_VIO_POSE))), "-q",
                       "--out", str(d / "o")], 4,
         r"novio\.mcap: no controller VIO \(/controller/vio/pose\); nothing to play back$"),
    Case("no-camera", "session without camera, marker-based tracker asked for",
         lambda g, d: ["playback", str(rewrite(g, d / "nocam.mcap", _drop("/display/camera"))), "-q",
                       "-t", "T1", "-t", "T4", "--out", str(d / "o")], 4,
         r"nocam\.mcap: no camera images \(/display/camera/image\): T4 need the camera; "
         r"run the VIO-only trackers with -t T1$"),
    Case("wrong-schema", "known topic carrying another schema (IMU on /controller/vio/pose)",
         lambda g, d: ["playback", str(with_channel(g, d / "ws.mcap", Topic.CONTROLLER_VIO_POSE, "phonepose.Imu",
                                                    "protobuf", build_file_descriptor_set(pb.Imu).SerializeToString(),
                                                    "protobuf")), "-q", "--out", str(d / "o")], 4,
         r"ws\.mcap: topic /controller/vio/pose has schema 'phonepose\.Imu', phonepose expects "
         r"'foxglove\.PoseInFrame'$"),
    Case("unknown-schema", "unknown schema (`acme.Pose`, unreadable descriptor) on a topic",
         lambda g, d: ["playback", str(with_channel(g, d / "us.mcap", Topic.CONTROLLER_VIO_POSE, "acme.Pose",
                                                    "protobuf", b"\x00junk", "protobuf")),
                       "-q", "--out", str(d / "o")], 4,
         r"us\.mcap: topic /controller/vio/pose has schema 'acme\.Pose'"),
    Case("json-encoding", "a topic in JSON instead of protobuf",
         lambda g, d: ["playback", str(with_channel(g, d / "js.mcap", Topic.CONTROLLER_VIO_POSE, "acme.Pose",
                                                    "jsonschema", b"{}", "json", lambda b: b'{"x": 1}')),
                       "-q", "--out", str(d / "o")], 4,
         r"js\.mcap: topic /controller/vio/pose has encoding 'json', phonepose reads protobuf only$"),
    Case("no-schema", "a protobuf topic without a schema (id 0, which MCAP allows)",
         lambda g, d: ["playback", str(with_channel(g, d / "ns.mcap", Topic.CONTROLLER_VIO_POSE, None, "", b"",
                                                    "protobuf")), "-q", "--out", str(d / "o")], 4,
         r"ns\.mcap: topic /controller/vio/pose has no schema: phonepose reads protobuf messages by their schema "
         r"\(a FileDescriptorSet\)$"),
    Case("log-time-0", "every message at log time 0 (a writer that does not set it: one tick, no metrics, exit 0 before)",
         lambda g, d: ["playback", str(rewrite(g, d / "t0.mcap", lambda t, msg, lt: [(t, msg, 0)])), "-q", "--out",
                       str(d / "o")], 4,
         r"t0\.mcap: all \d+ messages have the same log time \(0 ns\): phonepose plays a session in log-time order "
         r"\(the capture time, docs/format\.md\), which this file's writer did not set$"),
    Case("static-nan", "NaN in the marker's pose on the phone body (static content)",
         lambda g, d: ["playback", str(rewrite(g, d / "mk.mcap", _static(Topic.CONTROLLER_MARKER,
                                                                          _marker_nan))), "-q", "--out", str(d / "o")],
         4, r"mk\.mcap: marker pose on the body \(/controller/marker\) has NaN/inf values$"),
    Case("static-non-unit", "non-unit quaternion in the mocap calibration (static content)",
         lambda g, d: ["playback", str(rewrite(g, d / "gc.mcap", _static(Topic.GT_CALIBRATION, _gt_q5))),
                       "-q", "--out", str(d / "o")],
         4, r"gc\.mcap: ground-truth calibration \(/gt/calibration\) quaternion is not unit length "
            r"\(\|q\| = 5\.0\d*\)$"),
    Case("static-focal-tiny", "camera calibration with fx = fy = 1e-30 px (\"Found zero norm quaternions\" before)",
         lambda g, d: ["playback", str(rewrite(g, d / "k.mcap", _static(Topic.CAMERA_CALIBRATION, _k_tiny))),
                       "-q", "--out", str(d / "o")],
         4, r"k\.mcap: camera calibration: focal lengths fx=1e-30, fy=1e-30 px: expected 1 to 1000000 px \(a camera "
            r"matrix in pixels\)$"),
    Case("static-fisheye", "camera calibration of a fisheye lens (Foxglove's kannala_brandt; read as plumb_bob before)",
         lambda g, d: ["playback", str(rewrite(g, d / "fe.mcap", _static(Topic.CAMERA_CALIBRATION, _fisheye))),
                       "-q", "--out", str(d / "o")],
         4, r"fe\.mcap: /display/camera/calibration: distortion model 'kannala_brandt': phonepose models plumb_bob "
            r"\(k1 k2 p1 p2 k3\) only; calibrate the camera with phonepose calibrate-camera$"),
    Case("static-rational", "camera calibration with 8 coefficients, k4 = 0.3 (the first 5 were used before)",
         lambda g, d: ["playback", str(rewrite(g, d / "r8.mcap", _static(Topic.CAMERA_CALIBRATION, _rational))),
                       "-q", "--out", str(d / "o")],
         4, r"r8\.mcap: /display/camera/calibration: 8 distortion coefficients, of which the 6th is not zero "
            r"\(OpenCV's rational or thin-prism model\): phonepose models plumb_bob \(k1 k2 p1 p2 k3\) only; "
            r"calibrate without CALIB_RATIONAL_MODEL, or with phonepose calibrate-camera$"),
    Case("static-marker-size", "marker size 0",
         lambda g, d: ["playback", str(rewrite(g, d / "ms.mcap", _static(Topic.CONTROLLER_MARKER, _size0))),
                       "-q", "--out", str(d / "o")],
         4, r"ms\.mcap: marker size 0 m: expected a positive size$"),
    Case("static-marker-size-huge", "marker size 1e200 m (overflowed T8)",
         lambda g, d: ["playback", str(rewrite(g, d / "ms.mcap", _static(Topic.CONTROLLER_MARKER, _size_huge))),
                       "-q", "--out", str(d / "o")],
         4, r"ms\.mcap: marker size 1e\+200 m: expected at most 10 m \(the side of a printed or displayed marker\)$"),
    Case("start-end-miss-task", "`--start/--end` outside the task window (0.30-1.80 s)",
         lambda g, d: ["playback", str(g), "-q", "--start", "1.9", "--end", "2", "--out", str(d / "o")], 5,
         r"--start 1\.9 --end 2 selects 1\.90-2\.00 s, which misses the task window 0\.30-1\.80 s \(where "
         r"trajectories and metrics are computed\): choose a range that overlaps it$"),
    Case("evaluate-no-match", "`evaluate` with trajectories whose stamps never meet",
         lambda g, d: ["evaluate", "--gt", _gt(d), "--est", str(_write(d / "late.txt", LATE_ROWS))],
         4, r"no matching stamps between .*gt\.txt and .*late\.txt \(\|dt\| < 0\.02 s\)$"),
    Case("unknown-tracker", "unknown tracker name",
         lambda g, d: ["playback", str(g), "-q", "-t", "T99", "--out", str(d / "o")], 5,
         r"unknown tracker 'T99'; valid: T1, T2, T3, T4, T5, T6, T7, .*all, paper, or package\.module:ClassName$"),
    Case("bad-rate", "bad option value (`--rate -1`)",
         lambda g, d: ["playback", str(g), "-q", "--rate", "-1", "--out", str(d / "o")], 5,
         r"^phonepose: error: --rate -1: expected a finite number in \[0\.1, 1000\] Hz$"),
    Case("bad-correction-math", "bad option value (`--correction-math foo`)",
         lambda g, d: ["playback", str(g), "-q", "--correction-math", "foo", "--out", str(d / "o")], 5,
         r"playback: Invalid value for '--correction-math': 'foo' is not one of 'paper', 'se3'\. "
         r"\(see `phonepose playback --help`\)$"),
    Case("bad-dictionary", "unknown marker dictionary in the session's marker spec",
         lambda g, d: ["playback", str(rewrite(g, d / "dict.mcap", _bad_dictionary)), "-q", "--out", str(d / "o")], 4,
         r"dict\.mcap: marker dictionary 'DICT_NOPE_99' \(/controller/marker\) is not one OpenCV knows "
         r"\(DICT_4X4_50, DICT_APRILTAG_36h11, \.\.\.: \d+ in all\)$"),
    Case("marker-id-not-in-dictionary", "marker id 50 in DICT_4X4_50 (ids 0-49: never recognised)",
         lambda g, d: ["playback", str(rewrite(g, d / "id.mcap", _static(Topic.CONTROLLER_MARKER, _id50))), "-q",
                       "--out", str(d / "o")], 4,
         r"id\.mcap: marker id 50 \(/controller/marker\) is not in DICT_4X4_50 \(ids 0-49\)$"),
    Case("json-vio-no-marker", "a foreign session: JSON controller VIO, no camera, no marker spec",
         lambda g, d: ["playback", str(_json_vio_only(d / "js1.mcap")), "-q", "-t", "T1", "--out", str(d / "o")], 4,
         r"js1\.mcap: topic /controller/vio/pose has encoding 'json', phonepose reads protobuf only$"),
    Case("out-not-dir", "output directory cannot be created (a file is in the way)",
         lambda g, d: ["playback", str(g), "-q", "-t", "T1", "--out", str(_write(d / "f", b"x") / "out")], 6,
         r"--out .*f/out: .*f is not a directory$"),
    Case("rerun-not-writable", "`--rerun` file cannot be written",
         lambda g, d: ["playback", str(g), "-q", "-t", "T1", "--out", str(d / "o"), "--rerun", str(d)], 6,
         r"--rerun .*: is a directory; --rerun takes a file name$"),
    Case("config-missing", "`record sim --config` file does not exist",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"), "--config", str(d / "nope.toml")], 5,
         r"config file .*nope\.toml: no such file$"),
    Case("config-not-toml", "config file that is not TOML",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"),
                       "--config", str(_write(d / "c.toml", b"this is [not toml\n"))], 5,
         r"config file .*c\.toml: invalid TOML \(Expected '=' after a key"),
    Case("config-unknown-key", "config file with an unknown key",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"),
                       "--config", str(_write(d / "c.toml", b"[camera]\nfps = 1000\n"))], 5,
         r"unknown config key 'camera\.fps' \(known here: .*\brate_hz\b.*\)$"),
    Case("config-out-of-range", "config value out of range",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"),
                       "--config", str(_write(d / "c.toml", b"[camera]\nrate_hz = -5\n"))], 5,
         r"config key 'camera\.rate_hz' = -5\.0 is out of range: allowed \[1, 120\]$"),
    Case("config-wrong-type", "config value of the wrong type",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"),
                       "--config", str(_write(d / "c.toml", b'[camera]\nrate_hz = "fast"\n'))], 5,
         r"config key 'camera\.rate_hz' must be a number in \[1, 120\], got 'fast'$"),
    Case("config-bad-dictionary", "unknown marker dictionary in the simulator config",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"),
                       "--config", str(_write(d / "c.toml", b'[marker]\ndictionary = "DICT_FOO"\n'))], 5,
         r"config key 'marker\.dictionary' must be one of DICT_4X4_50, .*got 'DICT_FOO'$"),
    Case("record-bad-scenario", "`record sim --scenario exp9`",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"), "--scenario", "exp9"], 5,
         r"record sim: Invalid value for '--scenario': 'exp9' is not one of 'exp1', 'exp2'\. "
         r"\(see `phonepose record sim --help`\)$"),
    Case("record-out-not-writable", "`record sim --out` in a missing directory",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "nodir" / "s.mcap")], 6,
         r"--out .*nodir/s\.mcap: directory .*nodir does not exist$"),
    Case("record-out-exists", "`record sim --out` naming an existing session (kept untouched; `--force` replaces it)",
         lambda g, d: ["record", "sim", "-q", "--out", str(_write(d / "s.mcap", b"an earlier recording"))], 6,
         r"s\.mcap already exists: choose another --out, or add --force to replace it$"),
    Case("record-out-is-dir", "`record sim --out` naming a directory",
         lambda g, d: ["record", "sim", "-q", "--out", str(_mkdir(d / "sessions"))], 6,
         r"sessions: is a directory; --out takes a file name$"),
    Case("usage-missing-option", "a required option left out (`recover` without `--out`)",
         lambda g, d: ["recover", str(g)], 2,
         r"recover: Missing option '--out' / '-o'\. \(see `phonepose recover --help`\)$"),
    Case("usage-bad-value", "an option value of the wrong type (`--rate abc`)",
         lambda g, d: ["playback", str(g), "--rate", "abc"], 5,
         r"playback: Invalid value for '--rate': .*\(see `phonepose playback --help`\)$"),
    Case("usage-unknown-command", "an unknown command",
         lambda g, d: ["bogus"], 2, r"No such command 'bogus'\. \(see `phonepose --help`\)$"),
    Case("recover-same-file", "`recover` asked to overwrite its input",
         lambda g, d: ["recover", str(g), "--out", str(g)], 2,
         r"--out .*good\.mcap is the input .*good\.mcap: writing it would destroy the input; choose another name$"),
    Case("recover-nothing", "`recover` on bytes with no intact chunk",
         lambda g, d: ["recover", str(_write(d / "n.mcap", np.random.default_rng(0).bytes(50_000))),
                       "--out", str(d / "fixed.mcap")], 3,
         r"n\.mcap: nothing recoverable \(50000 of 50000 bytes unreadable, no intact chunk with known channels\)$"),
    Case("recover-out-dir", "`recover --out` in a missing directory",
         lambda g, d: ["recover", str(g), "--out", str(d / "nodir" / "fixed.mcap")], 6,
         r"--out .*nodir/fixed\.mcap: directory .*nodir does not exist$"),
    Case("recover-out-exists", "`recover --out` naming an existing file",
         lambda g, d: ["recover", str(g), "--out", str(_write(d / "fixed.mcap", b"x"))], 6,
         r"fixed\.mcap already exists: choose another --out, or add --force to replace it$"),
    Case("hand-eye-no-turns", "`calibrate-hand-eye` on a session whose phone turns about one axis only",
         lambda g, d: ["calibrate-hand-eye", str(g), "--out", str(d / "he.yaml")], 4,
         r"good\.mcap: the phone turned about one axis only: the hand-eye rotation about it is undetermined"),
    Case("hand-eye-not-a-file", "`playback --gt-calibration` with a file that is not one",
         lambda g, d: ["playback", str(g), "-q", "--gt-calibration", str(_write(d / "he.yaml", b"hello\n")),
                       "--out", str(d / "o")], 2, r"he\.yaml: not an OpenCV YAML/XML calibration file$"),
    Case("evaluate-missing", "`evaluate` with a missing trajectory file",
         lambda g, d: ["evaluate", "--gt", str(d / "gt.txt"), "--est", str(d / "est.txt")], 2,
         r"gt\.txt: no such file$"),
    Case("evaluate-garbage", "`evaluate` with a trajectory that is not TUM",
         lambda g, d: ["evaluate", "--gt", str(_write(d / "gt.txt", b"hello world\n")), "--est", str(d / "gt.txt")], 2,
         r"gt\.txt:1: not a number in 'hello world'"),
    Case("evaluate-bad-metric", "`evaluate --metric xx`",
         lambda g, d: ["evaluate", "--gt", str(d / "gt.txt"), "--est", str(d / "gt.txt"), "--metric", "xx"], 5,
         r"evaluate: Invalid value for '--metric': 'xx' is not one of 'rpg', 'ape', 'rpe', 'paper'\."),
    Case("evaluate-paper-no-in-view", "`evaluate --metric paper` without `--in-view`",
         lambda g, d: ["evaluate", "--gt", str(_write(d / "gt.txt", TUM_ROWS)), "--est", str(d / "gt.txt"),
                       "--metric", "paper"], 5,
         r"--metric paper needs --in-view FILE \(playback writes in_view\.txt beside groundtruth\.tum\)$"),
    Case("evaluate-bad-in-view", "a malformed `--in-view` file",
         lambda g, d: ["evaluate", "--gt", str(_write(d / "gt.txt", TUM_ROWS)), "--est", str(d / "gt.txt"),
                       "--metric", "paper", "--in-view", str(_write(d / "bad.txt", b"0.0 1\n1.0 yes\n"))], 2,
         r"bad\.txt:2: expected 'timestamp in_view\(0\|1\)', got '1\.0 yes'$"),
    # ------------------------------------------------------------------ hostile input (issue 18)
    *[Case(f"number-{cid}", f"`{command} {option} {value}`",
           lambda g, d, base=base, option=option, value=value: base(g, d) + [option, value],
           5, rf"^phonepose: error: {re.escape(option)} {re.escape(shown)}: expected {expected}$")
      for cid, command, base, option, value, shown, expected in HOSTILE_NUMBERS],
    Case("param-inf", "`batch --param rate_hz=inf`",
         lambda g, d: ["batch", str(g), "-p", "rate_hz=inf", "--out", str(d / "r.parquet")], 5,
         r"^phonepose: error: --param rate_hz=inf: expected a finite number in \[0\.1, 1000\] Hz$"),
    Case("param-tiny", "`batch --param rate_hz=1e-300` (was an error row and exit 1)",
         lambda g, d: ["batch", str(g), "-p", "rate_hz=1e-300", "--out", str(d / "r.parquet")], 5,
         r"^phonepose: error: --param rate_hz=1e-300: expected a finite number in \[0\.1, 1000\] Hz$"),
    Case("lengths-inf", "`evaluate --lengths 1,inf`",
         lambda g, d: ["evaluate", "--gt", str(_write(d / "gt.txt", TUM_ROWS)), "--est", str(d / "gt.txt"),
                       "--lengths", "1,inf"], 5, r"--lengths '1,inf': expected positive metres"),
    Case("config-binary", "a binary `--config`",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"),
                       "--config", str(_write(d / "c.toml", bytes(range(256)) * 4))], 5,
         r"config file .*c\.toml: not a TOML file \(binary data: a NUL byte at byte 0\)$"),
    Case("config-not-utf8", "a `--config` that is not UTF-8 text",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"),
                       "--config", str(_write(d / "c.toml", b"[camera]\nrate_hz = 30 # \xff\n"))], 5,
         r"config file .*c\.toml: not a TOML file \(not UTF-8 text: byte 24\)$"),
    Case("config-nested", "a deeply nested `--config` (`a = [[[[...]]]]`, 20 KB)",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"),
                       "--config", str(_write(d / "c.toml", b"a = " + b"[" * 10_000 + b"]" * 10_000 + b"\n"))], 5,
         r"config file .*c\.toml: invalid TOML \(nested too deeply\)$"),
    Case("config-huge", "a `--config` over 32 KiB (tomllib is quadratic in a dotted key's depth)",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"),
                       "--config", str(_write(d / "c.toml", b"[" + b".".join([b"a"] * 100_000) + b"]\n"))], 5,
         r"config file .*c\.toml: larger than 32 KiB, the most phonepose reads as a TOML file "
         r"\(every parameter with comments is \d\.\d KiB\): check that it is the right file$"),
    Case("config-fifo", "a FIFO as `--config`",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"), "--config", str(_fifo(d / "c.toml"))], 5,
         r"config file .*c\.toml: not a regular file \(a FIFO, socket or device\): give a TOML file$"),
    Case("trajectory-sparse-10g", "a 10 GB (sparse) file as `evaluate --gt` (was read whole: MemoryError)",
         lambda g, d: ["evaluate", "--gt", str(_sparse(d / "big.txt", 10 << 30)), "--est", str(d / "big.txt")], 2,
         r"big\.txt: larger than 1 GiB, the most phonepose reads as a trajectory file \(1 GiB of TUM lines is "
         r"~13 million poses, 37 hours at 100 Hz\): check that it is the right file$"),
    Case("motion-sparse-10g", "a 10 GB (sparse) file as `record sim --motion`",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"), "--motion", str(_sparse(d / "m.txt", 10 << 30))],
         2, r"m\.txt: larger than 1 GiB, the most phonepose reads as a trajectory file"),
    Case("playback-gt-sparse-10g", "a 10 GB (sparse) file as `playback --gt`",
         lambda g, d: ["playback", str(g), "-q", "--gt", str(_sparse(d / "gt.txt", 10 << 30)), "--out", str(d / "o")],
         2, r"gt\.txt: larger than 1 GiB, the most phonepose reads as a trajectory file"),
    Case("trajectory-nul-tail", "a valid trajectory followed by NUL bytes",
         lambda g, d: ["evaluate", "--gt", str(_write(d / "gt.txt", TUM_ROWS + bytes(4096))), "--est", str(d / "gt.txt")],
         2, r"gt\.txt: not a trajectory file \(binary data: a NUL byte at byte 420\)$"),
    Case("in-view-binary", "a binary `--in-view` file",
         lambda g, d: ["evaluate", "--gt", str(_write(d / "gt.txt", TUM_ROWS)), "--est", str(d / "gt.txt"),
                       "--metric", "paper", "--in-view", str(_write(d / "iv.txt", b"0.0 1\n\x00\x01"))], 2,
         r"iv\.txt: not an in-view file \(binary data: a NUL byte at byte 6\)$"),
    Case("trajectory-extreme", "a trajectory at 1e308 m (overflowed the alignment's SVD, inf metrics, `--json` failed)",
         lambda g, d: ["evaluate", "--gt", str(_write(d / "huge.txt", b"".join(
             b"%.1f 1e308 1e308 1e308 0 0 0 1\n" % (k / 10) for k in range(20)))), "--est", str(d / "huge.txt")], 2,
         r"huge\.txt:1: position 1e\+308 m is not one on Earth \(beyond ±1e7 m\): check the file's columns and units$"),
    Case("rpe-steps-1e160", "`evaluate --metric rpe --json` with positions stepping by 1e160 m",
         lambda g, d: ["evaluate", "--gt", str(_write(d / "step.txt", b"".join(
             b"%.1f %g 0 0 0 0 0 1\n" % (k / 10, k * 1e160) for k in range(20)))), "--est", str(d / "step.txt"),
             "--metric", "rpe", "--json"], 2, r"step\.txt:2: position 1e\+160 m is not one on Earth"),
    Case("trajectory-stamp-1e300", "a trajectory stamped 1e300 s",
         lambda g, d: ["evaluate", "--gt", str(_write(d / "t.txt", b"".join(
             b"%g 0 0 0 0 0 0 1\n" % (1e300 + k) for k in range(3)))), "--est", str(d / "t.txt")], 2,
         r"t\.txt:1: stamp 1e\+300 s is not a time \(beyond ±9e9 s, the year 2262\)"),
    Case("motion-extreme", "`record sim --motion` at 1e308 m (\"y must contain only finite values\")",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"), "--motion", str(_write(d / "m.txt", b"".join(
             b"%.1f %g 0 0 0 0 0 1\n" % (k / 10, 1e308 * (k % 2)) for k in range(300))))], 2,
         r"m\.txt:2: position 1e\+308 m is not one on Earth"),
    Case("evaluate-stationary", "`evaluate` (rpg) on a ground truth that does not move",
         lambda g, d: ["evaluate", "--gt", str(_write(d / "still.txt", b"".join(
             b"%.1f 1 2 3 0 0 0 1\n" % (k / 10) for k in range(20)))), "--est", str(d / "still.txt")], 4,
         r"still\.txt: its path is 0 m long, too short for the default RE lengths \(10-50 % of it, whole cm\): "
         r"give --lengths in m, or use --metric ape$"),
    Case("seed-300-digits", "`record sim --seed` with 301 digits (printed whole before)",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"), "--seed", str(10**300)], 5,
         r"^phonepose: error: --seed 1e\+300: expected an integer in \[0, 4294967295\]$"),
    *[Case(f"board-{cid}", why or f"`board --board '{spec}'`",
           lambda g, d, spec=spec, extra=extra: ["board", "--out", str(d / "b.png"), "--board", spec, *extra], 5,
           message)
      for cid, spec, extra, why, message in BOARD_CASES],
    Case("hand-eye-list", "`playback --gt-calibration` with a YAML list (an OpenCV `isMap()` assertion)",
         lambda g, d: ["playback", str(g), "-q", "--gt-calibration", str(_write(d / "l.yaml", b"- 1\n- 2\n")),
                       "--out", str(d / "o")], 2,
         r"l\.yaml: not an OpenCV YAML/XML calibration file \(its top level is a list; expected `key: value` lines, "
         r"as phonepose writes them\)$"),
    Case("gt-calibration-nested-list", "`evaluate --gt-calibration` whose T_controller_gt is a nested list",
         lambda g, d: ["evaluate", "--gt", _gt(d), "--est", str(d / "gt.txt"), "--gt-calibration",
                       str(_gt_calibration(d, b"T_controller_gt: [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]"))], 2,
         r"c\.yaml: T_controller_gt is not a matrix \(found a list; expected an !!opencv-matrix with rows, cols, dt "
         r"and data\)$"),
    Case("gt-calibration-offset-text", "a calibration whose `time_offset_s` is \"abc\" (read as 1.8e308)",
         lambda g, d: ["evaluate", "--gt", _gt(d), "--est", str(d / "gt.txt"), "--gt-calibration",
                       str(_gt_calibration(d, IDENTITY_4X4 + b'time_offset_s: "abc"\n'))], 2,
         r"c\.yaml: time_offset_s is not a number \(found text\)$"),
    Case("gt-calibration-offset-huge", "a calibration whose `time_offset_s` is 1e300",
         lambda g, d: ["evaluate", "--gt", _gt(d), "--est", str(d / "gt.txt"), "--gt-calibration",
                       str(_gt_calibration(d, IDENTITY_4X4 + b"time_offset_s: 1e300\n"))], 2,
         r"c\.yaml: time_offset_s 1e\+300 is not a clock offset in seconds \(expected at most 10 s either way\)$"),
    Case("gt-calibration-80gb-matrix", "a calibration matrix claiming 100000 x 100000 (80 GB for OpenCV)",
         lambda g, d: ["playback", str(g), "-q", "--out", str(d / "o"), "--gt-calibration",
                       str(_gt_calibration(d, IDENTITY_4X4.replace(b"rows: 4", b"rows: 100000")
                                           .replace(b"cols: 4", b"cols: 100000")))], 2,
         r"c\.yaml: T_controller_gt is not a matrix of at most 64 numbers \(its rows, cols and data disagree\)$"),
    Case("trajectory-fifo", "a FIFO as `evaluate --gt`",
         lambda g, d: ["evaluate", "--gt", str(_fifo(d / "gt.tum")), "--est", str(_write(d / "e.tum", TUM_ROWS))], 2,
         r"gt\.tum: not a regular file \(a FIFO, socket or device\): give a trajectory file$"),
    Case("hand-eye-fifo", "a FIFO as `playback --gt-calibration`",
         lambda g, d: ["playback", str(g), "-q", "--gt-calibration", str(_fifo(d / "he.yaml")), "--out", str(d / "o")], 2,
         r"he\.yaml: not a regular file \(a FIFO, socket or device\): give a calibration file$"),
    Case("image-fifo", "a FIFO among `calibrate-camera --images`",
         lambda g, d: ["calibrate-camera", "--images", str(_fifo_in(d / "imgs", "a.png")), "--out", str(d / "c.yaml")],
         2, r"imgs/a\.png: not a regular file \(a FIFO, socket or device\): give an image$"),
    Case("rerun-device", "`record sim --rerun /dev/full`",
         lambda g, d: ["record", "sim", "-q", "--out", str(d / "s.mcap"), "--rerun", "/dev/full"], 6,
         r"^phonepose: error: --rerun /dev/full: not a regular file \(a device, FIFO or socket\); give a file name$"),
    Case("camera-missing", "a camera index with no device (`calibrate-camera --camera 63`)",
         lambda g, d: ["calibrate-camera", "--camera", "63", "--out", str(d / "c.yaml")], 2,
         r"camera device 63 cannot be opened \(no such camera, or in use\)$"),
    Case("scheduler-not-a-url", "`batch --scheduler 'not a url'`",
         lambda g, d: ["batch", str(g), "--scheduler", "not a url", "--out", str(d / "r.parquet")], 5,
         r"--scheduler 'not a url': expected a Dask scheduler address such as tcp://host:8786$"),
]


IDENTITY_4X4 = (b"T_controller_gt: !!opencv-matrix\n   rows: 4\n   cols: 4\n   dt: d\n"
                b"   data: [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]\n")


def _gt_calibration(d: Path, body: bytes, name: str = "c.yaml") -> Path:
    """A ground-truth calibration file (phonepose.calibration.gt_calibration) with ``body`` as its keys."""
    return _write(d / name, b"%YAML:1.0\n---\nformat: phonepose-gt-calibration\nversion: 1\n" + body + b"\n")


def _sparse(path: Path, size: int) -> Path:
    """A file of ``size`` bytes that takes no space on the disk (NUL bytes only)."""
    with open(path, "wb") as f:
        f.truncate(size)
    return path


def _fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


def _fifo_in(folder: Path, name: str) -> Path:
    folder.mkdir()
    _write(folder / "b.png", b"\x89PNG")
    _fifo(folder / name)
    return folder


TUM_ROWS = b"".join(b"%.1f %.2f 0 0 0 0 0 1\n" % (k / 10, k / 100) for k in range(20))
LATE_ROWS = b"".join(b"%.1f %.2f 0 0 0 0 0 1\n" % (100 + k / 10, k / 100) for k in range(20))   # 100 s later


def _mkdir(path: Path) -> Path:
    path.mkdir()
    return path


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("good") / "good.mcap"
    write_test_session(path, duration_s=2.0)
    return path


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input(case: Case, good, tmp_path, cli):
    code, _, err = cli(*case.argv(good, tmp_path))
    lines = err.strip().splitlines()
    assert code == case.code, err
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("phonepose: error: ")
    message = case.message(good) if callable(case.message) else case.message
    assert re.search(message, lines[0]), lines[0]


@pytest.mark.parametrize("argv", [
    ["calibrate-hand-eye", "{bad}", "-o", "{d}/he.yaml"],           # OpenCV's FileStorage crashed on it (exit 139)
    ["calibrate-gt", "{bad}", "-o", "{d}/gt.yaml"],
    ["calibrate-camera", "-q", "--video", "{bad}", "-o", "{d}/c.yaml"],
    ["playback", "{bad}", "-q", "-t", "T1", "-o", "{d}/pb"],         # "unexpected UnicodeEncodeError"
    ["playback", "{good}", "-q", "-t", "T1", "-o", "{d}/pb", "--rerun", "{d}/r\udcfe.rrd"],
    ["info", "{bad}"],
])
def test_an_argument_that_is_not_utf8_is_one_line_before_any_work(good, tmp_path, cli, argv):
    """A file name in another encoding (bytes 0xff, 0xfe: os.fsdecode escapes them as lone surrogates)."""
    bad = tmp_path / "a\udcff.mcap"
    bad.write_bytes(good.read_bytes())
    before = sorted(os.listdir(os.fsencode(tmp_path)))
    args = [a.format(bad=bad, good=good, d=tmp_path) for a in argv]
    shown = next(a for a in args if any(0xDC80 <= ord(c) <= 0xDCFF for c in a))
    shown = os.fsencode(shown).decode("utf-8", "backslashreplace")
    code, out, err = cli(*args)
    assert code == 5 and out == "", err
    assert err == f"phonepose: error: the argument '{shown}' is not UTF-8 text (a file name in another " \
                  f"encoding?): rename the file with a UTF-8 name\n"
    assert sorted(os.listdir(os.fsencode(tmp_path))) == before


def test_a_session_without_camera_or_marker_spec_plays_the_vio_trackers(good, tmp_path, cli):
    """No camera and no /controller/marker: nothing to recognise, and nothing asks for a marker dictionary."""
    bare = rewrite(good, tmp_path / "bare.mcap", _drop("/display/camera", Topic.CONTROLLER_MARKER))
    code, out, err = cli("playback", str(bare), "-q", "-t", "T1", "-t", "T2", "--out", str(tmp_path / "o"))
    assert code == 0 and err == "", err
    assert (tmp_path / "o" / "trajectories" / "T1.tum").stat().st_size > 0


def test_the_good_session_plays(good, tmp_path, cli):
    """The control: the input every case breaks plays back cleanly."""
    code, out, err = cli("playback", str(good), "-q", "-t", "T1", "-t", "T4", "--out", str(tmp_path / "o"))
    assert code == 0 and err == "", err
    assert "T4" in out


def _subprocess(*args):
    return subprocess.run([sys.executable, "-m", "phonepose", *args], capture_output=True, text=True)


def _tum(path: Path) -> np.ndarray:
    return np.loadtxt(path, comments="#").reshape(-1, 8)


@pytest.fixture(scope="module")
def clean_run(good, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("clean") / "o"
    ok = _subprocess("playback", str(good), "-q", "-t", "T1", "--out", str(out))
    assert ok.returncode == 0 and ok.stderr == ""
    return out


WARNING_CASES = [
    ("duplicate-timestamps", "every controller VIO sample written twice", _duplicate_vio,
     r"/controller/vio/pose: 60 sample\(s\) skipped: duplicate or non-monotonic timestamp"),
    ("backwards-timestamps", "every 5th controller VIO stamp 200 ms in the past", _backwards_vio(),
     r"/controller/vio/pose: 12 sample\(s\) skipped: duplicate or non-monotonic timestamp"),
    ("bad-quaternions", "controller VIO with NaN / |q| = 5 / inf position in every other sample",
     _bad_quaternions(), r"/controller/vio/pose: 30 sample\(s\) skipped: NaN/inf value or non-unit quaternion"),
    ("foreign-payloads", "controller VIO where every other payload is an IMU message's bytes", _foreign_payloads(),
     r"/controller/vio/pose: 30 sample\(s\) skipped: no pose in the message \(neither position nor orientation set\)"),
    ("extreme-imu", "controller IMU with gyro 1e200 rad/s or accel -1e300 m/s^2 in every other sample",
     _extreme_imu(), r"/controller/imu: 100 sample\(s\) skipped: value outside any IMU's range "
                     r"\(\|gyro\| > 1000 rad/s or \|accel\| > 10000 m/s\^2\)"),
    ("undecodable-images", "camera frames that are not JPEG", _static(Topic.CAMERA_IMAGE, _garbage_image),
     r"/display/camera/image: 41 camera frame\(s\) could not be decoded; they count as showing no marker"),
    ("images-other-size", "camera frames of half the calibration's size (used with the wrong K before)",
     _static(Topic.CAMERA_IMAGE, _half_size_image),
     r"/display/camera/image: 41 camera frame\(s\) are 160x120 px, not the calibration's 320x240; they count as "
     r"showing no marker"),
    *((f"images-claiming-{w}x{h}", f"camera frames whose JPEG header claims {w}x{h} px (" + why + ")",
       _static(Topic.CAMERA_IMAGE, _claiming(w, h)),
       rf"/display/camera/image: 41 camera frame\(s\) are {shown}, not the calibration's 320x240; they count as "
       r"showing no marker")
      for w, h, shown, why in ((65500, 65500, "more than 178 Mpx", "OpenCV's validateInputImageSize failed"),
                               (20000, 20000, "more than 178 Mpx", "decoded at ~870 MB a frame"),
                               (640, 480, "640x480 px", "read from the header, never decoded"))),
    ("images-cut", "camera frames cut in half (libjpeg printed \"Corrupt JPEG data\" once a frame)",
     _static(Topic.CAMERA_IMAGE, _cut_image),
     r"/display/camera/image: 41 camera frame\(s\) hold damaged image data \(Corrupt JPEG data: premature end of "
     r"data segment\); decoded as far as it goes"),
]


@pytest.mark.parametrize("cid,what,fn,message", WARNING_CASES, ids=[c[0] for c in WARNING_CASES])
def test_bad_samples_are_reported_and_skipped(good, clean_run, tmp_path, cid, what, fn, message):
    """Reported once per topic on stderr, skipped (never used), and the playback still succeeds."""
    bad = rewrite(good, tmp_path / f"{cid}.mcap", fn)
    r = _subprocess("playback", str(bad), "-q", "-t", "T1", "--out", str(tmp_path / "o"))
    assert r.returncode == 0, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and re.search("^phonepose: warning: " + message + "$", lines[0]), r.stderr
    est = _tum(tmp_path / "o" / "trajectories" / "T1.tum")
    ref = _tum(clean_run / "trajectories" / "T1.tum")
    assert np.isfinite(est).all()
    assert len(est) == len(ref) and np.array_equal(est[:, 0], ref[:, 0])
    q_norm = np.linalg.norm(est[:, 4:8], axis=1)
    assert np.allclose(q_norm, 1.0, atol=1e-9)
    # the remaining samples of the same straight path interpolate to within a few mm of the clean run
    assert np.abs(est[:, 1:4] - ref[:, 1:4]).max() < 0.02


def test_a_session_without_its_info_message_says_so(good, clean_run, tmp_path):
    """/session/info removed (a tool that keeps some topics; an edited file): its task window is gone, so playback
    scores every tick of the session. It did so without a word, and the numbers differed from the recording's
    (TRI2: T4's inside frames 84 -> 248). One warning line now; the scores are of the whole session as before."""
    import json

    bare = rewrite(good, tmp_path / "noinfo.mcap", lambda t, msg, lt: [] if t == Topic.SESSION_INFO else [(t, msg, lt)])
    r = _subprocess("playback", str(bare), "-q", "-t", "T1", "--out", str(tmp_path / "o"))
    assert r.returncode == 0, r.stderr
    assert r.stderr.strip() == (f"phonepose: warning: {bare}: no /session/info, so no task window: the metrics cover "
                                "the whole session")
    frames = json.loads((tmp_path / "o" / "metrics.json").read_text())["trackers"]["T1"]["total"]["frames"]
    clean = json.loads((clean_run / "metrics.json").read_text())["trackers"]["T1"]["total"]["frames"]
    assert frames > clean
    # a ROS 2 bag's shape (no /session/info, the VIO in CDR): the error alone, no warning before it
    ros = with_channel(bare, tmp_path / "ros.mcap", Topic.CONTROLLER_VIO_POSE, "geometry_msgs/msg/PoseStamped",
                       "ros2msg", b"", "cdr", lambda b: b)
    r = _subprocess("playback", str(ros), "-q", "-t", "T1", "--out", str(tmp_path / "o2"))
    assert r.returncode == 4 and r.stderr.strip() == (f"phonepose: error: {ros}: topic /controller/vio/pose has "
                                                      "encoding 'cdr', phonepose reads protobuf only")


# ----------------------------------------------------------------------------- docs table
def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def _code(text: str) -> str:
    """A markdown code span that may itself contain backticks and pipes."""
    text = text.replace("|", "\\|")
    return f"`` {text} ``" if "`" in text else f"`{text}`"


def markdown_table(tmp: Path) -> str:
    """Run every case and print what the user sees (paths shortened), for docs/reliability.md."""
    import contextlib
    import io

    from phonepose.cli import main

    good = tmp / "good.mcap"
    write_test_session(good, duration_s=2.0)
    rows = ["| bad input | command | exit | what the user sees (stderr) |", "|---|---|---|---|"]
    for case in CASES:
        d = tmp / case.id
        d.mkdir()
        argv = case.argv(good, d)
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                main(argv)
                code = 0
            except SystemExit as exc:
                code = exc.code or 0
        line = err.getvalue().strip().replace(str(d) + "/", "").replace(str(tmp) + "/", "").replace(str(d), "DIR")
        if len(line) > 240:
            line = line[:237] + "..."
        command = " ".join(argv[:2]) if argv[0] in ("record", "experiment") else argv[0]
        rows.append(f"| {_cell(case.what)} | `{command}` | {code} | {_code(line)} |")
    for _cid, what, _fn, message in WARNING_CASES:
        msg = re.sub(r"\\(.)", r"\1", message)     # the regex's escapes undone
        rows.append(f"| {_cell(what)} | `playback` | 0 | {_code('phonepose: warning: ' + msg)} (samples skipped) |")
    return "\n".join(rows)


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as t:
        print(markdown_table(Path(t)))


def test_extreme_imu_values_do_not_reach_the_fusion(good, tmp_path):
    """T8 integrates the IMU: with the impossible samples skipped it runs, and its poses stay finite."""
    bad = rewrite(good, tmp_path / "imu.mcap", _extreme_imu())
    r = _subprocess("playback", str(bad), "-q", "-t", "T8", "--out", str(tmp_path / "o"))
    assert r.returncode == 0, r.stderr
    assert r.stderr.startswith("phonepose: warning: /controller/imu: 100 sample(s) skipped: value outside")
    est = _tum(tmp_path / "o" / "trajectories" / "T8.tum")
    assert len(est) > 10 and np.isfinite(est).all()


def test_evaluate_warns_when_the_matched_poses_cover_a_small_part(clean_run, tmp_path):
    """Another session's ground truth (all simulated sessions start at the same stamp) still matches some
    poses: when they cover under half of either trajectory, one warning line says so; the metrics stand."""
    gt_rows = (clean_run / "groundtruth.tum").read_text().splitlines()
    header = [r for r in gt_rows if r.startswith("#")]
    rows = [r for r in gt_rows if not r.startswith("#")]
    short = tmp_path / "short.tum"
    short.write_text("\n".join(header + rows[: len(rows) // 4]) + "\n")
    est = clean_run / "trajectories" / "T1.tum"
    n_est = sum(1 for r in est.read_text().splitlines() if not r.startswith("#"))
    r = _subprocess("evaluate", "--gt", str(short), "--est", str(est), "--metric", "ape")
    assert r.returncode == 0
    pct = round(100 * (len(rows) // 4) / n_est)
    assert r.stderr == (f"phonepose: warning: the matched poses cover {pct}% of {est}'s poses and 100% of {short}'s "
                        "time span: are they from the same session?\n")
    ok = _subprocess("evaluate", "--gt", str(clean_run / "groundtruth.tum"), "--est", str(est), "--metric", "ape")
    assert ok.returncode == 0 and ok.stderr == ""


def test_evaluate_warns_when_the_files_come_from_different_sessions(clean_run, tmp_path):
    """The issue's case: an estimate scored against another session's ground truth. Both start at the
    same stamp and overlap for most of their poses, so coverage cannot tell; the session tag playback
    writes in every file's header can. The same session's files give no warning."""
    from phonepose.evaluation.trajectory import read_session_tag

    other = tmp_path / "other.mcap"
    write_test_session(other, duration_s=2.5)          # another task window: another SessionInfo
    run = tmp_path / "o"
    assert _subprocess("playback", str(other), "-q", "-t", "T1", "--out", str(run)).returncode == 0
    est, gt = clean_run / "trajectories" / "T1.tum", run / "groundtruth.tum"
    tag_est, tag_gt = read_session_tag(est), read_session_tag(gt)
    assert tag_est.startswith("good.mcap ") and tag_gt.startswith("other.mcap ") and len(tag_gt.split()[1]) == 16
    assert read_session_tag(run / "trajectories" / "T1.tum") == tag_gt == read_session_tag(run / "in_view.txt")
    r = _subprocess("evaluate", "--gt", str(gt), "--est", str(est), "--metric", "paper", "--in-view",
                    str(clean_run / "in_view.txt"))
    assert r.returncode == 0
    assert r.stderr.splitlines()[0] == (
        f"phonepose: warning: these files come from different sessions ({est}: {tag_est}; {gt}: {tag_gt}; "
        f"{clean_run / 'in_view.txt'}: {tag_est}): the errors compare two recordings")
    same = _subprocess("evaluate", "--gt", str(run / "groundtruth.tum"), "--est", str(run / "trajectories" / "T1.tum"))
    assert same.returncode == 0 and same.stderr == ""


def test_evaluate_reports_bad_rows(clean_run, tmp_path):
    """Trajectory files: a non-unit quaternion is normalised (as evo and rpg do) and reported; duplicate stamps are
    reported."""
    import json

    gt = clean_run / "groundtruth.tum"
    est = clean_run / "trajectories" / "T1.tum"
    ok = _subprocess("evaluate", "--gt", str(gt), "--est", str(est), "--json")
    assert ok.returncode == 0 and ok.stderr == ""
    n = json.loads(ok.stdout)["n_matched"]
    lines = est.read_text().splitlines()
    rows = [i for i, line in enumerate(lines) if not line.startswith("#")]
    bad = list(lines)
    parts = bad[rows[5]].split()
    parts[7] = "5.0"                                  # qw = 5: |q| far from 1
    bad[rows[5]] = " ".join(parts)
    (tmp_path / "q.tum").write_text("\n".join(bad) + "\n")
    r = _subprocess("evaluate", "--gt", str(gt), "--est", str(tmp_path / "q.tum"), "--json")
    assert r.returncode == 0
    assert r.stderr.strip() == (f"phonepose: warning: {tmp_path / 'q.tum'}: 1 pose(s) whose quaternion is not unit "
                                f"length (|q| {float(np.linalg.norm([float(x) for x in parts[4:]])):.6g} to "
                                f"{float(np.linalg.norm([float(x) for x in parts[4:]])):.6g}): normalised, as evo and "
                                "rpg do")
    assert json.loads(r.stdout)["n_matched"] == n
    dup = list(lines)
    dup.insert(rows[3], lines[rows[3]])
    (tmp_path / "d.tum").write_text("\n".join(dup) + "\n")
    r = _subprocess("evaluate", "--gt", str(gt), "--est", str(tmp_path / "d.tum"), "--json")
    assert r.returncode == 0
    assert r.stderr.strip() == (f"phonepose: warning: {tmp_path / 'd.tum'}: 1 duplicate or non-monotonic "
                                "timestamp(s), used as evo/rpg do")


def test_output_on_a_read_only_filesystem(good, tmp_path, cli):
    """A read-only mount (root with mount permission only): playback, record and recover say so in one line."""
    with mounted_tmpfs(tmp_path / "ro", "ro,size=1m") as mnt:
        for argv, pattern in [
            (["playback", str(good), "-q", "-t", "T1", "--out", str(mnt / "out")],
             r"--out .*ro/out: directory .*ro is on a read-only file system$"),
            (["recover", str(good), "--out", str(mnt / "fixed.mcap")],
             r"--out .*ro/fixed\.mcap: directory .*ro is on a read-only file system$"),
            (["record", "sim", "-q", "--out", str(mnt / "s.mcap")],
             r"--out .*ro/s\.mcap: directory .*ro is on a read-only file system$"),
            (["board", "--out", str(mnt / "b.png")], r"--out .*ro/b\.png: directory .*ro is on a read-only file system$"),
        ]:
            code, _, err = cli(*argv)
            assert code == 6, err
            assert len(err.strip().splitlines()) == 1 and re.search(pattern, err.strip()), err
