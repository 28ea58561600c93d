"""A minimal renderer of one marker seen by a pinhole camera, for tests and benchmarks.

This is deliberately small and independent of the simulator (phonepose/record/sim): it exists
so that marker recognition can be checked against exactly known corners and poses. The image
is rendered ``supersample`` times larger with ``warpPerspective`` and box-filtered down with
``INTER_AREA``, so pixels integrate the scene as a sensor would; corners are then exact in
OpenCV's pixel-centre convention (pixel ``i`` covers ``[i - 0.5, i + 0.5]``).
Lens distortion (plumb_bob) is added by :func:`render_marker` when ``camera.D`` is non-zero: the
scene is rendered through the pinhole part and remapped, every output pixel sampling where its
undistorted ray lands.
"""

from __future__ import annotations

import cv2
import numpy as np

from phonepose.geometry import Pose
from phonepose.pipeline.markers import aruco_dictionary, marker_object_points
from phonepose.pipeline.types import CameraModel, MarkerModel


def pinhole_camera(f: float = 500.0, width: int = 640, height: int = 480,
                   T_display_camera: Pose | None = None) -> CameraModel:
    K = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
    return CameraModel(K=K, D=np.zeros(5), width=width, height=height,
                       T_display_camera=T_display_camera if T_display_camera is not None else Pose.identity())


def marker_texture(marker: MarkerModel, px_per_module: int = 80, quiet_modules: float = 1.5,
                   black: int = 20, white: int = 225) -> tuple[np.ndarray, int, int]:
    """(texture, side of the black square in texture px, quiet-zone width in px)."""
    dictionary = aruco_dictionary(marker.dictionary)
    modules = dictionary.markerSize + 2  # data bits + 1-bit black border each side
    side = modules * px_per_module
    img = cv2.aruco.generateImageMarker(dictionary, marker.id, side, borderBits=1)
    quiet = int(round(quiet_modules * px_per_module))
    img = cv2.copyMakeBorder(img, quiet, quiet, quiet, quiet, cv2.BORDER_CONSTANT, value=255)
    img = np.where(img > 127, white, black).astype(np.uint8)
    return img, side, quiet


def project_corners(camera: CameraModel, marker: MarkerModel, T_camera_marker: Pose) -> np.ndarray:
    """The exact image corners TL, TR, BR, BL (pixel centres, distorted by ``camera.D``)."""
    rvec, tvec = T_camera_marker.as_cv()
    pts, _ = cv2.projectPoints(marker_object_points(marker.size_m), rvec, tvec, camera.K, camera.D)
    return pts.reshape(4, 2)


def render_marker(camera: CameraModel, marker: MarkerModel, T_camera_marker: Pose, *, supersample: int = 4,
                  background: int = 110, blur_sigma: float = 0.0, noise_sigma: float = 0.0,
                  rng: np.random.Generator | None = None) -> np.ndarray:
    """A grayscale ``camera.height x camera.width`` image of the marker at ``T_camera_marker``."""
    if np.any(np.asarray(camera.D) != 0):
        pinhole = CameraModel(camera.K, np.zeros(5), camera.width, camera.height, camera.T_display_camera)
        ideal = render_marker(pinhole, marker, T_camera_marker, supersample=supersample, background=background)
        u, v = np.meshgrid(np.arange(camera.width, dtype=np.float64), np.arange(camera.height, dtype=np.float64))
        pts = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)
        und = cv2.undistortPoints(pts, camera.K, camera.D, None, None, camera.K, criteria).reshape(camera.height, camera.width, 2)
        img = cv2.remap(ideal, und[..., 0].astype(np.float32), und[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=background).astype(np.float64)
        return _finish(img, blur_sigma, noise_sigma, rng)
    texture, side, quiet = marker_texture(marker)
    L, s = marker.size_m, supersample
    # texture pixel centres -> marker plane (x, y, 1): texture edge coordinate = centre + 0.5
    tex_to_plane = np.array([[L / side, 0.0, (0.5 - quiet) * L / side - L / 2],
                             [0.0, -L / side, L / 2 - (0.5 - quiet) * L / side],
                             [0.0, 0.0, 1.0]])
    R = T_camera_marker.rotation.as_matrix()
    plane_to_image = camera.K @ np.column_stack([R[:, 0], R[:, 1], T_camera_marker.translation])
    # full-resolution pixel centre x  ->  supersampled pixel centre s(x + 0.5) - 0.5
    image_to_super = np.array([[s, 0.0, 0.5 * s - 0.5], [0.0, s, 0.5 * s - 0.5], [0.0, 0.0, 1.0]])
    H = image_to_super @ plane_to_image @ tex_to_plane
    big = cv2.warpPerspective(texture, H, (camera.width * s, camera.height * s), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=background)
    img = cv2.resize(big, (camera.width, camera.height), interpolation=cv2.INTER_AREA).astype(np.float64)
    return _finish(img, blur_sigma, noise_sigma, rng)


def _finish(img: np.ndarray, blur_sigma: float, noise_sigma: float, rng: np.random.Generator | None) -> np.ndarray:
    if blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma)
    if noise_sigma > 0:
        rng = rng if rng is not None else np.random.default_rng(0)
        img = img + rng.normal(0.0, noise_sigma, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def looking_at(distance_m: float, tilt_deg: float = 0.0, tilt_axis_deg: float = 0.0, roll_deg: float = 0.0,
               offset_xy_m=(0.0, 0.0)) -> Pose:
    """T_camera_marker: the marker ``distance_m`` ahead, facing the camera, tilted about an in-plane axis."""
    from scipy.spatial.transform import Rotation

    facing = Rotation.from_euler("x", 180, degrees=True)  # marker z points back at the camera
    axis = np.array([np.cos(np.radians(tilt_axis_deg)), np.sin(np.radians(tilt_axis_deg)), 0.0])
    tilt = Rotation.from_rotvec(np.radians(tilt_deg) * axis)
    roll = Rotation.from_euler("z", roll_deg, degrees=True)
    return Pose(facing * tilt * roll, np.array([offset_xy_m[0], offset_xy_m[1], distance_m]))


def encode_jpeg(gray: np.ndarray, quality: int = 90) -> bytes:
    ok, buf = cv2.imencode(".jpg", gray, [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return buf.tobytes()
