"""Foxglove's own reader decodes what phonepose writes: @mcap/core (npm) reads the session and
trackers.mcap, protobufjs decodes every new channel from the schema stored in the file
(tests/js/read_mcap.mjs; `npm ci --prefix tests/js` installs them, .ci/run does)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from phonepose.schemas.topics import Frame, Topic, tracker_pose_topic
from phonepose.topics import tracker_frame

JS = Path(__file__).parent / "js"
NODE = shutil.which("node")

pytestmark = pytest.mark.skipif(NODE is None or not (JS / "node_modules" / "@mcap" / "core").is_dir(),
                                reason="node and tests/js/node_modules (npm ci --prefix tests/js) are needed")


def read_with_mcap_core(path: Path, *topics: str) -> dict:
    r = subprocess.run([NODE, str(JS / "read_mcap.mjs"), str(path), *topics], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


@pytest.mark.slow
def test_mcap_core_decodes_the_frame_tree_and_the_image_annotations(tmp_path):
    from phonepose.playback.engine import run_playback
    from phonepose.record.sim import default_config, record_sim

    session = tmp_path / "s.mcap"
    record_sim(session, scenario="exp2", path="TRI1", seed=0, config=default_config().replace(camera=dict(rate_hz=4.0)))
    got = read_with_mcap_core(session, Topic.TF_DISPLAY, Topic.TF_CONTROLLER, Topic.TF_CONTROLLER_VIO, Topic.TF_MARKER,
                              Topic.CONTROLLER_MARKER_OUTLINE, Topic.CAMERA_FRUSTUM, Topic.DISPLAY_VIO_POSE,
                              Topic.CONTROLLER_VIO_POSE)
    edges = {topic: (got[topic]["first"]["parent_frame_id"], got[topic]["first"]["child_frame_id"])
             for topic in (Topic.TF_DISPLAY, Topic.TF_CONTROLLER, Topic.TF_CONTROLLER_VIO, Topic.TF_MARKER)}
    assert edges == {Topic.TF_DISPLAY: (Frame.DISPLAY_VIO, Frame.DISPLAY),
                     Topic.TF_CONTROLLER: (Frame.CONTROLLER_VIO, Frame.CONTROLLER),
                     Topic.TF_CONTROLLER_VIO: (Frame.DISPLAY_VIO, Frame.CONTROLLER_VIO),
                     Topic.TF_MARKER: (Frame.CONTROLLER, Frame.MARKER)}
    # one transform per pose sample, carrying the pose itself
    assert got[Topic.TF_DISPLAY]["count"] == got[Topic.DISPLAY_VIO_POSE]["count"] > 0
    assert got[Topic.TF_CONTROLLER]["count"] == got[Topic.CONTROLLER_VIO_POSE]["count"]
    pose = got[Topic.DISPLAY_VIO_POSE]["first"]["pose"]["position"]
    tf = got[Topic.TF_DISPLAY]["first"]["translation"]
    assert all(tf.get(k, 0.0) == pytest.approx(pose.get(k, 0.0)) for k in "xyz")
    for topic, frame in ((Topic.CONTROLLER_MARKER_OUTLINE, Frame.MARKER), (Topic.CAMERA_FRUSTUM, Frame.DISPLAY_CAMERA)):
        cloud = got[topic]["first"]
        assert got[topic]["schema"] == "foxglove.PointCloud" and cloud["frame_id"] == frame
        assert [f["name"] for f in cloud["fields"]] == ["x", "y", "z"] and cloud["point_stride"] == 12

    out = tmp_path / "pb"
    trackers = ["T1", "T7", "T8"]
    run_playback(session, trackers=trackers, out_dir=out)
    got = read_with_mcap_core(out / "trackers.mcap", Topic.PIPELINE_MARKERS, Topic.PIPELINE_MARKER_ANNOTATIONS,
                              Topic.TF_TRACKERS, *(tracker_pose_topic(n) for n in trackers))
    # every tracker's estimate is a frame of its own under display_vio, one transform per pose message
    tf = got[Topic.TF_TRACKERS]
    assert tf["schema"] == "foxglove.FrameTransform" and tf["first"]["parent_frame_id"] == Frame.DISPLAY_VIO
    assert tf["children"] == {tracker_frame(n): got[tracker_pose_topic(n)]["count"] for n in trackers}
    assert all(c > 0 for c in tf["children"].values())
    ann, det = got[Topic.PIPELINE_MARKER_ANNOTATIONS], got[Topic.PIPELINE_MARKERS]
    assert ann["schema"] == "foxglove.ImageAnnotations" and ann["count"] == det["count"] > 0
    from phonepose.session import SessionReader

    with SessionReader(out / "trackers.mcap") as r:
        pairs = list(zip(r.messages([Topic.PIPELINE_MARKERS]), r.messages([Topic.PIPELINE_MARKER_ANNOTATIONS]), strict=True))
    seen = [(d.msg, a.msg) for d, a in pairs if d.msg.detections]
    assert seen
    d, a = seen[0]
    assert a.timestamp == d.timestamp                            # matched to the image by its capture time
    loop = a.points[0]
    assert [v for p in loop.points for v in (p.x, p.y)] == pytest.approx(list(d.detections[0].corners_px))
    assert a.texts[0].text.startswith(f"id {d.detections[0].id}: ")
