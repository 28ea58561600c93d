"""Marker recognition: the controller's on-screen ArUco marker -> its pose in display_vio.

Choices (measured; see docs/pipeline.md and ../shared/docs/notes/markers.md §1.4, §3.3, §4):

- Corners without OpenCV's half-pixel biases. CONTOUR refinement fits each edge line through
  the outermost *black pixel centres*, 0.5 px inside the true edge, so the marker looks smaller
  and farther away; we push every fitted edge 0.5 px outward and re-intersect. APRILTAG
  refinement returns the whole quad shifted by +0.5 px in x and y (AprilTag's pixel-centre
  convention); we subtract 0.5 px.
- Two stages, so that the accurate but slow APRILTAG refinement (docs/performance.md#marker-recognition)
  only ever runs on a small crop: a fast CONTOUR detection on the full frame finds the
  marker, then the APRILTAG detector runs on a crop around it; if the crop fails, the CONTOUR
  corners (+0.5 px edge fix) are used. When the marker was seen in the previous frame, the
  APRILTAG crop is taken around that position first and the full-frame pass is skipped.
- The APRILTAG crop first runs with a minimum tile contrast of ``APRILTAG_MIN_CONTRAST`` grey levels
  (OpenCV's default 5 turns the sensor noise of a flat background into thousands of tiny clusters,
  each fitted as a candidate quad: ~3/4 of the crop's cost), and again with the default only if the
  expected marker is not found that way; see the constant.
- Only the expected id counts; every other id is ignored.
- Pose: ``solvePnPGeneric(IPPE_SQUARE)`` gives both planar solutions; take the best if its
  reprojection error is clearly lower (ratio > 4), else the one whose rotation is closer to the
  previous frame's; then ``solvePnPRefineLM``.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import cv2
import numpy as np

from phonepose.errors import ConfigError
from phonepose.geometry import Pose
from phonepose.pipeline.types import CameraModel, MarkerModel, MarkerObservation

# Above this ratio of the two IPPE reprojection errors the better solution is trusted outright
# (IPPE authors' likelihood-ratio idea; notes §4 use ~4).
AMBIGUITY_RATIO = 4.0
# The previous rotation is only a useful tie-breaker if it is recent.
CONTINUITY_MAX_GAP_NS = 500_000_000
# Crop margin (fraction of the marker's bounding-box side) around a fresh full-frame detection,
# and the larger one around last frame's position (the marker may have moved since; if it moved
# out of the crop the full-frame pass runs). APRILTAG's cost grows with the crop area
# (docs/performance.md#marker-recognition).
DETECTION_MARGIN = 0.35
TRACKING_MARGIN = 0.5
MIN_MARGIN_PX = 12
# AprilTag's quad detector classifies a pixel black or white only where the grey levels of its
# tile's 3x3-tile neighbourhood (12x12 px) span at least aprilTagMinWhiteBlackDiff; elsewhere it is
# left out of every component. At OpenCV's default (5) the noise of flat image areas becomes
# many tiny components whose boundaries are each fitted as a candidate quad. A marker's own
# edge spans the black-to-white range of the screen (~190 levels in the simulator's frames), so every
# tile along it is classified the same at 30 and the marker's quad is fitted from the same pixels
# (same corners as the default; docs/performance.md#marker-recognition). A crop where the marker is
# not found this way (a dim or washed-out screen) is searched again with the default, so the higher
# threshold never loses a marker the default finds.
APRILTAG_MIN_CONTRAST = 30
# AprilTag convention leaks a +0.5 px shift; CONTOUR edges sit 0.5 px inside the true edge.
APRILTAG_SHIFT_PX = 0.5
CONTOUR_EDGE_OFFSET_PX = 0.5


def aruco_dictionary_names() -> list[str]:
    """The names of OpenCV's predefined dictionaries (``DICT_4X4_50`` ...), sorted."""
    return sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))


def aruco_dictionary(name: str) -> cv2.aruco.Dictionary:
    """OpenCV's predefined dictionary by name (``DICT_4X4_50`` ...); ConfigError if unknown."""
    allowed = aruco_dictionary_names()
    if name not in allowed:
        raise ConfigError(f"unknown marker dictionary {name!r}; allowed: {', '.join(allowed)}")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


def marker_object_points(size_m: float) -> np.ndarray:
    """TL, TR, BR, BL of the black square in the marker frame: the layout IPPE_SQUARE requires."""
    h = size_m / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]], dtype=np.float64)


def push_edges_outward(corners: np.ndarray, offset_px: float = CONTOUR_EDGE_OFFSET_PX) -> np.ndarray:
    """Move each side of a convex quad ``offset_px`` outward and re-intersect adjacent sides."""
    c = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    centre = c.mean(axis=0)
    normals, offsets = [], []
    for i in range(4):
        p, q = c[i], c[(i + 1) % 4]
        d = q - p
        n = np.array([-d[1], d[0]]) / np.linalg.norm(d)
        if np.dot(n, p - centre) < 0:  # point the normal away from the quad
            n = -n
        normals.append(n)
        offsets.append(np.dot(n, p) + offset_px)
    out = np.empty((4, 2))
    for i in range(4):  # corner i joins side i-1 (c[i-1] -> c[i]) and side i (c[i] -> c[i+1])
        a = np.array([normals[i - 1], normals[i]])
        out[i] = np.linalg.solve(a, np.array([offsets[i - 1], offsets[i]]))
    return out


def reprojection_rms_px(projected: np.ndarray, corners: np.ndarray) -> float:
    """``sqrt(mean(sum((projected - corners)², axis=1)))`` of the four corners, on Python floats in
    numpy's order of operations (``d * d``, the sums left to right: the same bits, held to numpy's
    by tests/test_markers.py); the three numpy calls cost ~15x more on four points, once per frame."""
    p = np.asarray(projected, dtype=np.float64).reshape(-1).tolist()
    c = np.asarray(corners, dtype=np.float64).reshape(-1).tolist()
    d = [p[i] - c[i] for i in range(8)]
    sq = [d[i] * d[i] + d[i + 1] * d[i + 1] for i in (0, 2, 4, 6)]
    return math.sqrt((sq[0] + sq[1] + sq[2] + sq[3]) / 4)


@dataclass
class _Detection:
    corners: np.ndarray   # (4, 2) float64, full-frame pixel coordinates, bias-corrected
    stage: str            # "track-roi" | "roi" | "contour"


@dataclass
class MarkerRecognizer:
    """Recognises one marker (dictionary, id, size from the session) and estimates its pose.

    Stateful only for continuity (previous position and rotation); ``reset()`` forgets both.
    """

    camera: CameraModel
    marker: MarkerModel
    stats: Counter = field(default_factory=Counter)  # how often each stage delivered the corners

    def __post_init__(self) -> None:
        dictionary = aruco_dictionary(self.marker.dictionary)
        fast = cv2.aruco.DetectorParameters()
        fast.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_CONTOUR
        accurate = cv2.aruco.DetectorParameters()
        accurate.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_APRILTAG
        # Built once, reused for every frame.
        self._fast = cv2.aruco.ArucoDetector(dictionary, fast)
        self._accurate_low_contrast = cv2.aruco.ArucoDetector(dictionary, accurate)
        accurate.aprilTagMinWhiteBlackDiff = APRILTAG_MIN_CONTRAST
        self._accurate = cv2.aruco.ArucoDetector(dictionary, accurate)
        self._object_points = marker_object_points(self.marker.size_m)
        self._K = np.asarray(self.camera.K, dtype=np.float64)
        self._D = np.asarray(self.camera.D, dtype=np.float64).reshape(-1)
        self._T_body_marker_inv = self.marker.T_body_marker.inv()
        self.reset()

    def reset(self) -> None:
        self._last_corners: np.ndarray | None = None      # set only if seen in the previous frame
        self._last_rotation: Pose | None = None
        self._last_seen_ns: int | None = None

    # ------------------------------------------------------------------ corners
    def _find_expected(self, detector: cv2.aruco.ArucoDetector, image: np.ndarray) -> np.ndarray | None:
        corners, ids, _ = detector.detectMarkers(image)
        if ids is None:
            return None
        for c, i in zip(corners, ids.reshape(-1), strict=True):
            if int(i) == self.marker.id:
                return c.reshape(4, 2).astype(np.float64)
        return None

    def _roi(self, corners: np.ndarray, margin: float, shape) -> tuple[int, int, int, int]:
        # on Python floats: the same numbers as numpy's min/max/floor here, at a tenth of the cost
        xs, ys = corners[:, 0].tolist(), corners[:, 1].tolist()
        lo_x, lo_y, hi_x, hi_y = min(xs), min(ys), max(xs), max(ys)
        pad = max(margin * max(hi_x - lo_x, hi_y - lo_y), MIN_MARGIN_PX)
        h, w = shape[:2]
        x0, y0 = max(math.floor(lo_x - pad), 0), max(math.floor(lo_y - pad), 0)
        x1, y1 = min(math.ceil(hi_x + pad) + 1, w), min(math.ceil(hi_y + pad) + 1, h)
        return x0, y0, x1, y1

    def _accurate_in_roi(self, gray: np.ndarray, around: np.ndarray, margin: float) -> np.ndarray | None:
        x0, y0, x1, y1 = self._roi(around, margin, gray.shape)
        crop = gray[y0:y1, x0:x1]
        found = self._find_expected(self._accurate, crop)
        if found is None:
            found = self._find_expected(self._accurate_low_contrast, crop)
        if found is None:
            return None
        return found + np.array([x0, y0]) - APRILTAG_SHIFT_PX

    def detect_corners(self, gray: np.ndarray) -> _Detection | None:
        """Bias-corrected corners (TL, TR, BR, BL) of the expected marker, or None."""
        if self._last_corners is not None:
            tracked = self._accurate_in_roi(gray, self._last_corners, TRACKING_MARGIN)
            if tracked is not None:
                return _Detection(tracked, "track-roi")
        coarse = self._find_expected(self._fast, gray)
        if coarse is None:
            return None
        refined = self._accurate_in_roi(gray, coarse, DETECTION_MARGIN)
        if refined is not None:
            return _Detection(refined, "roi")
        return _Detection(push_edges_outward(coarse), "contour")

    # ------------------------------------------------------------------ pose
    def estimate_pose(self, corners: np.ndarray) -> tuple[Pose, float, int, float] | None:
        """(T_camera_marker, RMS reprojection error px, chosen IPPE solution, ambiguity ratio), or None
        when PnP finds no solution (e.g. a calibration with absurd distortion)."""
        image_points = np.ascontiguousarray(corners, dtype=np.float64).reshape(4, 1, 2)
        n, rvecs, tvecs, errors = cv2.solvePnPGeneric(self._object_points, image_points, self._K, self._D,
                                                      flags=cv2.SOLVEPNP_IPPE_SQUARE)
        if not n:
            return None
        errors = np.asarray(errors, dtype=np.float64).reshape(-1)
        ratio = float(errors[1] / max(errors[0], 1e-12)) if n > 1 else float("inf")
        chosen = 0
        if n > 1 and ratio <= AMBIGUITY_RATIO and self._last_rotation is not None:
            # Near-frontal views: reprojection cannot tell the two apart; continuity can.
            angles = [Pose.from_cv(rvecs[k], tvecs[k]).angle_to(self._last_rotation) for k in range(n)]
            chosen = int(np.argmin(angles))
        rvec, tvec = cv2.solvePnPRefineLM(self._object_points, image_points, self._K, self._D,
                                          rvecs[chosen].copy(), tvecs[chosen].copy())
        projected, _ = cv2.projectPoints(self._object_points, rvec, tvec, self._K, self._D)
        rms = reprojection_rms_px(projected, corners)
        return Pose.from_cv(rvec, tvec), rms, chosen, ratio

    # ------------------------------------------------------------------ one frame
    def recognize(self, gray: np.ndarray, T_dvio_display: Pose | None = None,
                  t_ns: int | None = None) -> MarkerObservation | None:
        """The marker in this grayscale frame, or None if the expected id is not recognised.

        ``T_dvio_controller`` is filled when the display pose is given, else it is None.
        """
        recent = (self._last_seen_ns is not None and t_ns is not None
                  and 0 <= t_ns - self._last_seen_ns <= CONTINUITY_MAX_GAP_NS)
        if not recent and t_ns is not None:
            self._last_rotation = None
        detection = self.detect_corners(gray)
        if detection is None:
            self._last_corners = None
            return None
        self.stats[detection.stage] += 1
        estimate = self.estimate_pose(detection.corners)
        if estimate is None:
            self._last_corners = None
            return None
        T_camera_marker, rms, chosen, ratio = estimate
        self._last_corners = detection.corners
        self._last_rotation = T_camera_marker   # (only its rotation is used)
        self._last_seen_ns = t_ns
        T_dvio_controller = None
        if T_dvio_display is not None:
            T_dvio_controller = (T_dvio_display @ self.camera.T_display_camera @ T_camera_marker
                                 @ self._T_body_marker_inv)
        return MarkerObservation(corners_px=detection.corners, T_camera_marker=T_camera_marker,
                                 T_dvio_controller=T_dvio_controller, reprojection_error_px=rms,
                                 chosen_solution=chosen, ambiguity_ratio=ratio, id=self.marker.id)
