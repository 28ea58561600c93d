"""Static parts of the scene that the recorder's and the playback's Rerun output share."""

from __future__ import annotations

import numpy as np
import rerun as rr

from phonepose.geometry import Pose
from phonepose.pipeline.types import TaskPath, TaskTargets
from phonepose.viewer import entities as E
from phonepose.viewer.style import TASK_COLOR

IMAGE_PLANE_DISTANCE_M = 0.1   # how far in front of the camera the frustum draws the image
WORKING_DEPTH_M = 0.3          # where the phone is held in front of the display camera (26-37 cm)


def log_camera(rec: rr.RecordingStream, T_display_camera: Pose | None = None, K=None, width: int | None = None,
               height: int | None = None, image_plane_distance: float = IMAGE_PLANE_DISTANCE_M) -> None:
    """The display camera on the display body (static extrinsics) and its pinhole (static), its
    frustum drawn out to ``image_plane_distance``."""
    if T_display_camera is not None:
        rec.log(E.CAMERA, rr.Transform3D(translation=np.asarray(T_display_camera.translation, np.float32).reshape(3),
                                         quaternion=rr.Quaternion(xyzw=np.asarray(T_display_camera.quat_xyzw,
                                                                                  np.float32).reshape(4))),
                static=True)
    if K is not None and width is not None and height is not None:
        rec.log(E.IMAGE, rr.Pinhole(image_from_camera=np.asarray(K, np.float32).reshape(3, 3),
                                    resolution=[int(width), int(height)], camera_xyz=rr.ViewCoordinates.RDF,
                                    image_plane_distance=float(image_plane_distance)), static=True)


def log_task(rec: rr.RecordingStream, targets: TaskTargets | None = None, path: TaskPath | None = None) -> None:
    """Experiment 1's targets (cubes) or experiment 2's path (a closed line), static, in display_vio."""
    if targets is not None and len(targets.targets):
        centers = np.array([t.position for t in targets.targets], dtype=np.float32)
        quats = [rr.Quaternion(xyzw=list(t.orientation_xyzw)) for t in targets.targets]
        half = float(targets.cube_size_m or 0.02) / 2
        rec.log(E.TASK_TARGETS, rr.Boxes3D(centers=centers, half_sizes=[[half, half, half]] * len(centers),
                                           quaternions=quats, labels=[str(t.index) for t in targets.targets],
                                           colors=[TASK_COLOR]), static=True)
    if path is not None and len(path.waypoints):
        pts = np.array(path.waypoints, dtype=np.float32)
        if path.closed:
            pts = np.vstack([pts, pts[:1]])
        rec.log(E.TASK_PATH, rr.LineStrips3D([pts], colors=[TASK_COLOR], radii=0.0015,
                                             labels=[path.name or "path"]), static=True)


def log_body_marker(rec: rr.RecordingStream, path: str, label: str, color, radius: float = 0.006) -> None:
    """A dot labelled ``label`` at the origin of the (moving) entity ``path``, in its colour (static)."""
    rec.log(path, rr.Points3D([[0.0, 0.0, 0.0]], colors=[color], radii=[radius], labels=[label]), static=True)
