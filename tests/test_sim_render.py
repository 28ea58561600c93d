"""Rendered camera frames: the marker is where the geometry says, and detectable exactly when in view."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from phonepose.geometry import Pose
from phonepose.record.sim import SimSession, default_config
from phonepose.record.sim.world import HEIGHT, WIDTH, look_at_rotation, marker_corners_in_marker

CLEAN = dict(render=dict(noise_sigma_dn=0.0, jpeg_quality=100, brightness_variation=0.0, motion_blur=False))


def _detector(refine: int = cv2.aruco.CORNER_REFINE_NONE) -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = refine
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), params)


def _decode(jpeg: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)


def _find(det, img, marker_id=7):
    corners, ids, _ = det.detectMarkers(img)
    if ids is None or marker_id not in ids.ravel():
        return None
    return corners[list(ids.ravel()).index(marker_id)].reshape(4, 2)


def _clearly(s: SimSession):
    """Frames clearly in view (whole marker >= 15 px inside, <= 55 deg from facing) and clearly
    out of view (marker centre outside the image, or the screen facing away)."""
    size = s.cfg.marker.size_m
    corners = np.array([s.marker_corners_px(i) for i in range(len(s.t_cam))])
    T_cm = s.T_cam_ctrl @ s.world.T_controller_marker
    normal = T_cm.rotation.as_matrix()[:, :, 2]
    to_cam = -T_cm.translation / np.linalg.norm(T_cm.translation, axis=1, keepdims=True)
    cos = np.einsum("ni,ni->n", normal, to_cam)
    inside = np.all((corners[..., 0] > 15) & (corners[..., 0] < WIDTH - 16) &
                    (corners[..., 1] > 15) & (corners[..., 1] < HEIGHT - 16), axis=1)
    und = T_cm.translation[:, :2] / T_cm.translation[:, 2:3] * np.diag(s.world.camera.K)[:2] + s.world.camera.K[:2, 2]
    centre_out = (und[:, 0] < 0) | (und[:, 0] > WIDTH - 1) | (und[:, 1] < 0) | (und[:, 1] > HEIGHT - 1)
    assert size > 0
    return inside & (cos > np.cos(np.deg2rad(55))), centre_out | (cos < 0)


@pytest.fixture(scope="module")
def tri2():
    return SimSession("exp2", "TRI2", 1, seed=0)


@pytest.fixture(scope="module")
def tri2_clean():
    return SimSession("exp2", "TRI2", 1, seed=0, config=default_config().replace(**CLEAN))


def test_marker_detected_in_view_and_not_out_of_view(tri2):
    s = tri2
    clearly_in, clearly_out = _clearly(s)
    assert clearly_in.sum() > 200 and clearly_out.sum() > 20
    det = _detector()
    rng = np.random.default_rng(0)
    idx = np.arange(0, len(s.t_cam), 2)
    found = np.array([_find(det, _decode(s.renderer.encode(s.render_frame(int(i), rng)))) is not None for i in idx])
    assert found[clearly_in[idx]].mean() >= 0.97
    assert not found[clearly_out[idx]].any()
    # and the simulator's own in-view flag agrees with detection on nearly every frame
    assert np.mean(found == s.in_view[idx]) > 0.97


def test_true_corners_land_on_detected_corners_within_1px_on_clean_frames(tri2_clean):
    s = tri2_clean
    clearly_in, _ = _clearly(s)
    det = _detector(cv2.aruco.CORNER_REFINE_SUBPIX)
    plain = _detector()
    rng = np.random.default_rng(0)
    errs, plain_errs = [], []
    for i in np.nonzero(clearly_in)[0][::3]:
        img = _decode(s.renderer.encode(s.render_frame(int(i), rng)))
        gt = s.marker_corners_px(int(i))
        c = _find(det, img)
        assert c is not None
        errs.append(np.abs(c - gt).max())
        c = _find(plain, img)
        plain_errs.append(np.linalg.norm(c - gt, axis=1).mean())
    assert len(errs) > 50
    assert max(errs) < 1.0
    assert np.mean(errs) < 0.35
    # without refinement OpenCV returns integer corners on the outermost black pixels (0.5 px inward)
    assert np.mean(plain_errs) < 1.0


def test_lens_distortion_is_rendered():
    """With distortion on, the detected corners follow the distorted projection, not the pinhole one."""
    cfg = default_config().replace(**CLEAN, camera=dict(k1=-0.25, k2=0.08))
    s = SimSession("exp2", "REC1", 1, seed=0, config=cfg)
    det = _detector(cv2.aruco.CORNER_REFINE_SUBPIX)
    rng = np.random.default_rng(0)
    pin_worse = 0
    checked = 0
    for i in range(0, len(s.t_cam), 7):
        if not s.in_view[i]:
            continue
        c = _find(det, _decode(s.renderer.encode(s.render_frame(i, rng))))
        if c is None:
            continue
        gt = s.marker_corners_px(i)
        T_cm = s.T_cam_ctrl[i] @ s.world.T_controller_marker
        p = T_cm.apply(marker_corners_in_marker(0.05))
        pinhole = p[:, :2] / p[:, 2:3] * np.diag(s.world.camera.K)[:2] + s.world.camera.K[:2, 2]
        assert np.abs(c - gt).max() < 1.0
        pin_worse += np.abs(c - pinhole).max() > 1.5
        checked += 1
    assert checked > 20 and pin_worse > checked // 3


def test_marker_facing_away_is_not_detected(tri2_clean):
    s = tri2_clean
    r = s.renderer
    det = _detector()
    pos = np.array([0.0, 0.0, 0.3])
    facing = look_at_rotation(pos, np.zeros(3), up=np.array([0.0, -1.0, 0.0]))
    rng = np.random.default_rng(0)
    seen = _find(det, _decode(r.encode(r.render(Pose(facing, pos), None, 1.0, rng))))
    away = _find(det, _decode(r.encode(r.render(Pose(facing * Rotation.from_euler("y", 180, degrees=True), pos),
                                                None, 1.0, rng))))
    assert seen is not None and away is None


def test_motion_blur_smears_a_fast_marker(tri2):
    s = tri2
    speeds = np.hypot(*s.blur.T)
    i = int(np.argmax(np.where(s.in_view, speeds, 0)))
    assert speeds[i] > 2.0
    rng = np.random.default_rng(0)
    blurred = s.render_frame(i, rng).astype(float)
    sharp = s.renderer.render(s.T_cam_ctrl[i], None, float(s.gain[i]), rng).astype(float)
    # blur removes sharp edges: the mean Laplacian drops
    def sharpness(im):
        return np.abs(cv2.Laplacian(im[..., 1], cv2.CV_64F)).mean()

    assert sharpness(blurred) < 0.97 * sharpness(sharp)
