"""Camera frames of the simulated scene: background, the phone, its screen with the marker.

How it stays exact and fast (markers.md §2):
- The phone is a flat textured rectangle (front: bezel, white screen, the ArUco marker with its
  quiet zone; back: dark housing) drawn with ``warpPerspective`` of a texture whose pixel grid
  is tied to metres, so the projected marker corners land exactly where the pinhole model puts
  them (OpenCV pixel-centre convention).
- It is drawn at 2x into an undistorted canvas (with a margin: barrel distortion pulls pixels
  from outside the 640x480 pinhole image in), box-filtered down with INTER_AREA, then the lens
  distortion is applied by remapping with precomputed maps. Only the phone's bounding box is
  warped and remapped; the static background is pre-distorted once.
- Noise comes from a precomputed bank (random offsets per frame), motion blur is a line kernel
  along the marker's image-space motion during the exposure, then a global brightness gain
  (auto-exposure) and JPEG.
"""

from __future__ import annotations

import cv2
import numpy as np

from phonepose.geometry import Pose
from phonepose.record.sim.config import SimConfig
from phonepose.record.sim.world import (HEIGHT, PHONE_HEIGHT_M, PHONE_THICKNESS_M, PHONE_WIDTH_M, SCREEN_MARGIN_M,
                                        WIDTH, CameraIntrinsics, MARKER_CENTER_IN_BODY)

MARGIN = 48          # undistorted canvas margin (px) around the 640x480 pinhole image
SS = 2               # supersampling factor of the phone rendering
TEX_PX_PER_M = 4800  # texture resolution: 0.21 mm per texel, a 5 cm marker is 240 texels
NOISE_BANK = 4


def _marker_texture(cfg: SimConfig) -> np.ndarray:
    """Front face of the phone, gray levels, (rows = top to bottom, cols = left to right)."""
    r = cfg.render
    w = int(round(PHONE_WIDTH_M * TEX_PX_PER_M))
    h = int(round(PHONE_HEIGHT_M * TEX_PX_PER_M))
    w, h = w - w % 8, h - h % 8
    tex = np.full((h, w), 18, np.uint8)                          # dark bezel / housing edge
    b = int(round(SCREEN_MARGIN_M * TEX_PX_PER_M))
    tex[b:h - b, b:w - b] = r.screen_white_dn                    # lit screen
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, cfg.marker.dictionary))
    bits = dictionary.markerSize + 2
    side = int(round(cfg.marker.size_m * TEX_PX_PER_M))
    cell = side // bits
    side = cell * bits
    img = cv2.aruco.generateImageMarker(dictionary, cfg.marker.id, bits, borderBits=1)
    img = cv2.resize(img, (side, side), interpolation=cv2.INTER_NEAREST)
    img = np.where(img > 127, r.screen_white_dn, r.screen_black_dn).astype(np.uint8)
    # Marker centre in texel coordinates (texel centres at integers): body x right, y up.
    cx = (MARKER_CENTER_IN_BODY[0] + PHONE_WIDTH_M / 2) * TEX_PX_PER_M - 0.5
    cy = (PHONE_HEIGHT_M / 2 - MARKER_CENTER_IN_BODY[1]) * TEX_PX_PER_M - 0.5
    x0 = int(round(cx - (side - 1) / 2))
    y0 = int(round(cy - (side - 1) / 2))
    tex[y0:y0 + side, x0:x0 + side] = img
    # The exact metric size of the drawn square must equal the configured size.
    return tex, side / TEX_PX_PER_M, (x0, y0)


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
        front, side_m, (x0, y0) = _marker_texture(cfg)
        self.marker_side_m = side_m
        # Texel (u, v) of level 0 has its centre at body x = (u + 0.5)/ppm - W/2 + sx,
        # y = H/2 - (v + 0.5)/ppm + sy; (sx, sy) put the marker square's centre at its body pose.
        ppm = TEX_PX_PER_M
        hpx, wpx = front.shape
        W, H = wpx / ppm, hpx / ppm
        side_px = side_m * ppm
        self._plane_shift = np.array([MARKER_CENTER_IN_BODY[0] - (x0 + side_px / 2) / ppm + W / 2,
                                      MARKER_CENTER_IN_BODY[1] - H / 2 + (y0 + side_px / 2) / ppm])
        self.tex_size_m = (W, H)
        back = np.full_like(front, 45)
        cv2.circle(back, (wpx // 4, hpx // 10), wpx // 10, 20, -1)   # camera bump
        self.levels = {"front": _mips(front), "back": _mips(back)}
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
        s = cfg.render.noise_sigma_dn
        self.noise = []
        if s > 0:
            for _ in range(NOISE_BANK):
                n = np.rint(rng.normal(0, s, size=(HEIGHT + 64, WIDTH + 64, 3)))
                self.noise.append((np.clip(n, 0, 255).astype(np.uint8), np.clip(-n, 0, 255).astype(np.uint8)))
        self._encode_params = [cv2.IMWRITE_JPEG_QUALITY, int(cfg.render.jpeg_quality)]

    # ------------------------------------------------------------------ geometry
    def _face_corners(self, T_cam_ctrl: Pose, front: bool) -> np.ndarray:
        """The 3D corners (camera frame) of the textured face: TL, TR, BR, BL of the texture."""
        w, h = self.tex_size_m
        sx, sy = self._plane_shift
        z = PHONE_THICKNESS_M / 2 if front else -PHONE_THICKNESS_M / 2
        # For the back face the texture is seen mirrored: walk its corners the other way round.
        xs = np.array([-w / 2, w / 2, w / 2, -w / 2]) + sx
        ys = np.array([h / 2, h / 2, -h / 2, -h / 2]) + sy
        if not front:
            xs = -xs
        return T_cam_ctrl.apply(np.column_stack([xs, ys, np.full(4, z)]))

    def render(self, T_cam_ctrl: Pose, blur_px: np.ndarray | None, gain: float, rng: np.random.Generator) -> np.ndarray:
        """The BGR frame (uint8, 480x640x3) with the phone at ``T_cam_ctrl``.

        ``blur_px``: the marker's image displacement (dx, dy) during the exposure (None: no blur).
        """
        frame = self.bg.copy()
        R = T_cam_ctrl.rotation.as_matrix()
        normal = R[:, 2]
        front = float(normal @ -T_cam_ctrl.translation) > 0
        corners = self._face_corners(T_cam_ctrl, front)
        if np.all(corners[:, 2] > 0.03):
            self._draw_phone(frame, corners, front, blur_px)
        if gain != 1.0:
            cv2.convertScaleAbs(frame, frame, alpha=gain)
        if self.noise:
            pos, neg = self.noise[int(rng.integers(len(self.noise)))]
            oy, ox = (int(v) for v in rng.integers(0, 64, size=2))
            cv2.add(frame, pos[oy:oy + HEIGHT, ox:ox + WIDTH], frame)
            cv2.subtract(frame, neg[oy:oy + HEIGHT, ox:ox + WIDTH], frame)
        return frame

    def encode(self, frame: np.ndarray) -> bytes:
        ok, buf = cv2.imencode(".jpg", frame, self._encode_params)
        return buf.tobytes()

    def _draw_phone(self, frame: np.ndarray, corners: np.ndarray, front: bool, blur_px) -> None:
        proj = corners[:, :2] / corners[:, 2:3] * np.diag(self.Kc)[:2] + self.Kc[:2, 2]   # canvas pixels
        # Distorted-image bounding box: where the canvas quad's bounding box lands.
        lo = proj.min(axis=0) - 3
        hi = proj.max(axis=0) + 3
        if hi[0] < 0 or hi[1] < 0 or lo[0] > self.cw - 1 or lo[1] > self.ch - 1:
            return
        if blur_px is not None:
            pad = int(np.ceil(np.abs(blur_px).max() / 2)) + 2
            lo -= pad
            hi += pad
        d_lo, d_hi = self._distorted_box(lo, hi)
        if d_lo is None:
            return
        (x0, y0), (x1, y1) = d_lo, d_hi
        mx = self.map_x[y0:y1, x0:x1]
        my = self.map_y[y0:y1, x0:x1]
        cx0 = max(int(np.floor(mx.min())) - 2, 0)
        cy0 = max(int(np.floor(my.min())) - 2, 0)
        cx1 = min(int(np.ceil(mx.max())) + 3, self.cw)
        cy1 = min(int(np.ceil(my.max())) + 3, self.ch)
        patch2 = self.bg_canvas2[cy0 * SS:cy1 * SS, cx0 * SS:cx1 * SS].copy()
        # texture -> local 2x canvas pixels
        tex_levels = self.levels["front" if front else "back"]
        span_px = np.linalg.norm(proj[1] - proj[0]) * SS
        tex_w = tex_levels[0].shape[1]
        level = 0
        while level + 1 < len(tex_levels) and tex_w / 2 ** (level + 1) >= span_px:
            level += 1
        tex = tex_levels[level]
        th, tw = tex.shape
        # texel centres of the chosen level at their metric places: corner texels' outer edges at -0.5 / size-0.5
        src = np.array([[-0.5, -0.5], [tw - 0.5, -0.5], [tw - 0.5, th - 0.5], [-0.5, th - 0.5]], np.float64)
        dst = (proj - np.array([cx0, cy0])) * SS + (SS - 1) / 2
        H = _dlt(src, dst)
        # The phone is gray: warp one channel (3x cheaper), then paste it inside its outline.
        size = (patch2.shape[1], patch2.shape[0])
        gray2 = cv2.warpPerspective(tex, H, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        quad = cv2.perspectiveTransform(src.reshape(1, 4, 2), H)[0]
        mask2 = np.zeros(patch2.shape[:2], np.uint8)
        cv2.fillConvexPoly(mask2, np.round(quad * 16).astype(np.int32), 255, lineType=cv2.LINE_AA, shift=4)
        cv2.copyTo(cv2.cvtColor(gray2, cv2.COLOR_GRAY2BGR), mask2, patch2)
        patch = cv2.resize(patch2, (cx1 - cx0, cy1 - cy0), interpolation=cv2.INTER_AREA)
        if blur_px is not None:
            patch = _motion_blur(patch, blur_px)
        out = cv2.remap(patch, mx - np.float32(cx0), my - np.float32(cy0), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
        frame[y0:y1, x0:x1] = out

    def _distorted_box(self, lo, hi):
        """Integer box [x0, x1) x [y0, y1) of distorted pixels whose canvas point is in [lo, hi]."""
        # Under radial distortion a canvas box maps to a curved region; test its border densely.
        xs = np.linspace(lo[0], hi[0], 12)
        ys = np.linspace(lo[1], hi[1], 12)
        border = np.concatenate([np.column_stack([xs, np.full(12, lo[1])]), np.column_stack([xs, np.full(12, hi[1])]),
                                 np.column_stack([np.full(12, lo[0]), ys]), np.column_stack([np.full(12, hi[0]), ys])])
        # canvas -> normalised -> distorted pixels
        norm = (border - self.Kc[:2, 2]) / np.diag(self.Kc)[:2]
        pts = np.column_stack([norm, np.ones(len(norm))])
        px = self.camera.project(pts)
        x0 = max(int(np.floor(px[:, 0].min())) - 2, 0)
        y0 = max(int(np.floor(px[:, 1].min())) - 2, 0)
        x1 = min(int(np.ceil(px[:, 0].max())) + 3, WIDTH)
        y1 = min(int(np.ceil(px[:, 1].max())) + 3, HEIGHT)
        if x1 <= x0 or y1 <= y0:
            return None, None
        return (x0, y0), (x1, y1)


def _dlt(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Exact 4-point homography in float64 (getPerspectiveTransform works in float32)."""
    A = []
    b = []
    for (x, y), (u, v) in zip(src, dst):
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
    length = float(np.hypot(*d))
    if length < 0.75:
        return img
    n = int(np.ceil(length)) | 1
    k = np.zeros((n, n), np.float32)
    c = (n - 1) / 2
    steps = max(int(np.ceil(length * 4)), 2)
    for s in np.linspace(-0.5, 0.5, steps):
        x, y = c + s * d[0], c + s * d[1]
        xi, yi = int(np.floor(x)), int(np.floor(y))
        fx, fy = x - xi, y - yi
        for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            if 0 <= xi + dx < n and 0 <= yi + dy < n:
                k[yi + dy, xi + dx] += w
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
