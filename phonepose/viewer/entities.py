"""The one Rerun entity tree of phonepose, shared by ``record --rerun`` and ``playback --rerun``.

``/world`` is display_vio in both (gravity-aligned, z up: ``RIGHT_HAND_Z_UP``): the frame the
trackers report in and the only one every session has (the motion-capture world needs
``/gt/calibration``; the recorder maps mocap poses into display_vio through it).

    /world                                  view coordinates (static)
    /world/display                          display body pose from its VIO (Transform3D)
    /world/display/camera                   T_display_camera (static)
    /world/display/camera/image             Pinhole (static), EncodedImage (the recorded JPEG bytes)
    /world/display/camera/image/marker      playback: the recognised marker (LineStrips2D, id as label) and
                                            its diagnostics as data (reprojection error, ambiguity ratio)
    /world/controller                       record: controller VIO pose mapped through the anchors
    /world/gt/controller                    ground-truth controller pose (record: mocap; playback: the
                                            associated GT); /world/gt/display: mocap display pose (record)
    /world/gt/trajectory/{NNNN,open}        playback: GT so far
    /world/trackers/<name>/pose             playback: a tracker's estimate (Transform3D, axes, labelled dot)
    /world/trackers/<name>/trajectory/...   playback: its trajectory so far
    /world/task/targets | /world/task/path  experiment 1 targets (Boxes3D) or experiment 2 path (static)
    /errors/position_cm/<name>              playback: position error against GT, cm (Scalars)
    /errors/rotation_deg/<name>             playback: rotation error against GT, degrees (Scalars)
    /status/task                            playback: calibration / task / after (StateChange)
    /status/marker                          playback: marker in view / out of view (StateChange)
    /metrics                                playback: the metrics table and the colour legend (TextDocument, static)
    /imu/gyro, /imu/accel                   record: controller IMU (Scalars, 3 series each)

Timelines: ``time`` (timestamp on the display's clock) in both; in playback also ``session_time``
(duration since the session's first message, the default) and ``tick`` (sequence).
"""

from __future__ import annotations

WORLD = "/world"
DISPLAY = "/world/display"
CAMERA = "/world/display/camera"
IMAGE = "/world/display/camera/image"
MARKER = "/world/display/camera/image/marker"
CONTROLLER_VIO = "/world/controller"
GT = "/world/gt"
GT_CONTROLLER = "/world/gt/controller"
GT_DISPLAY = "/world/gt/display"
GT_TRAJECTORY = "/world/gt/trajectory"
TRACKERS = "/world/trackers"
TASK = "/world/task"
TASK_TARGETS = "/world/task/targets"
TASK_PATH = "/world/task/path"
ERRORS = "/errors"
POSITION_ERRORS = "/errors/position_cm"
ROTATION_ERRORS = "/errors/rotation_deg"
STATUS = "/status"
STATUS_TASK = "/status/task"
STATUS_MARKER = "/status/marker"
METRICS = "/metrics"
IMU_GYRO = "/imu/gyro"
IMU_ACCEL = "/imu/accel"

TIME = "time"      # timestamp timeline, the display's clock
TICK = "tick"      # sequence timeline, the playback tick index
SESSION_TIME = "session_time"   # duration timeline: seconds since the session's first message (playback)


def tracker_pose(name: str) -> str:
    return f"{TRACKERS}/{name}/pose"


def tracker_trajectory(name: str) -> str:
    return f"{TRACKERS}/{name}/trajectory"


def position_error(name: str) -> str:
    return f"{POSITION_ERRORS}/{name}"


def rotation_error(name: str) -> str:
    return f"{ROTATION_ERRORS}/{name}"
