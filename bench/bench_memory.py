"""Peak memory of a playback: a 10-minute session against a 1-minute one of the same kind.

Playback must stream (read chunk by chunk, decode one frame at a time), so its peak resident
memory must not grow with the session's length: the ratio of the two peaks should be ~1. Each
playback (``--tracker all``, outputs written) runs in its own child process, which reports its
own peak RSS (``VmHWM`` of /proc/self/status, else ``ru_maxrss``) next to its RSS after the
imports and the session's setup, before the first tick (the fixed cost), and its peak up to the
last tick (the streaming part; after it the trajectories are assembled and the metrics, which
need every pose for the alignment, are computed: that part is O(session length) by nature).

The sessions are the kind of the hand-made playback test session (phonepose.testing.playback_session):
30 Hz 640x480 JPEG frames of a rendered 5 cm marker circling in view, display + controller VIO
at 30 Hz, anchors, GT at 60 Hz, IMU at 100 Hz. They are written streaming, in log-time order,
with the frames of one 2 s circle rendered once and reused (the poses repeat with the same
period), so building 10 minutes takes seconds. The simulator is not used: 10 minutes of
simulated recording would take longer than the whole benchmark may.

    python -m bench memory          or          python bench/bench_memory.py
"""

from __future__ import annotations

import heapq
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

LONG_S = 600.0
SHORT_S = 60.0
TARGET_RATIO = 1.05  # "does not grow": within 5 % (allocator noise) of the 1-minute session

_CHILD = r"""
import json, resource, sys, time
def status_kb(key):
    try:
        for line in open("/proc/self/status"):
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except OSError:
        pass
    return None
def peak_kb():
    kb = status_kb("VmHWM")
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss if kb is None else kb
def rss_kb():
    return status_kb("VmRSS") or 0
from phonepose.playback.engine import run_playback
seen = {}
def progress(done, total):
    if done == 1:
        seen["setup_rss_kb"] = rss_kb()
    if done == total:
        seen["last_tick_peak_kb"] = peak_kb()
t0 = time.perf_counter()
res = run_playback(sys.argv[1], trackers=["all"], out_dir=sys.argv[2], progress=progress)
print(json.dumps({"peak_kb": peak_kb(), "setup_rss_kb": seen.get("setup_rss_kb", 0),
                  "last_tick_peak_kb": seen.get("last_tick_peak_kb", 0), "ticks": res.n_ticks,
                  "frames": res.frames_decoded, "wall_s": time.perf_counter() - t0}))
"""


def write_streaming_session(path: Path, duration_s: float, width: int = 640, height: int = 480) -> int:
    """A session like ``write_test_session`` (marker in view throughout), written in log-time order
    without holding it in memory. Returns the number of messages."""
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from scipy.spatial.transform import Rotation

    from phonepose.geometry import Pose
    from phonepose.schemas import phonepose_pb2 as pb
    from phonepose.schemas.topics import Frame, Topic
    from phonepose.session import SessionWriter
    from phonepose.session.codec import encode_pose, frame_transform, pose_in_frame
    from phonepose.testing.marker_images import encode_jpeg, pinhole_camera, render_marker
    from phonepose.testing.playback_session import ANCHOR_ERROR, MARKER, T0_NS, T_DVIO_ANCHOR, T_WORLD_DVIO, T_camera_marker_at

    cam = pinhole_camera(f=250.0 * width / 320, width=width, height=height)
    T_dvio_display = Pose.identity()
    T_cvio_anchor = Pose.from_xyzw([-0.5, 0.3, 0.2], Rotation.from_euler("y", 40, degrees=True).as_quat())
    map_c = T_cvio_anchor @ (T_DVIO_ANCHOR @ ANCHOR_ERROR).inv()
    forever = 1e12  # the marker never slides out of view

    def ns(t_s: float) -> int:
        return T0_NS + int(round(t_s * 1e9))

    def ctrl_true(t_s: float) -> Pose:
        return T_dvio_display @ T_camera_marker_at(t_s, forever) @ MARKER.T_body_marker.inv()

    period_frames = 60  # the circle's period is 2 s: 60 frames at 30 Hz, then the same images again
    bank = [encode_jpeg(render_marker(cam, MARKER, T_camera_marker_at(k / 30.0, forever), supersample=2))
            for k in range(period_frames)]

    def static():
        info = pb.SessionInfo(source="test", scenario="bench-memory", seed=0, phonepose_version="bench",
                              description=f"bench memory session, {duration_s:.0f} s")
        info.task_start.FromNanoseconds(ns(0.3))
        info.task_end.FromNanoseconds(ns(duration_s - 0.2))
        info.timestamp.FromNanoseconds(T0_NS)
        yield T0_NS, Topic.SESSION_INFO, info
        calib = CameraCalibration(frame_id=Frame.DISPLAY_CAMERA, width=width, height=height, distortion_model="plumb_bob",
                                  D=[0.0] * 5, K=[float(v) for v in cam.K.reshape(-1)])
        calib.timestamp.FromNanoseconds(T0_NS)
        yield T0_NS, Topic.CAMERA_CALIBRATION, calib
        yield T0_NS, Topic.CAMERA_EXTRINSICS, frame_transform(Pose.identity(), Frame.DISPLAY, Frame.DISPLAY_CAMERA, T0_NS)
        spec = pb.MarkerSpec(dictionary=MARKER.dictionary, id=MARKER.id, size_m=MARKER.size_m)
        encode_pose(MARKER.T_body_marker, spec.pose_in_body)
        spec.timestamp.FromNanoseconds(T0_NS)
        yield T0_NS, Topic.CONTROLLER_MARKER, spec
        yield T0_NS, Topic.GT_CALIBRATION, frame_transform(T_WORLD_DVIO, Frame.WORLD, Frame.DISPLAY_VIO, T0_NS)
        yield ns(0.05), Topic.DISPLAY_ANCHOR, pose_in_frame(T_DVIO_ANCHOR, Frame.DISPLAY_VIO, ns(0.05))
        yield ns(0.07), Topic.CONTROLLER_ANCHOR, pose_in_frame(T_cvio_anchor, Frame.CONTROLLER_VIO, ns(0.07))
        ev = pb.CalibrationEvent(kind=pb.CalibrationEvent.CM1, frame_id=Frame.DISPLAY_VIO)
        ev.timestamp.FromNanoseconds(ns(0.2))
        ev.fix_timestamp.FromNanoseconds(ns(0.1))
        encode_pose(ctrl_true(0.2), ev.pose_fix_vio)
        encode_pose(T_DVIO_ANCHOR @ T_cvio_anchor.inv() @ map_c @ ctrl_true(0.2), ev.pose_align_vio)
        yield ns(0.2), Topic.CALIBRATION_EVENTS, ev
        ev2 = pb.CalibrationEvent(kind=pb.CalibrationEvent.CM2, frame_id=Frame.DISPLAY_VIO)
        ev2.timestamp.FromNanoseconds(ns(0.25))
        yield ns(0.25), Topic.CALIBRATION_EVENTS, ev2

    def camera():
        for k in range(int(duration_s * 30) + 1):
            t = k / 30.0
            img = CompressedImage(frame_id=Frame.DISPLAY_CAMERA, format="jpeg", data=bank[k % period_frames])
            img.timestamp.FromNanoseconds(ns(t))
            yield ns(t), Topic.CAMERA_IMAGE, img

    # the motion repeats every 2 s: one period of poses, computed once
    vio_c = [map_c @ ctrl_true((k + 0.5) / 30.0) for k in range(period_frames)]
    gt_c = [T_WORLD_DVIO @ ctrl_true(k / 60.0) for k in range(2 * period_frames)]

    def vio():
        for k in range(int(duration_s * 30) + 1):
            t = (k + 0.5) / 30.0
            if t > duration_s:
                break
            yield ns(t), Topic.DISPLAY_VIO_POSE, pose_in_frame(T_dvio_display, Frame.DISPLAY_VIO, ns(t))
            yield ns(t) + 3_000_000, Topic.CONTROLLER_VIO_POSE, pose_in_frame(vio_c[k % period_frames],
                                                                              Frame.CONTROLLER_VIO, ns(t))

    def gt():
        for k in range(int(duration_s * 60) + 1):
            t = k / 60.0
            yield ns(t), Topic.GT_CONTROLLER_POSE, pose_in_frame(gt_c[k % (2 * period_frames)], Frame.WORLD, ns(t))

    def imu():
        for k in range(int(duration_s * 100) + 1):
            t = k / 100.0
            m = pb.Imu(frame_id=Frame.CONTROLLER, gyro_x=0.01 * (k % 1000), gyro_y=0.0, gyro_z=0.1, accel_x=0.0,
                       accel_y=9.81, accel_z=0.0)
            m.timestamp.FromNanoseconds(ns(t))
            yield ns(t) + 2_000_000, Topic.CONTROLLER_IMU, m

    n = 0
    streams = [static(), camera(), vio(), gt(), imu()]
    # each stream is in time order; merge them (stable on ties by stream index)
    merged = heapq.merge(*[((t, i, topic, msg) for t, topic, msg in s) for i, s in enumerate(streams)],
                         key=lambda x: (x[0], x[1]))
    with SessionWriter(path) as w:
        for t, _, topic, msg in merged:
            w.write(topic, msg, t)
            n += 1
    return n


def _play(session: Path, out: Path) -> dict:
    r = subprocess.run([sys.executable, "-c", _CHILD, str(session), str(out)], capture_output=True, text=True,
                       timeout=1200)
    if r.returncode != 0:
        raise RuntimeError(f"playback of {session} failed: {r.stderr.strip().splitlines()[-1:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-memory-") as d:
        tmp = Path(d)
        sizes = {}
        t0 = time.perf_counter()
        for name, dur in (("short", SHORT_S), ("long", LONG_S)):
            p = tmp / f"{name}.mcap"
            write_streaming_session(p, dur)
            sizes[name] = p.stat().st_size / 1e6
        t_build = time.perf_counter() - t0
        runs = {name: _play(tmp / f"{name}.mcap", tmp / f"out-{name}") for name in ("short", "long")}
    s, lg = runs["short"], runs["long"]
    res = {
        "session": "hand-made kind (testdata): 640x480 JPEG 30 Hz, VIO 30 Hz, GT 60 Hz, IMU 100 Hz, anchors",
        "short_s": SHORT_S, "long_s": LONG_S,
        "short_MB": round(sizes["short"], 1), "long_MB": round(sizes["long"], 1),
        "build_s": round(t_build, 1),
        "short_ticks": s["ticks"], "long_ticks": lg["ticks"],
        "short_peak_MB": round(s["peak_kb"] / 1024, 1), "long_peak_MB": round(lg["peak_kb"] / 1024, 1),
        "short_setup_MB": round(s["setup_rss_kb"] / 1024, 1), "long_setup_MB": round(lg["setup_rss_kb"] / 1024, 1),
        "short_peak_at_last_tick_MB": round(s["last_tick_peak_kb"] / 1024, 1),
        "long_peak_at_last_tick_MB": round(lg["last_tick_peak_kb"] / 1024, 1),
        "peak_ratio_long_vs_short": round(lg["peak_kb"] / s["peak_kb"], 3),
        "ticks_peak_ratio_long_vs_short": round(lg["last_tick_peak_kb"] / s["last_tick_peak_kb"], 3),
        "growth_MB": round((lg["peak_kb"] - s["peak_kb"]) / 1024, 1),
        "target_ratio": TARGET_RATIO,
        "long_playback_s": round(lg["wall_s"], 1),
    }
    print(f"sessions built in {t_build:.0f} s: {SHORT_S:.0f} s ({res['short_MB']} MB) and {LONG_S:.0f} s "
          f"({res['long_MB']} MB) of the hand-made kind, 640x480 at 30 Hz")
    print(f"  playback --tracker all, peak RSS: {SHORT_S:.0f} s session {res['short_peak_MB']} MB "
          f"(after setup {res['short_setup_MB']} MB), {LONG_S:.0f} s session {res['long_peak_MB']} MB "
          f"(after setup {res['long_setup_MB']} MB)")
    print(f"  peak RSS up to the last tick (the streaming part; then trajectories are built and the metrics "
          f"computed): {res['short_peak_at_last_tick_MB']} MB vs {res['long_peak_at_last_tick_MB']} MB = "
          f"{res['ticks_peak_ratio_long_vs_short']:.2f}x")
    print(f"  ratio 10 min / 1 min: {res['peak_ratio_long_vs_short']:.2f}x (+{res['growth_MB']} MB; "
          f"target <= {TARGET_RATIO}x); the 10-minute playback took {res['long_playback_s']} s")
    return res


if __name__ == "__main__":
    main()
