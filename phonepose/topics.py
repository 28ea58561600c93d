"""Every topic and frame name of a phonepose session (docs/format.md has what each topic carries).

This is the only module that spells topic and frame names; everything else imports them (through
phonepose.schemas.topics where the message types are needed too). It imports no message format,
so that the pipeline can name a topic without depending on the session's encoding.
"""

from __future__ import annotations


class Frame:
    """Coordinate frame ids (``frame_id`` fields, Rerun frame names)."""

    WORLD = "world"                    # motion capture
    GT_WORLD = "gt_world"              # a WebXR headset's stationary reference space, z up (phonepose/record/live/webxr.py)
    DISPLAY_VIO = "display_vio"        # the display device's VIO world; trackers report here
    CONTROLLER_VIO = "controller_vio"  # the controller's own VIO world
    DISPLAY = "display"                # display device body
    DISPLAY_CAMERA = "display_camera"  # OpenCV optical: x right, y down, z forward
    CONTROLLER = "controller"          # phone body of the controller
    MARKER = "marker"                  # the ArUco marker on the controller's screen
    ANCHOR = "anchor"                  # the shared (cloud) anchor


class Topic:
    """Topic names. ``TRACKER_POSE`` is a template: use :func:`tracker_pose_topic`."""

    CAMERA_IMAGE = "/display/camera/image"
    CAMERA_CALIBRATION = "/display/camera/calibration"
    CAMERA_EXTRINSICS = "/display/camera/extrinsics"   # display -> display_camera (static)
    DISPLAY_VIO_POSE = "/display/vio/pose"
    DISPLAY_ANCHOR = "/display/anchor"
    CONTROLLER_VIO_POSE = "/controller/vio/pose"
    CONTROLLER_ANCHOR = "/controller/anchor"
    CONTROLLER_IMU = "/controller/imu"
    CONTROLLER_MARKER = "/controller/marker"
    GT_CONTROLLER_POSE = "/gt/controller/pose"
    GT_DISPLAY_POSE = "/gt/display/pose"
    GT_BOARD_CONTROLLER_POSE = "/gt/board_controller/pose"   # a headset's other controller (the paper's R-sensor)
    GT_HEADSET_POSE = "/gt/headset/pose"                       # a headset's viewer
    GT_CALIBRATION = "/gt/calibration"                 # world -> display_vio
    CALIBRATION_EVENTS = "/events/calibration"
    EXPERIMENT_TARGETS = "/experiment/targets"
    EXPERIMENT_PATH = "/experiment/path"
    SESSION_INFO = "/session/info"
    LOG = "/log"
    # the frame tree (phonepose.viewer.frames): each topic places its child frame in its parent
    TF_DISPLAY = "/tf/display"                         # display_vio -> display (from /display/vio/pose)
    TF_CONTROLLER_VIO = "/tf/controller_vio"           # display_vio -> controller_vio (from the two anchors)
    TF_CONTROLLER = "/tf/controller"                   # controller_vio -> controller (from /controller/vio/pose)
    TF_MARKER = "/tf/marker"                           # controller -> marker (from /controller/marker, static)
    CONTROLLER_MARKER_OUTLINE = "/controller/marker/outline"   # the marker square as points, in frame marker
    CAMERA_FRUSTUM = "/display/camera/frustum"         # the camera's view as points, in frame display_camera
    # playback output
    PIPELINE_MARKERS = "/pipeline/markers"
    PIPELINE_MARKER_ANNOTATIONS = "/pipeline/markers/annotations"   # the same detections for Foxglove's Image panel
    TRACKER_POSE = "/trackers/{name}/pose"
    TF_TRACKERS = "/tf/trackers"                       # display_vio -> tracker/<name>: every estimate as a frame


def tracker_pose_topic(name: str) -> str:
    return Topic.TRACKER_POSE.format(name=name)


def tracker_frame(name: str) -> str:
    """The frame of tracker ``name``'s estimate on ``/tf/trackers`` (child of display_vio)."""
    return f"tracker/{name}"
