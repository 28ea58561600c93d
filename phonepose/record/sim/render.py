"""Camera frames of the simulated scene: background, the phone, its screen with the marker.

How it stays exact and fast (markers.md §2):
- The phone is a flat rectangle: bezel and lit screen are anti-aliased polygons (back: dark
  housing); the marker with its one-module quiet zone is a ``warpPerspective`` of a texture
  whose texel grid is tied to metres, so the projected marker corners land exactly where the
  pinhole model puts them (OpenCV pixel-centre convention). A mip level close to the projected
  size is picked, so the warp never skips texels.
- All of it is drawn at 2x into an undistorted canvas (with a margin: barrel distortion pulls
  pixels from outside the 640x480 pinhole image in), box-filtered down with INTER_AREA, then
  the lens distortion is applied by remapping with precomputed maps. Only the phone's bounding
  box is drawn and remapped; the static background is pre-distorted once.
- Noise comes from a precomputed bank (random offsets per frame), motion blur is a line kernel
  along the marker's image-space motion during the exposure, then a global brightness gain
  (auto-exposure) and JPEG.
"""

from __future__ import annotations

import cv2
import numpy as np

from phonepose.geometry import Pose
from phonepose.record.sim.config import SimConfig
from phonepose.record.sim.world import (
    HEIGHT,
    MARKER_CENTER_IN_BODY,
    PHONE_HEIGHT_M,
    PHONE_THICKNESS_M,
    PHONE_WIDTH_M,
    SCREEN_MARGIN_M,
    WIDTH,
    CameraIntrinsics,
)

MARGIN = 48          # undistorted canvas margin (px) around the 640x480 pinhole image
SS = 2               # supersampling factor of the phone rendering
NOISE_BANK = 4
GAIN_STEP = 0.005


def _marker_texture(cfg: SimConfig) -> tuple[np.ndarray, float]:
    """The marker with a one-module white quiet zone, as shown on the screen (gray levels).

    Returns the texture and the metric width of one texel. Texel (u, v) has its centre at
    ((u + 0.5) * texel - half, half - (v + 0.5) * texel) in the marker frame (x right, y up),
    so the texture's outer edges are exactly the quiet zone's edges.
    """
    r = cfg.render
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, cfg.marker.dictionary))
    bits = dictionary.markerSize + 2                      # data bits + black border
    cell = 40                                             # texels per module
    img = cv2.aruco.generateImageMarker(dictionary, cfg.marker.id, bits * cell, borderBits=1)
    img = cv2.copyMakeBorder(img, cell, cell, cell, cell, cv2.BORDER_CONSTANT, value=255)   # quiet zone
    tex = np.where(img > 127, r.screen_white_dn, r.screen_black_dn).astype(np.uint8)
    texel_m = cfg.marker.size_m / (bits * cell)
    return tex, texel_m


class Renderer:
    """Draws frames for one camera and one phone; build once per session."""

    def __init__(self, cfg: SimConfig, camera: CameraIntrinsics, rng: np.random.Generator):
        self.cfg = cfg
        self.camera = camera
        self.K = camera.K
        # Undistorted canvas intrinsics (principal point shifted by the margin).
        self.Kc = camera.K.copy()
        self.Kc[0, 2] += MARGIN
        self.Kc[1, 2] += MARGIN
        self.cw, self.ch = WIDTH + 2 * MARGIN, HEIGHT + 2 * MARGIN
        tex, self.texel_m = _marker_texture(cfg)
        self.marker_levels = _mips(tex)
        self.quiet_half_m = tex.shape[0] * self.texel_m / 2   # half side of marker + quiet zone
        self.white = int(cfg.render.screen_white_dn)
        self.bg_canvas2 = _background(self.cw * SS, self.ch * SS, rng)
        self.bg_canvas = cv2.resize(self.bg_canvas2, (self.cw, self.ch), interpolation=cv2.INTER_AREA)
        # Distorted pixel -> undistorted canvas coordinate maps.
        uu, vv = np.meshgrid(np.arange(WIDTH, dtype=np.float64), np.arange(HEIGHT, dtype=np.float64))
        pts = np.stack([uu.ravel(), vv.ravel()], axis=1).reshape(-1, 1, 2)
        und = cv2.undistortPoints(pts, camera.K, camera.D, None, None, self.Kc,
                                      (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)).reshape(HEIGHT, WIDTH, 2)
        self.map_x = und[..., 0].astype(np.float32)
        self.map_y = und[..., 1].astype(np.float32)
        self.bg = cv2.remap(self.bg_canvas, self.map_x, self.map_y, cv2.INTER_LINEAR)
        # fixed-point maps remap about twice as fast; the phone's patch is pasted into a working
        # copy of the canvas so the maps need no per-frame offset
        self.map_fixed = cv2.convertMaps(self.map_x, self.map_y, cv2.CV_16SC2)
        self.work = self.bg_canvas.copy()
        self._bg_cache: dict[int, np.ndarray] = {}
        self._f = np.diag(self.Kc)[:2].copy()
        self._c = self.Kc[:2, 2].copy()
        s = cfg.render.noise_sigma_dn
        self.noise = []
        if s > 0:
            for _ in range(NOISE_BANK):
                n = np.rint(rng.normal(0, s, size=(HEIGHT + 64, WIDTH + 64, 3)))
                self.noise.append((np.clip(n, 0, 255).astype(np.uint8), np.clip(-n, 0, 255).astype(np.uint8)))
        self._encode_params = [cv2.IMWRITE_JPEG_QUALITY, int(cfg.render.jpeg_quality)]

    # ------------------------------------------------------------------ drawing
    def _canvas(self, T: tuple[np.ndarray, np.ndarray], xy: np.ndarray, z: float) -> np.ndarray | None:
        """Canvas pixel coordinates of body-plane points (x, y, z); None if any is behind the camera."""
        R, t = T
        pts = xy @ R[:, :2].T + (R[:, 2] * z + t)
        if np.any(pts[:, 2] < 0.03):
            return None
        return pts[:, :2] / pts[:, 2:3] * self._f + self._c

    def render(self, T_cam_ctrl: Pose | tuple[np.ndarray, np.ndarray], blur_px: np.ndarray | None, gain: float,
               rng: np.random.Generator) -> np.ndarray:
        """The BGR frame (uint8, 480x640x3) with the phone at ``T_cam_ctrl`` (a Pose or (R, t)).

        ``blur_px``: the marker's image displacement (dx, dy) during the exposure (None: no blur).
        """
        # Brightness changes slowly: the gain is quantised to 0.5 % (< 1 DN) so the brightened
        # background can be cached; only the phone's box is scaled per frame.
        gain = round(gain / GAIN_STEP) * GAIN_STEP
        frame = self._background_at(gain).copy()
        if isinstance(T_cam_ctrl, Pose):
            T_cam_ctrl = (T_cam_ctrl.rotation.as_matrix(), np.asarray(T_cam_ctrl.translation, dtype=float))
        R, t = T_cam_ctrl
        front = float(R[:, 2] @ -t) > 0
        self._draw_phone(frame, T_cam_ctrl, front, blur_px, gain)
        if self.noise:
            pos, neg = self.noise[int(rng.integers(len(self.noise)))]
            oy, ox = (int(v) for v in rng.integers(0, 64, size=2))
            cv2.add(frame, pos[oy:oy + HEIGHT, ox:ox + WIDTH], frame)
            cv2.subtract(frame, neg[oy:oy + HEIGHT, ox:ox + WIDTH], frame)
        return frame

    def _background_at(self, gain: float) -> np.ndarray:
        key = int(round(gain / GAIN_STEP))
        bg = self._bg_cache.get(key)
        if bg is None:
            bg = self.bg if key == int(round(1 / GAIN_STEP)) else cv2.convertScaleAbs(self.bg, alpha=gain)
            self._bg_cache[key] = bg
        return bg

    def encode(self, frame: np.ndarray) -> bytes:
        ok, buf = cv2.imencode(".jpg", frame, self._encode_params)
        return buf.tobytes()

    def _draw_phone(self, frame: np.ndarray, T, front: bool, blur_px, gain: float) -> None:
        w2, h2 = PHONE_WIDTH_M / 2, PHONE_HEIGHT_M / 2
        outline_xy = np.array([[-w2, h2], [w2, h2], [w2, -h2], [-w2, -h2]])
        z = PHONE_THICKNESS_M / 2 if front else -PHONE_THICKNESS_M / 2
        outline = self._canvas(T, outline_xy, z)
        if outline is None:
            return
        lo = outline.min(axis=0) - 3
        hi = outline.max(axis=0) + 3
        if blur_px is not None:
            pad = int(np.ceil(np.abs(blur_px).max() / 2)) + 2
            lo -= pad
            hi += pad
        if hi[0] < 0 or hi[1] < 0 or lo[0] > self.cw - 1 or lo[1] > self.ch - 1:
            return
        d_lo, d_hi = self._distorted_box(lo, hi)
        if d_lo is None:
            return
        (x0, y0), (x1, y1) = d_lo, d_hi
        # The patch only needs to cover the phone: the remap reads everything else from the
        # working canvas, which holds the background.
        cx0, cy0 = max(int(np.floor(lo[0])), 0), max(int(np.floor(lo[1])), 0)
        cx1, cy1 = min(int(np.ceil(hi[0])) + 1, self.cw), min(int(np.ceil(hi[1])) + 1, self.ch)
        if cx1 <= cx0 or cy1 <= cy0:
            return
        patch2 = self.bg_canvas2[cy0 * SS:cy1 * SS, cx0 * SS:cx1 * SS].copy()
        origin = np.array([cx0, cy0])

        def local2(px):   # canvas pixels -> pixels of the 2x patch (pixel-centre convention)
            return (px - origin) * SS + (SS - 1) / 2

        def fill(px, value):
            pts = np.round(local2(px) * 16).astype(np.int32)
            cv2.fillConvexPoly(patch2, pts, (value, value, value), lineType=cv2.LINE_AA, shift=4)

        if not front:
            fill(outline, 40)                                   # the phone's back
        else:
            fill(outline, 18)                                   # bezel
            m = SCREEN_MARGIN_M
            screen = self._canvas(T, outline_xy - np.sign(outline_xy) * m, z)
            fill(screen, self.white)
            self._draw_marker(patch2, T, z, local2)
        patch = cv2.resize(patch2, (cx1 - cx0, cy1 - cy0), interpolation=cv2.INTER_AREA)
        if blur_px is not None:
            patch = _motion_blur(patch, blur_px)
        self.work[cy0:cy1, cx0:cx1] = patch
        m1, m2 = self.map_fixed
        roi = cv2.remap(self.work, m1[y0:y1, x0:x1], m2[y0:y1, x0:x1], cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
        if gain != 1.0:
            cv2.convertScaleAbs(roi, roi, alpha=gain)
        frame[y0:y1, x0:x1] = roi
        self.work[cy0:cy1, cx0:cx1] = self.bg_canvas[cy0:cy1, cx0:cx1]

    def _draw_marker(self, patch2: np.ndarray, T: tuple[np.ndarray, np.ndarray], z: float, local2) -> None:
        """Warp the marker texture (exact texel-to-metre mapping) into the 2x patch."""
        c = MARKER_CENTER_IN_BODY[:2]
        q = self.quiet_half_m
        quad_xy = c + np.array([[-q, q], [q, q], [q, -q], [-q, -q]])
        quad = self._canvas(T, quad_xy, z)
        if quad is None:
            return
        dst = local2(quad)
        span = np.linalg.norm(dst[1] - dst[0])
        levels = self.marker_levels
        level = 0
        while level + 1 < len(levels) and levels[level + 1].shape[1] >= span:
            level += 1
        tex = levels[level]
        th, tw = tex.shape
        # texture outer edges (-0.5 and size - 0.5 in texel coordinates) are the quad's corners
        src = np.array([[-0.5, -0.5], [tw - 0.5, -0.5], [tw - 0.5, th - 0.5], [-0.5, th - 0.5]])
        bx0 = max(int(np.floor(dst[:, 0].min())) - 1, 0)
        by0 = max(int(np.floor(dst[:, 1].min())) - 1, 0)
        bx1 = min(int(np.ceil(dst[:, 0].max())) + 2, patch2.shape[1])
        by1 = min(int(np.ceil(dst[:, 1].max())) + 2, patch2.shape[0])
        if bx1 <= bx0 or by1 <= by0:
            return
        H = _dlt(src, dst - np.array([bx0, by0]))
        size = (bx1 - bx0, by1 - by0)
        gray = cv2.warpPerspective(tex, H, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        mask = np.zeros((size[1], size[0]), np.uint8)
        cv2.fillConvexPoly(mask, np.round((dst - np.array([bx0, by0])) * 16).astype(np.int32), 255, shift=4)
        cv2.copyTo(cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR), mask, patch2[by0:by1, bx0:bx1])

    def _distorted_box(self, lo, hi):
        """Integer box [x0, x1) x [y0, y1) of distorted pixels covering the canvas box [lo, hi]."""
        # Under radial distortion a canvas box maps to a curved region: distort its border.
        xs = np.linspace(lo[0], hi[0], 8)
        ys = np.linspace(lo[1], hi[1], 8)
        border = np.concatenate([np.column_stack([xs, np.full(8, lo[1])]), np.column_stack([xs, np.full(8, hi[1])]),
                                 np.column_stack([np.full(8, lo[0]), ys]), np.column_stack([np.full(8, hi[0]), ys])])
        px = self._distort((border - self._c) / self._f)
        x0 = max(int(np.floor(px[:, 0].min())) - 2, 0)
        y0 = max(int(np.floor(px[:, 1].min())) - 2, 0)
        x1 = min(int(np.ceil(px[:, 0].max())) + 3, WIDTH)
        y1 = min(int(np.ceil(px[:, 1].max())) + 3, HEIGHT)
        if x1 <= x0 or y1 <= y0:
            return None, None
        return (x0, y0), (x1, y1)

    def _distort(self, xy: np.ndarray) -> np.ndarray:
        """Normalised pinhole coordinates -> distorted pixels (OpenCV plumb_bob)."""
        k1, k2, p1, p2, k3 = self.camera.D
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.column_stack([xd * self.K[0, 0] + self.K[0, 2], yd * self.K[1, 1] + self.K[1, 2]])


def _dlt(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Exact 4-point homography in float64 (getPerspectiveTransform works in float32)."""
    A = []
    b = []
    for (x, y), (u, v) in zip(src, dst, strict=True):
        A.append([x, y, 1, 0, 0, 0, -u * x, -u * y])
        A.append([0, 0, 0, x, y, 1, -v * x, -v * y])
        b += [u, v]
    h = np.linalg.solve(np.array(A), np.array(b))
    return np.append(h, 1.0).reshape(3, 3)


def _mips(tex: np.ndarray) -> list[np.ndarray]:
    out = [tex]
    while min(out[-1].shape[:2]) >= 64 and out[-1].shape[0] % 2 == 0 and out[-1].shape[1] % 2 == 0:
        out.append(cv2.resize(out[-1], (out[-1].shape[1] // 2, out[-1].shape[0] // 2), interpolation=cv2.INTER_AREA))
    return out


def _motion_blur(img: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Average of the image shifted along the segment ``d`` (px) centred on the frame time."""
    length = float(np.hypot(*d))
    if length < 0.75:
        return img
    n = int(np.ceil(length)) | 1
    c = (n - 1) / 2
    s = np.linspace(-0.5, 0.5, max(int(np.ceil(length * 4)), 2))
    x, y = c + s * d[0], c + s * d[1]
    xi, yi = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - xi, y - yi
    k = np.zeros((n + 1, n + 1), np.float64)
    # bilinear splat of the sample points along the segment
    np.add.at(k, (yi, xi), (1 - fx) * (1 - fy))
    np.add.at(k, (yi, xi + 1), fx * (1 - fy))
    np.add.at(k, (yi + 1, xi), (1 - fx) * fy)
    np.add.at(k, (yi + 1, xi + 1), fx * fy)
    k = k[:n, :n].astype(np.float32)
    k /= k.sum()
    return cv2.filter2D(img, -1, k, borderType=cv2.BORDER_REPLICATE)


def _background(w: int, h: int, rng: np.random.Generator) -> np.ndarray:
    """A room-like textured background: smooth colour noise, shelves and posters, a gradient."""
    # low-saturation room light: a smooth luminance field with a slight colour tint
    lum = cv2.resize(rng.uniform(70, 180, size=(h // 120 + 2, w // 120 + 2)).astype(np.float32), (w, h),
                     interpolation=cv2.INTER_CUBIC)
    tint = rng.uniform(0.85, 1.15, size=3).astype(np.float32)
    img = lum[..., None] * tint
    fine = rng.normal(0, 5, size=(h // 3, w // 3)).astype(np.float32)
    img += cv2.resize(fine, (w, h), interpolation=cv2.INTER_LINEAR)[..., None]
    for _ in range(18):
        x0, y0 = int(rng.uniform(0, w)), int(rng.uniform(0, h))
        x1, y1 = x0 + int(rng.uniform(w * 0.03, w * 0.3)), y0 + int(rng.uniform(h * 0.03, h * 0.25))
        color = [float(c) for c in rng.uniform(40, 200) * rng.uniform(0.7, 1.3, 3)]
        cv2.rectangle(img, (x0, y0), (x1, y1), color, -1)
    grad = np.linspace(1.1, 0.8, h, dtype=np.float32)[:, None, None]
    img = img * grad
    img = cv2.GaussianBlur(img, (0, 0), 1.2)
    return np.clip(img, 0, 255).astype(np.uint8)
