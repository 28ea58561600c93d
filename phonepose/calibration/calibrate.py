"""Camera intrinsics and distortion (plumb_bob k1 k2 p1 p2 k3) from views of a ChArUco board.

Everything that measures is OpenCV's: ``CharucoDetector.detectBoard`` finds the board's corners
(sub-pixel) in each frame, ``CharucoBoard.matchImagePoints`` pairs them with their board
coordinates, and ``calibrateCameraExtended`` fits K and D and gives the per-view RMS and the
standard deviations of the intrinsics. What is ours is which frames become views:

- ``--images DIR``: every image in which the board shows at least ``min_corners`` non-collinear corners;
- ``--video FILE``: every k-th frame (k chosen so about ``3 * max_views`` frames are examined),
  skipping frames in which the board has barely moved since the last kept view;
- ``--camera N``: MJPG at ``--size`` (the mode ``record live`` records in), one frame every
  ``interval_s`` seconds, the same way, until ``max_views`` views, ``seconds`` elapsed or Ctrl-C.

and, if more than ``max_views`` views remain, an evenly spaced subset of them (more views of the
same poses add run time but no information).
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from phonepose.calibration.board import DEFAULT_BOARD, BoardSpec, board_spec
from phonepose.calibration.camera_file import CameraCalibrationFile
from phonepose.errors import ConfigError, InputFileError, PhoneposeError, SessionContentError
from phonepose.files import check_input
from phonepose.pipeline.shared import UNDECODABLE, Decoded, decode_gray
from phonepose.pipeline.types import camera_problem

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
MIN_VIEWS = 4            # 9 unknowns + 6 per view; OpenCV's own ChArUco tutorial calibrates from 4 photos
RECOMMENDED_VIEWS = 15
MIN_CORNERS = 8          # of the default board's 24; fewer corners per view constrain too little
MIN_MOTION = 0.02        # a stream frame whose corners moved < 2 % of the image diagonal is the same view

Progress = Callable[[str], None]


@dataclass(frozen=True)
class View:
    """One frame in which the board was found: its corners in the image and on the board."""

    name: str                    # file name, or "frame N"
    ids: np.ndarray              # (N,) ChArUco corner ids
    object_points: np.ndarray    # (N, 3) float32, metres on the board
    image_points: np.ndarray     # (N, 2) float32, pixels


@dataclass
class CalibrationResult:
    K: np.ndarray                        # (3, 3)
    D: np.ndarray                        # (5,) k1 k2 p1 p2 k3
    width: int
    height: int
    rms_px: float                        # RMS reprojection error over all corners of all views
    per_view_rms_px: np.ndarray          # (n_views,)
    views: list[str]                     # names of the views used, in order
    corners_per_view: list[int]
    std_intrinsics: np.ndarray           # (9,) standard deviations of fx fy cx cy k1 k2 p1 p2 k3
    board: BoardSpec = DEFAULT_BOARD
    frames_examined: int = 0
    frames_with_board: int = 0
    skipped: list[str] = field(default_factory=list)    # unreadable inputs, reported as warnings

    def to_file(self) -> CameraCalibrationFile:
        return CameraCalibrationFile(self.K, self.D, self.width, self.height, self.rms_px, board_spec(self.board))


class BoardFinder:
    """Finds the board in a frame; a frame with too few (or only collinear) corners is no view."""

    def __init__(self, board: BoardSpec = DEFAULT_BOARD, min_corners: int = MIN_CORNERS):
        self.spec = board
        self.board = board.opencv()
        self.detector = cv2.aruco.CharucoDetector(self.board)
        self.min_corners = max(4, min(int(min_corners), board.n_corners))

    def find(self, image: np.ndarray, name: str) -> View | None:
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
        corners, ids, _, _ = self.detector.detectBoard(gray)
        if ids is None or len(ids) < self.min_corners:
            return None
        if self.board.checkCharucoCornersCollinear(ids):
            return None
        # OpenCV's stubs type detectedCorners as a list of arrays; a ChArUco board takes the one array detectBoard gives
        obj, img = self.board.matchImagePoints(corners, ids)  # type: ignore[call-overload]
        return View(name, ids.reshape(-1).astype(int), obj.reshape(-1, 3).astype(np.float32),
                    img.reshape(-1, 2).astype(np.float32))


def same_view(view: View, kept: list[View], diagonal: float) -> View | None:
    """The view of ``kept`` that ``view`` repeats (its common corners moved less than MIN_MOTION of the image
    diagonal on average), or None: a new view. Every source keeps only new views (a still video, a photo copied twice),
    since a repeated view adds no information and weighs its pose twice."""
    for last in reversed(kept):     # the latest first: a stream's next frame is most like its last view
        common, a, b = np.intersect1d(view.ids, last.ids, return_indices=True)
        if len(common) < 4:
            continue
        shift = np.linalg.norm(view.image_points[a] - last.image_points[b], axis=1).mean()
        if shift < MIN_MOTION * diagonal:
            return last
    return None


def spread(views: list[View], max_views: int) -> list[View]:
    """At most ``max_views`` views, evenly spaced in their order."""
    if len(views) <= max_views:
        return views
    keep = np.unique(np.linspace(0, len(views) - 1, max_views).round().astype(int))
    return [views[i] for i in keep]


# --- sources ---------------------------------------------------------------------------------

@dataclass
class _Collected:
    views: list[View]
    size: tuple[int, int] | None      # (width, height)
    examined: int
    with_board: int
    skipped: list[str]


def views_from_images(directory: str | Path, finder: BoardFinder, progress: Progress | None = None) -> _Collected:
    directory = Path(directory)
    if not directory.exists():
        raise InputFileError(f"{directory}: no such directory")
    if not directory.is_dir():
        raise InputFileError(f"{directory}: not a directory ({{images}} takes a directory of images)",
                             parameter="images", value=directory)
    files = sorted(p for p in directory.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.is_dir())
    if not files:
        raise InputFileError(f"{directory}: no images ({', '.join(IMAGE_SUFFIXES)})")
    for path in files:
        check_input(path, "image")    # a FIFO or device among the images: refused before reading any
    views: list[View] = []
    skipped: list[str] = []
    size, examined, with_board = None, 0, 0
    for path in files:
        decoded = _decode_image(path)
        image = decoded.gray
        if image is None:
            skipped.append(f"{path.name}: not an image phonepose can read" if decoded.problem == UNDECODABLE
                           else f"{path.name}: {decoded.problem}")
            continue
        if decoded.damaged:     # used, and said (the list is what the command warns of)
            skipped.append(f"{path.name}: damaged image data ({decoded.damaged}); read as far as it goes")
        examined += 1
        here = (image.shape[1], image.shape[0])
        if size is None:
            size = here
        elif here != size:
            raise SessionContentError(f"{path}: {here[0]}x{here[1]} px, but the images before it are "
                                      f"{size[0]}x{size[1]}; calibrate one camera resolution at a time")
        view = finder.find(image, path.name)
        if view is not None:
            with_board += 1
            seen = same_view(view, views, float(np.hypot(*size)))
            if seen is not None:
                skipped.append(f"{path.name}: the same view as {seen.name} (the board moved less than "
                               f"{MIN_MOTION:.0%} of the image diagonal); not used")
                continue
            views.append(view)
            if progress:
                progress(f"{path.name}: {len(view.ids)} corners")
    if examined == 0:
        raise InputFileError(f"{directory}: none of its {len(files)} image files can be read")
    return _Collected(views, size, examined, with_board, skipped)


def _decode_image(path: Path) -> Decoded:
    """The grayscale image in ``path`` (pipeline.shared.decode_gray: the size from its header first). The bytes are
    read here and decoded from memory: a path that is not UTF-8 crashes ``cv2.imread`` (SIGSEGV)."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read ({exc.strerror or exc})") from None
    return decode_gray(data)


def opencv_path(path: Path, what: str, fix: str = "rename it", error: type[PhoneposeError] = InputFileError) -> str:
    """``path`` as the str OpenCV is given (a video, which it opens by name), or an InputFileError when the name
    is not UTF-8: OpenCV crashes on one (SIGSEGV)."""
    name = os.fspath(path)
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        raise error(f"{name.encode('utf-8', 'backslashreplace').decode()}: OpenCV cannot open {what} whose "
                             f"name is not UTF-8 text; {fix}") from None
    return name


@contextlib.contextmanager
def _quiet_opencv() -> Iterator[None]:
    """OpenCV's video backends print WARN lines when a file or device cannot be opened; our one
    error line says it instead."""
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(level)


def camera_exists(index: int) -> bool:
    """Whether camera ``index`` can be asked for: on Linux its /dev/videoN exists (OpenCV raises
    cv2.error beyond its index range and crashes on -1); elsewhere any index >= 0."""
    if index < 0:
        return False
    if sys.platform.startswith("linux"):
        return os.path.exists(f"/dev/video{index}")
    return True


def _open_device(index: int, size: tuple[int, int] | None = None) -> cv2.VideoCapture:
    """Camera ``index`` in the mode ``record live --camera`` records with: MJPG, at ``size`` if given
    (a webcam may crop its sensor differently in another mode, which changes the intrinsics)."""
    if not camera_exists(index):
        raise InputFileError(f"camera device {index} cannot be opened (no such camera, or in use)")
    with _quiet_opencv():
        cap = cv2.VideoCapture(int(index))
        if cap.isOpened():
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*"MJPG"))
            if size is not None:
                cap.set(cv2.CAP_PROP_FRAME_WIDTH, size[0])
                cap.set(cv2.CAP_PROP_FRAME_HEIGHT, size[1])
        return cap


def _collect_stream(cap: cv2.VideoCapture, finder: BoardFinder, name: str, *, every: int = 1,
                    interval_s: float = 0.0, seconds: float | None = None, max_views: int | None = None,
                    progress: Progress | None = None) -> _Collected:
    """Views from a video or a live camera: every ``every``-th frame, at most one per ``interval_s``
    seconds of wall time, each a view only if the board moved since the last view."""
    views: list[View] = []
    size, examined, with_board, index = None, 0, 0, -1
    t_start = t_last = time.monotonic()
    try:
        while True:
            if seconds is not None and time.monotonic() - t_start > seconds:
                break
            if max_views is not None and len(views) >= max_views:
                break
            index += 1
            if index % every:
                if not cap.grab():
                    break
                continue
            ok, frame = cap.read()
            if not ok or frame is None:
                break
            if interval_s > 0 and examined and time.monotonic() - t_last < interval_s:
                continue
            t_last = time.monotonic()
            examined += 1
            size = size or (frame.shape[1], frame.shape[0])
            view = finder.find(frame, f"frame {index}")
            if view is None:
                continue
            with_board += 1
            if same_view(view, views, float(np.hypot(*size))) is None:
                views.append(view)
                if progress:
                    progress(f"{name} frame {index}: view {len(views)}, {len(view.ids)} corners")
    except KeyboardInterrupt:      # live capture: Ctrl-C ends the capture, the calibration still runs
        if progress:
            progress("interrupted: calibrating from the views so far")
    finally:
        cap.release()
    return _Collected(views, size, examined, with_board, [])


def views_from_video(path: str | Path, finder: BoardFinder, max_views: int = 40,
                     progress: Progress | None = None) -> _Collected:
    path = check_input(path, "video file")
    name = opencv_path(path, "a video")
    with _quiet_opencv():
        cap = cv2.VideoCapture(name)
    if not cap.isOpened():
        raise InputFileError(f"{path}: not a video OpenCV can read")
    n_frames = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
    every = max(1, n_frames // (3 * max_views)) if n_frames > 0 else 1
    collected = _collect_stream(cap, finder, path.name, every=every, progress=progress)
    if collected.examined == 0:
        raise InputFileError(f"{path}: no frame could be decoded")
    return collected


def views_from_device(index: int, finder: BoardFinder, max_views: int = 40, interval_s: float = 0.5,
                      seconds: float = 120.0, size: tuple[int, int] | None = None,
                      progress: Progress | None = None) -> _Collected:
    cap = _open_device(index, size)
    if not cap.isOpened():
        raise InputFileError(f"camera device {index} cannot be opened (no such camera, or in use)")
    got = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    if size is not None and got != tuple(size):
        cap.release()
        raise ConfigError(f"{{size}} {size[0]}x{size[1]}: camera device {index} gives {got[0]}x{got[1]}; "
                          "use a size the camera supports", parameter="size", value=size)
    if progress:
        progress(f"camera {index}: move the board through the whole image, tilted in every direction; "
                 f"stops after {max_views} views or {seconds:g} s (Ctrl-C to stop earlier)")
    collected = _collect_stream(cap, finder, f"camera {index}", interval_s=interval_s, seconds=seconds,
                                max_views=max_views, progress=progress)
    if collected.examined == 0:
        raise InputFileError(f"camera device {index} opened but delivered no frame")
    return collected


# --- calibration ---------------------------------------------------------------------------------

def calibrate_views(views: list[View], image_size: tuple[int, int], board: BoardSpec = DEFAULT_BOARD,
                    flags: int = 0) -> CalibrationResult:
    """cv2.calibrateCameraExtended on ``views`` (full plumb_bob model unless ``flags`` fix terms)."""
    obj = [v.object_points for v in views]
    img = [v.image_points for v in views]
    try:
        # OpenCV's stubs do not mark cameraMatrix/distCoeffs optional; None asks it to estimate them
        rms, K, D, _, _, std_in, _, per_view = cv2.calibrateCameraExtended(  # type: ignore[call-overload]
            obj, img, tuple(int(s) for s in image_size), None, None, flags=flags,
            criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12))
    except cv2.error as exc:
        raise SessionContentError(f"calibration failed: {' '.join(str(exc).split())[-200:]}") from None
    D5 = np.zeros(5)
    D5[: min(5, D.size)] = D.ravel()[:5]
    if not np.isfinite(rms) or camera_problem(K, D5, *image_size) is not None:   # the one check a calibration file gets
        raise SessionContentError("calibration failed: the fit did not converge (take views from more angles)")
    return CalibrationResult(K=K, D=D5, width=int(image_size[0]), height=int(image_size[1]), rms_px=float(rms),
                             per_view_rms_px=per_view.ravel().astype(float), views=[v.name for v in views],
                             corners_per_view=[len(v.ids) for v in views],
                             std_intrinsics=std_in.ravel()[:9].astype(float), board=board)


def calibrate_camera(*, images: str | Path | None = None, video: str | Path | None = None,
                     device: int | None = None, board: BoardSpec = DEFAULT_BOARD, max_views: int = 40,
                     min_corners: int = MIN_CORNERS, min_views: int = MIN_VIEWS, device_seconds: float = 120.0,
                     device_interval_s: float = 0.5, device_size: tuple[int, int] | None = None,
                     progress: Progress | None = None) -> CalibrationResult:
    """Calibrate from exactly one source. Too few views is a SessionContentError (exit 4) saying how
    many frames showed the board; unreadable inputs are InputFileErrors (exit 2)."""
    given = [name for name, value in (("device", device), ("video", video), ("images", images))
             if value is not None]
    if len(given) != 1:
        raise ConfigError("give exactly one of {device} N, {video} FILE, {images} DIR"
                          + (f" (got {' and '.join('{' + name + '}' for name in given)})" if given else ""),
                          parameter="device", also=["video", "images"], expected="exactly one source")
    if max_views < min_views:
        raise ConfigError(f"{{max_views}} {max_views}: must be >= {min_views}", parameter="max_views",
                          value=max_views, expected=f">= {min_views}")
    finder = BoardFinder(board, min_corners)
    if images is not None:
        got, what = views_from_images(images, finder, progress), f"{images}: of {{n}} images"
    elif video is not None:
        got, what = views_from_video(video, finder, max_views, progress), f"{video}: of {{n}} frames examined"
    else:
        assert device is not None   # exactly one source was given
        got = views_from_device(int(device), finder, max_views, device_interval_s, device_seconds, device_size,
                                progress)
        what = f"camera device {device}: of {{n}} frames examined"
    where = what.format(n=got.examined)
    if got.with_board == 0:
        raise SessionContentError(f"{where}, none shows the board with >= {finder.min_corners} corners "
                                  f"({board_spec(board)}); check {{board}} and that the whole board is sharp and lit",
                                  parameter="board", value=board_spec(board))
    if len(got.views) < min_views:
        raise SessionContentError(f"{where}, {got.with_board} show the board with >= {finder.min_corners} corners "
                                  f"({len(got.views)} distinct views); need at least {min_views} "
                                  f"(better {RECOMMENDED_VIEWS}-40, from different angles and distances)")
    views = spread(got.views, max_views)
    assert got.size is not None   # set by the first view found
    result = calibrate_views(views, got.size, board)
    result.frames_examined, result.frames_with_board, result.skipped = got.examined, got.with_board, got.skipped
    return result
