"""SharedStages: one decode + recognition per camera frame, anchor mapping, /pipeline/markers."""

from __future__ import annotations

import numpy as np
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

from phonepose.geometry import Pose
from phonepose.pipeline.anchors import controller_in_display_vio
from phonepose.pipeline.shared import SharedStages
from phonepose.pipeline.trackers import make_trackers
from phonepose.pipeline.types import Frame as PipelineFrame
from phonepose.pipeline.types import MarkerModel, SessionContext, Tick
from phonepose.playback.outputs import detections_message
from phonepose.schemas.topics import Frame
from phonepose.session import codec
from phonepose.testing.marker_images import encode_jpeg, looking_at, pinhole_camera, render_marker

T_DISPLAY_CAMERA = Pose.from_rotvec([0.0, 0.0, 0.0], [0.0, 0.07, 0.0])
CAMERA = pinhole_camera(T_display_camera=T_DISPLAY_CAMERA)
MARKER = MarkerModel("DICT_4X4_50", 7, 0.05, Pose.from_rotvec([0.0, 0.0, 0.0], [0.0, 0.02, 0.004]))
T_CAMERA_MARKER = looking_at(0.3, 30, 40, roll_deg=15)
T_DVIO_DISPLAY = Pose.from_rotvec([0.1, -0.2, 0.05], [0.5, 1.4, -0.2])
ANCHORS = dict(T_dvio_anchor=Pose.from_rotvec([0, 0, 0.5], [1.0, 0.0, 0.0]),
               T_cvio_anchor=Pose.from_rotvec([0, 0, -0.3], [0.0, 2.0, 0.0]),
               T_cvio_controller=Pose.from_rotvec([0.2, 0.1, 0.0], [0.3, 0.2, 0.1]))


def jpeg(pose: Pose | None) -> CompressedImage:
    gray = (render_marker(CAMERA, MARKER, pose, blur_sigma=0.5) if pose is not None
            else np.full((480, 640), 110, np.uint8))
    return CompressedImage(data=encode_jpeg(gray, 92), format="jpeg", frame_id=Frame.DISPLAY_CAMERA)


def tick(i, image=None, image_t_ns=None, new=False, display=T_DVIO_DISPLAY, **kw) -> Tick:
    frame = None if image is None else PipelineFrame(image.data, image.format, image_t_ns, new, display)
    return Tick(index=i, t_ns=i * 50_000_000, frame=frame, T_dvio_display=display, **{**ANCHORS, **kw})


def test_process_detects_reuses_and_maps():
    stages = SharedStages(SessionContext(camera=CAMERA, marker=MARKER))
    frame = jpeg(T_CAMERA_MARKER)
    obs0 = stages.process(tick(0, frame, 1_000, new=True))
    assert obs0.in_view
    truth = T_DVIO_DISPLAY @ T_DISPLAY_CAMERA @ T_CAMERA_MARKER @ MARKER.T_body_marker.inv()
    assert obs0.marker.T_dvio_controller.distance_to(truth) < 0.001
    assert np.degrees(obs0.marker.T_dvio_controller.angle_to(truth)) < 0.5
    assert obs0.T_dvio_controller_vio.allclose(controller_in_display_vio(**ANCHORS), atol=1e-12)
    # the next tick carries the same frame: reused, not decoded again
    obs1 = stages.process(tick(1, frame, 1_000, new=False))
    assert stages.frames_decoded == 1 and obs1.marker is obs0.marker
    # an empty frame: out of view; VIO still mapped
    obs2 = stages.process(tick(2, jpeg(None), 100_000_000, new=True))
    assert not obs2.in_view and stages.frames_decoded == 2 and obs2.T_dvio_controller_vio is not None
    # no image at all, and no anchors: nothing
    obs3 = stages.process(Tick(index=3, t_ns=150_000_000))
    assert not obs3.in_view and obs3.T_dvio_controller_vio is None
    # a marker without a display pose cannot be placed in display_vio
    obs4 = stages.process(tick(4, frame, 200_000_000, new=True, display=None))
    assert not obs4.in_view


def _reencoded(frame: CompressedImage, orientation: int | None = None, size: tuple[int, int] | None = None):
    """The frame's pixels saved again by Pillow, with an EXIF orientation tag and/or resized (another tool's JPEG)."""
    import io

    from PIL import Image

    image = Image.open(io.BytesIO(frame.data))
    if size is not None:
        image = image.resize(size)
    exif = image.getexif()
    if orientation is not None:
        exif[0x0112] = orientation
    out = io.BytesIO()
    image.save(out, "JPEG", quality=95, exif=exif)
    return CompressedImage(data=out.getvalue(), format="jpeg", frame_id=Frame.DISPLAY_CAMERA)


def test_frames_are_read_as_stored_and_other_sizes_are_not_used():
    """A JPEG with an EXIF orientation (another tool's camera frames): OpenCV's decoder turned the pixels (180° made
    T4's p_ATE 0.9 -> 17.9 cm on a simulated session, silently). The calibration describes the stored pixels, so the
    tag is ignored and the pose is exactly the untagged frame's. A frame of another size than the calibration's
    (1280x960 for 640x480) was used with the wrong K: it now counts as showing no marker, and is counted."""
    frame = jpeg(T_CAMERA_MARKER)
    plain = SharedStages(SessionContext(camera=CAMERA, marker=MARKER)).process(tick(0, _reencoded(frame), 1, new=True))
    assert plain.in_view
    for orientation in (3, 6, 8):
        stages = SharedStages(SessionContext(camera=CAMERA, marker=MARKER))
        obs = stages.process(tick(0, _reencoded(frame, orientation), 1, new=True))
        assert obs.in_view and obs.marker.T_dvio_controller.allclose(plain.marker.T_dvio_controller, atol=0), orientation
    stages = SharedStages(SessionContext(camera=CAMERA, marker=MARKER))
    obs = stages.process(tick(0, _reencoded(frame, size=(1280, 960)), 1, new=True))
    assert not obs.in_view
    assert (stages.frames_decoded, stages.frames_undecodable, stages.frames_wrong_size) == (1, 0, 1)
    assert stages.wrong_size == "1280x960 px, not the calibration's 640x480"


def test_detections_message():
    stages = SharedStages(SessionContext(camera=CAMERA, marker=MARKER))
    obs = stages.process(tick(0, jpeg(T_CAMERA_MARKER), 123_456_789, new=True))
    msg = detections_message(obs)
    assert msg.frame_id == Frame.DISPLAY_CAMERA and msg.timestamp.ToNanoseconds() == 123_456_789
    (det,) = msg.detections
    assert det.id == 7 and len(det.corners_px) == 8
    np.testing.assert_allclose(np.reshape(det.corners_px, (4, 2)), obs.marker.corners_px)
    assert codec.pose_of(det.pose_in_camera).allclose(obs.marker.T_camera_marker, atol=1e-9)
    assert codec.pose_of(det.controller_in_display_vio).allclose(obs.marker.T_dvio_controller, atol=1e-9)
    empty = detections_message(stages.process(tick(1, jpeg(None), 200, new=True)))
    assert len(empty.detections) == 0


def test_all_trackers_step_on_one_observation():
    stages = SharedStages(SessionContext(camera=CAMERA, marker=MARKER))
    trackers = make_trackers("all")
    obs = stages.process(tick(0, jpeg(T_CAMERA_MARKER), 1, new=True))
    poses = {t.name: t.step(obs) for t in trackers}
    assert poses["T1"].allclose(obs.T_dvio_controller_vio)
    for name in ("T4", "T5", "T6", "T7"):
        assert poses[name] is obs.marker.T_dvio_controller


def test_prefetch_gives_the_same_observations_as_process_alone():
    """The look-ahead decodes on one worker thread and recognises on another, in tick order: the same
    corners and poses to the bit as without it (the tracked crop depends on the previous frame), the same
    counters; close() stops both threads."""
    import threading

    before = set(threading.enumerate())

    near = [looking_at(0.3 + 0.01 * k, 30 - k, 40 + k, roll_deg=15) for k in range(4)]
    ticks = [tick(0, jpeg(near[0]), 1_000, new=True), tick(1, jpeg(near[0]), 1_000, new=False),
             tick(2, jpeg(near[1]), 2_000, new=True), tick(3, jpeg(None), 3_000, new=True),
             tick(4, jpeg(near[2]), 4_000, new=True), tick(5, jpeg(near[3]), 5_000, new=True),
             Tick(index=6, t_ns=350_000_000)]
    alone = SharedStages(SessionContext(camera=CAMERA, marker=MARKER))
    expected = [alone.process(t) for t in ticks]
    ahead = SharedStages(SessionContext(camera=CAMERA, marker=MARKER))
    try:
        for t in ticks:
            ahead.prefetch(t)
        got = [ahead.process(t) for t in ticks]
        started = set(threading.enumerate()) - before
        assert {t.name.rsplit("_", 1)[0] for t in started} >= {"phonepose-decode", "phonepose-recognition"}
    finally:
        ahead.close()
    assert not any(t.is_alive() for t in started)
    assert [o.in_view for o in got] == [o.in_view for o in expected] == [True, True, True, False, True, True, False]
    assert got[1].marker is got[0].marker                 # the reused frame's recognition, as without it
    for g, e in zip(got, expected, strict=True):
        if e.marker is not None:
            assert g.marker.corners_px.tobytes() == e.marker.corners_px.tobytes()
            assert g.marker.T_dvio_controller.as_matrix().tobytes() == e.marker.T_dvio_controller.as_matrix().tobytes()
    assert ahead.frames_decoded == alone.frames_decoded == 5
    assert ahead.recognizer.stats == alone.recognizer.stats
    assert alone.recognizer.stats["track-roi"] >= 2       # the crop around the last sighting was used


def test_prefetch_out_of_order_is_refused_and_reset_drains():
    stages = SharedStages(SessionContext(camera=CAMERA, marker=MARKER))
    try:
        t0, t1 = tick(0, jpeg(T_CAMERA_MARKER), 1_000, new=True), tick(1, jpeg(None), 2_000, new=True)
        stages.prefetch(t0)
        stages.prefetch(t1)
        with pytest.raises(RuntimeError, match="in the order they were prefetched"):
            stages.process(t1)
        stages.reset()                                      # drops what is still pending
        assert stages.process(t0).in_view                   # and works without the look-ahead again
    finally:
        stages.close()
