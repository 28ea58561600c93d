"""The static part of the simulated world (paper Fig. 8): frames, camera, display, anchor, phone.

Conventions
-----------
- ``world`` (motion capture), ``display_vio``, ``controller_vio`` and ``anchor`` are gravity
  aligned with **z up**; gravity is ``(0, 0, -9.81)`` in each of them.
- Phone bodies (``display``, ``controller``): x right, y up (portrait), z out of the screen
  (Android sensor convention). The display camera is the back camera: it looks along -z.
- ``display_camera`` is OpenCV optical (x right, y down, z forward).
- ``marker`` (on the controller's screen): x right, y up, z out of the screen, its origin at the
  centre of the black square, as ``SOLVEPNP_IPPE_SQUARE`` expects.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.geometry import Pose
from phonepose.record.sim.config import SimConfig

GRAVITY = 9.80665
GRAVITY_WORLD = np.array([0.0, 0.0, -GRAVITY])

WIDTH, HEIGHT = 640, 480

# Phone dimensions (a typical 6" phone) and where the marker sits on its screen.
PHONE_WIDTH_M = 0.075
PHONE_HEIGHT_M = 0.155
PHONE_THICKNESS_M = 0.008
SCREEN_MARGIN_M = 0.004            # bezel
MARKER_CENTER_IN_BODY = np.array([0.0, 0.02, PHONE_THICKNESS_M / 2])

# The display camera on the display phone's body: back camera near the top left, optical axes
# x = body x, y = -body y, z = -body z.
T_DISPLAY_CAMERA = Pose(Rotation.from_matrix(np.diag([1.0, -1.0, -1.0])), np.array([-0.02, 0.06, -0.004]))

DISPLAY_HEIGHT_M = 1.3             # tripod height of the display phone in the mocap world


@dataclass(frozen=True)
class CameraIntrinsics:
    K: np.ndarray        # (3, 3)
    D: np.ndarray        # (5,) k1 k2 p1 p2 k3 (OpenCV plumb_bob order)
    width: int = WIDTH
    height: int = HEIGHT

    @classmethod
    def from_config(cls, cfg: SimConfig) -> CameraIntrinsics:
        c = cfg.camera
        # Principal point at the image centre in OpenCV's pixel-centre convention.
        K = np.array([[c.fx, 0.0, (WIDTH - 1) / 2], [0.0, c.fy, (HEIGHT - 1) / 2], [0.0, 0.0, 1.0]])
        return cls(K=K, D=np.array([c.k1, c.k2, c.p1, c.p2, c.k3]))

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Distorted pixel coordinates (N, 2) of points (N, 3) in display_camera (z > 0)."""
        pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 1, 3)
        px, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), self.K, self.D)
        return px.reshape(-1, 2)


def marker_pose_in_body() -> Pose:
    """T_controller_marker: the marker on the screen, axes aligned with the body."""
    return Pose(Rotation.identity(), MARKER_CENTER_IN_BODY.copy())


def marker_corners_in_marker(size_m: float) -> np.ndarray:
    """TL, TR, BR, BL of the black square in the marker frame (the IPPE_SQUARE layout)."""
    h = size_m / 2
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def yaw(deg: float) -> Rotation:
    return Rotation.from_euler("z", deg, degrees=True)


def random_unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def error_pose(rng: np.random.Generator, translation_m: float, yaw_deg: float, tilt_deg: float) -> Pose:
    """A fixed-size error: translation of the given magnitude in a random direction, rotation
    N(0, yaw) about z and N(0, tilt) about x and y (gravity keeps tilt small)."""
    t = random_unit(rng) * translation_m
    angles = rng.normal(size=3) * np.array([tilt_deg, tilt_deg, yaw_deg])
    return Pose(Rotation.from_euler("xyz", angles, degrees=True), t)


WORLD_UP = np.array([0.0, 0.0, 1.0])


def look_at_rotation(position: np.ndarray, target: np.ndarray, up: np.ndarray = WORLD_UP) -> Rotation:
    """Orientation of a phone body at ``position`` whose screen (+z) faces ``target``, upright (+y ~ up)."""
    z = target - position
    z = z / np.linalg.norm(z)
    x = np.cross(up, z)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return Rotation.from_matrix(np.column_stack([x, y, z]))


@dataclass(frozen=True)
class World:
    """Everything that does not move: true frames and the per-session fixed errors."""

    camera: CameraIntrinsics
    T_world_display: Pose          # the display phone on its tripod (true)
    T_world_dvio: Pose             # the display's VIO world (true)
    T_world_cvio: Pose             # the controller's VIO world (true)
    T_world_anchor: Pose           # the shared anchor (true)
    anchor_error_display: Pose     # T_anchor_true_anchor_resolved, display side
    anchor_error_controller: Pose  # same, controller side
    hand_eye: Pose                 # T_controller_mocapbody: mocap rigid body vs phone frame
    calibration_error: Pose        # /gt/calibration = T_world_dvio · calibration_error
    T_controller_marker: Pose

    @property
    def T_world_camera(self) -> Pose:
        return self.T_world_display @ T_DISPLAY_CAMERA

    @property
    def T_dvio_anchor_resolved(self) -> Pose:
        return self.T_world_dvio.inv() @ self.T_world_anchor @ self.anchor_error_display

    @property
    def T_cvio_anchor_resolved(self) -> Pose:
        return self.T_world_cvio.inv() @ self.T_world_anchor @ self.anchor_error_controller


def build_world(cfg: SimConfig, rng_for) -> World:
    """``rng_for(name)`` returns the named random sub-stream."""
    rng = rng_for("world")
    tilt = np.deg2rad(cfg.camera.tilt_down_deg)
    forward = np.array([0.0, np.cos(tilt), -np.sin(tilt)])   # camera looks along +y, tilted down
    z_body = -forward
    x_body = np.array([1.0, 0.0, 0.0])
    y_body = np.cross(z_body, x_body)
    T_world_display = Pose(Rotation.from_matrix(np.column_stack([x_body, y_body, z_body])),
                           np.array([0.0, 0.0, DISPLAY_HEIGHT_M]))
    # VIO worlds start where each phone started its session: gravity aligned, arbitrary yaw.
    T_world_dvio = Pose(yaw(rng.uniform(-180, 180)), np.array([*rng.uniform(-1.0, 1.0, 2), rng.uniform(0.8, 1.5)]))
    T_world_cvio = Pose(yaw(rng.uniform(-180, 180)), np.array([*rng.uniform(-1.0, 1.0, 2), rng.uniform(0.8, 1.5)]))
    # The anchor lies on a table in front of the display, gravity aligned.
    horiz = np.array([0.0, 1.0, 0.0])
    anchor_pos = T_world_display.translation + horiz * cfg.anchor.distance_m + np.array([rng.uniform(-0.2, 0.2), 0, -0.5])
    T_world_anchor = Pose(yaw(rng.uniform(-180, 180)), anchor_pos)
    a = cfg.anchor
    anchor_error_display = error_pose(rng_for("anchor_display"), a.display_translation_m, a.display_yaw_deg,
                                      a.display_tilt_deg)
    anchor_error_controller = error_pose(rng_for("anchor_controller"), a.controller_translation_m,
                                         a.controller_yaw_deg, a.controller_tilt_deg)
    r = rng_for("hand_eye")
    m = cfg.mocap
    hand_eye = Pose(Rotation.from_rotvec(random_unit(r) * np.deg2rad(m.hand_eye_rotation_deg)),
                    random_unit(r) * m.hand_eye_translation_m)
    r = rng_for("mocap_calibration")
    calibration_error = Pose(Rotation.from_rotvec(random_unit(r) * np.deg2rad(m.calibration_rotation_deg)),
                             random_unit(r) * m.calibration_translation_m)
    return World(camera=CameraIntrinsics.from_config(cfg), T_world_display=T_world_display,
                 T_world_dvio=T_world_dvio, T_world_cvio=T_world_cvio, T_world_anchor=T_world_anchor,
                 anchor_error_display=anchor_error_display, anchor_error_controller=anchor_error_controller,
                 hand_eye=hand_eye, calibration_error=calibration_error, T_controller_marker=marker_pose_in_body())


def marker_in_view(world: World, T_camera_controller: Pose, size_m: float, margin_px: float = 3.0,
                   max_view_angle_deg: float = 70.0) -> np.ndarray:
    """Whether the whole marker is inside the image and faces the camera, for a stack of poses."""
    T_cm = T_camera_controller @ world.T_controller_marker
    corners = marker_corners_in_marker(size_m)
    n = len(T_cm) if not T_cm.single else 1
    R = T_cm.rotation.as_matrix().reshape(n, 3, 3)
    t = T_cm.translation.reshape(n, 3)
    pts = np.einsum("nij,kj->nki", R, corners) + t[:, None, :]          # (n, 4, 3)
    ok = np.all(pts[..., 2] > 0.05, axis=1)
    normal = R[:, :, 2]
    to_cam = -t / np.linalg.norm(t, axis=1, keepdims=True)
    ok &= np.einsum("ni,ni->n", normal, to_cam) > np.cos(np.deg2rad(max_view_angle_deg))
    px = np.full((n, 4, 2), -1e6)
    if ok.any():
        safe = pts[ok].copy()
        px[ok] = world.camera.project(safe.reshape(-1, 3)).reshape(-1, 4, 2)
    inside = (px[..., 0] >= margin_px) & (px[..., 0] <= WIDTH - 1 - margin_px) & \
             (px[..., 1] >= margin_px) & (px[..., 1] <= HEIGHT - 1 - margin_px)
    # Points far outside the image can wrap around under radial distortion: require that the
    # undistorted projection is inside too.
    und = np.full((n, 4, 2), -1e6)
    if ok.any():
        p = pts[ok]
        und[ok] = (p[..., :2] / p[..., 2:3]) * np.array([world.camera.K[0, 0], world.camera.K[1, 1]]) + \
            world.camera.K[:2, 2]
    m2 = 40.0
    inside &= (und[..., 0] > -m2) & (und[..., 0] < WIDTH + m2) & (und[..., 1] > -m2) & (und[..., 1] < HEIGHT + m2)
    return ok & np.all(inside, axis=1)
