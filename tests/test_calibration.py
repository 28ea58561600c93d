"""Camera calibration, the ChArUco board and the marker PNG (phonepose/calibration, docs/calibration.md).

The calibration is checked against a camera we know: views of the default board are rendered
through a known K and plumb_bob distortion (inverse-mapped per pixel, 2x supersampled, with sensor
noise), then calibrated through the API, ``--images`` and ``--video`` (MJPG). Also against real
photos: OpenCV's ChArUco tutorial images (already in tests/data/opencv_contrib for the marker tests)
and the intrinsics OpenCV's own sample calibrated from them.

``python tests/test_calibration.py`` prints the numbers quoted in docs/calibration.md.
"""

from __future__ import annotations

import io
import pathlib
import time

import cv2
import numpy as np
import pytest

from phonepose.calibration import load_calibration, save_calibration
from phonepose.calibration.board import DEFAULT_BOARD, BoardSpec, board_png, board_spec, parse_board_spec, render_board
from phonepose.calibration.calibrate import BoardFinder, calibrate_camera, calibrate_views
from phonepose.calibration.marker_image import marker_image, marker_png
from phonepose.errors import ConfigError, InputFileError, SessionContentError

DATA = pathlib.Path(__file__).parent / "data" / "opencv_contrib"

# The synthetic camera: a 640x480 webcam with clear barrel distortion and a principal point off centre.
SIZE = (640, 480)
K_TRUE = np.array([[612.0, 0.0, 329.0], [0.0, 607.0, 236.5], [0.0, 0.0, 1.0]])
D_TRUE = np.array([-0.26, 0.10, 0.0012, -0.0015, -0.02])
NOISE_DN = 2.0
N_VIEWS = 30
SS = 2              # supersampling: render at 2x, average down (anti-aliased edges, as a lens gives)
TEX_PX_PER_SQUARE = 100


def _undistort(points, K, D, P=None):
    """cv2.undistortPoints iterated to convergence (OpenCV 4: undistortPointsIter; 5: a criteria argument)."""
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    if hasattr(cv2, "undistortPointsIter"):
        return cv2.undistortPointsIter(points, K, D, None, P, crit)
    return cv2.undistortPoints(points, K, D, R=None, P=P, criteria=crit)


def _rot(rx: float, ry: float, rz: float) -> np.ndarray:
    return cv2.Rodrigues(np.array([rx, 0, 0.0]))[0] @ cv2.Rodrigues(np.array([0, ry, 0.0]))[0] @ \
        cv2.Rodrigues(np.array([0, 0, rz]))[0]


def synth_poses(n: int, seed: int = 0, board: BoardSpec = DEFAULT_BOARD) -> list[tuple[np.ndarray, np.ndarray]]:
    """Board poses (R, t: board -> camera, metres) a person would show: centre anywhere in the image,
    30-60 cm away, tilted up to 40 degrees about x and y and turned up to 25 degrees."""
    rng = np.random.default_rng(seed)
    centre_b = np.array([board.size_mm[0] / 2000, board.size_mm[1] / 2000, 0.0])
    poses = []
    for _ in range(n):
        z = rng.uniform(0.30, 0.60)
        u, v = rng.uniform(0.2, 0.8) * SIZE[0], rng.uniform(0.2, 0.8) * SIZE[1]
        centre_c = z * np.array([(u - K_TRUE[0, 2]) / K_TRUE[0, 0], (v - K_TRUE[1, 2]) / K_TRUE[1, 1], 1.0])
        R = _rot(*np.radians([rng.uniform(-40, 40), rng.uniform(-40, 40), rng.uniform(-25, 25)]))
        poses.append((R, centre_c - R @ centre_b))
    return poses


class Renderer:
    """Images of the board through K_TRUE, D_TRUE.

    Inverse mapping: each output pixel is undistorted (cv2.undistortPoints iterated to 1e-10),
    its ray intersected with the board plane (the board->normalised-image homography [r1 r2 t]
    inverted), and the board texture sampled there with cv2.remap. OpenCV has no function that
    renders a plane through a distorting camera, hence this.
    """

    def __init__(self, board: BoardSpec = DEFAULT_BOARD):
        self.board = board
        self.margin = TEX_PX_PER_SQUARE
        w = board.squares_x * TEX_PX_PER_SQUARE + 2 * self.margin
        h = board.squares_y * TEX_PX_PER_SQUARE + 2 * self.margin
        self.texture = board.opencv().generateImage((w, h), marginSize=self.margin, borderBits=1)
        self.px_per_m = TEX_PX_PER_SQUARE / (board.square_mm / 1000)
        # Output pixel centres of the SS x image in 1x pixel coordinates (1x pixel i spans SS pixels).
        xs = (np.arange(SIZE[0] * SS) - (SS - 1) / 2) / SS
        ys = (np.arange(SIZE[1] * SS) - (SS - 1) / 2) / SS
        grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 1, 2)
        self.rays = _undistort(grid, K_TRUE, D_TRUE).astype(np.float32)      # normalised image coordinates
        self.texture_f = self.texture.astype(np.float32)

    def render(self, R: np.ndarray, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        H = np.column_stack([R[:, 0], R[:, 1], t])          # board (X, Y, 1) -> normalised image
        # board metres -> texture: texture pixel k spans [k, k+1), so coordinate c is sampled at index c - 0.5
        to_tex = np.array([[self.px_per_m, 0, self.margin - 0.5], [0, self.px_per_m, self.margin - 0.5], [0, 0, 1]])
        maps = cv2.perspectiveTransform(self.rays, to_tex @ np.linalg.inv(H)).reshape(SIZE[1] * SS, SIZE[0] * SS, 2)
        behind = (self.rays.reshape(-1, 2) @ np.linalg.inv(H)[2, :2] + np.linalg.inv(H)[2, 2]) <= 0
        maps.reshape(-1, 2)[behind] = -1e4                  # rays that meet the plane behind the camera see no board
        big = cv2.remap(self.texture_f, maps, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                        borderValue=140.0)
        img = cv2.resize(big, SIZE, interpolation=cv2.INTER_AREA)
        img = 30 + img * (200 / 255)                         # print contrast, not pure 0/255
        return np.clip(img + rng.normal(0, NOISE_DN, img.shape), 0, 255).round().astype(np.uint8)


def synth_images(n: int = N_VIEWS, seed: int = 0) -> tuple[list[np.ndarray], list]:
    renderer, rng = Renderer(), np.random.default_rng(seed + 1000)
    poses = synth_poses(n, seed)
    return [renderer.render(R, t, rng) for R, t in poses], poses


def recovery_errors(K: np.ndarray, D: np.ndarray) -> dict[str, float]:
    return {"fx_%": 100 * (K[0, 0] / K_TRUE[0, 0] - 1), "fy_%": 100 * (K[1, 1] / K_TRUE[1, 1] - 1),
            "cx_px": K[0, 2] - K_TRUE[0, 2], "cy_px": K[1, 2] - K_TRUE[1, 2], "k1": D[0] - D_TRUE[0],
            "k2": D[1] - D_TRUE[1]}


def field_error_px(K: np.ndarray, D: np.ndarray, frac: float = 0.8) -> float:
    """Largest distance, over the central ``frac`` of the image, between where the true and the
    estimated model put the same ray (focal, principal point and distortion errors together)."""
    W, H = SIZE
    m = (1 - frac) / 2
    grid = np.stack(np.meshgrid(np.linspace(m * (W - 1), (1 - m) * (W - 1), 17),
                                np.linspace(m * (H - 1), (1 - m) * (H - 1), 13)), -1).reshape(-1, 1, 2)
    a = _undistort(grid, K_TRUE, D_TRUE, K_TRUE)
    b = _undistort(grid, K, D, K_TRUE)
    return float(np.linalg.norm((a - b).reshape(-1, 2), axis=1).max())


def assert_recovered(K: np.ndarray, D: np.ndarray, rms: float, jpeg: bool = False) -> None:
    # Measured on 5 seeds of this set (docs/calibration.md): |fx|, |fy| <= 0.16 %, |cx|, |cy| <= 0.77 px,
    # |k1| <= 0.0041, field error <= 1.33 px, RMS 0.08-0.09 px (PNG). OpenCV's own 1-sigma here is
    # 0.4-0.6 px on fx, 0.5-0.8 px on cx/cy, 0.003 on k1. Bounds: about 3 sigma.
    e = recovery_errors(K, D)
    assert abs(e["fx_%"]) < 0.4 and abs(e["fy_%"]) < 0.4, e
    assert abs(e["cx_px"]) < 2.0 and abs(e["cy_px"]) < 2.0, e
    assert abs(e["k1"]) < 0.012, e
    assert field_error_px(K, D) < 2.0
    assert rms < (0.3 if jpeg else 0.15)


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    images, poses = synth_images()
    folder = tmp_path_factory.mktemp("views")
    for i, img in enumerate(images):
        cv2.imwrite(str(folder / f"view_{i:02d}.png"), img)
    return images, poses, folder


@pytest.fixture(scope="module")
def synthetic_video(synthetic, tmp_path_factory):
    """An MJPG .avi: each view held for 2 frames, as a hand pausing, with a frame of empty wall between."""
    images, _, _ = synthetic
    path = tmp_path_factory.mktemp("video") / "board.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 15, SIZE, isColor=False)
    assert writer.isOpened()
    blank = np.full((SIZE[1], SIZE[0]), 140, np.uint8)
    for img in images:
        for frame in (img, img, blank):
            writer.write(frame)
    writer.release()
    return path


# --- the synthetic views are right ---------------------------------------------------------------

def test_detected_corners_are_where_the_known_camera_projects_them(synthetic):
    images, poses, _ = synthetic
    finder = BoardFinder()
    errs, found = [], 0
    for img, (R, t) in zip(images, poses, strict=True):
        view = finder.find(img, "v")
        if view is None:
            continue
        found += 1
        proj, _ = cv2.projectPoints(view.object_points.astype(np.float64), cv2.Rodrigues(R)[0], t, K_TRUE, D_TRUE)
        errs.append(proj.reshape(-1, 2) - view.image_points)
    errs = np.concatenate(errs)
    dist = np.linalg.norm(errs, axis=1)
    assert found >= 25
    # measured: RMS 0.099 px, max 0.51 px, mean (-0.011, -0.007) px. A rendering or convention error
    # (half a pixel, the board's axes) would show here as a bias of >= 0.5 px.
    assert np.sqrt(np.mean(dist ** 2)) < 0.15 and dist.max() < 0.8
    assert np.all(np.abs(errs.mean(axis=0)) < 0.05)


# --- calibration recovers the known camera -------------------------------------------------------

def test_calibrate_views_recovers_the_known_camera(synthetic):
    images, _, _ = synthetic
    finder = BoardFinder()
    views = [v for v in (finder.find(img, f"v{i}") for i, img in enumerate(images)) if v is not None]
    result = calibrate_views(views, SIZE)
    assert_recovered(result.K, result.D, result.rms_px)
    assert len(result.per_view_rms_px) == len(views) == len(result.views)
    assert result.per_view_rms_px.max() < 0.3
    assert np.all(result.std_intrinsics[:4] < 1.0)      # OpenCV's own uncertainty agrees: well constrained


def test_cli_images_recovers_the_known_camera_and_writes_the_file(synthetic, tmp_path, cli):
    _, _, folder = synthetic
    out = tmp_path / "cam.yaml"
    code, stdout, err = cli("calibrate-camera", "--images", str(folder), "--out", str(out), "-q")
    assert code == 0, err
    calib = load_calibration(out)
    assert (calib.width, calib.height) == SIZE
    assert parse_board_spec(calib.board) == DEFAULT_BOARD
    assert_recovered(calib.K, calib.D, calib.reprojection_error_px)
    assert "RMS reprojection error" in stdout and f"{calib.K[0, 0]:.2f}" in stdout
    assert "warning" not in err


def test_photos_in_other_formats_and_exif_orientations_give_the_same_camera(synthetic, tmp_path, cli):
    """Photos as cameras and tools save them: 16-bit PNG, RGBA, palette, TIFF, BMP, WebP, and JPEG whose EXIF
    orientation says "turn 90°" (a phone held upright). OpenCV applied the tag: half the folder tagged was refused as
    two sizes, all of it calibrated a 480x640 camera (fx and fy, cx and cy swapped) that no video frame has. The
    calibration is of the stored pixels, as a video's; every lossless format gives the PNG run's numbers exactly."""
    from PIL import Image

    images, _, folder = synthetic
    code, _, err = cli("calibrate-camera", "--images", str(folder), "--out", str(tmp_path / "png.yaml"), "-q")
    assert code == 0, err
    reference = load_calibration(tmp_path / "png.yaml")
    writers = {
        "png16": lambda p, g: cv2.imwrite(str(p.with_suffix(".png")), g.astype(np.uint16) * 257),
        "rgba": lambda p, g: cv2.imwrite(str(p.with_suffix(".png")), cv2.cvtColor(g, cv2.COLOR_GRAY2BGRA)),
        "palette": lambda p, g: Image.fromarray(g).convert("P").save(p.with_suffix(".png")),
        "tiff": lambda p, g: cv2.imwrite(str(p.with_suffix(".tif")), g),
        "bmp": lambda p, g: cv2.imwrite(str(p.with_suffix(".bmp")), g),
        "webp": lambda p, g: cv2.imwrite(str(p.with_suffix(".webp")), g, [cv2.IMWRITE_WEBP_QUALITY, 101]),
    }
    for name, write in writers.items():
        sub = tmp_path / name
        sub.mkdir()
        for i, g in enumerate(images):
            write(sub / f"v{i:02d}", g)
        code, _, err = cli("calibrate-camera", "--images", str(sub), "--out", str(tmp_path / f"{name}.yaml"), "-q")
        assert code == 0, (name, err)
        got = load_calibration(tmp_path / f"{name}.yaml")
        assert np.array_equal(got.K, reference.K) and np.array_equal(got.D, reference.D), name
    results = []
    for tagged in ("half", "all"):
        sub = tmp_path / f"exif-{tagged}"
        sub.mkdir()
        for i, g in enumerate(images):
            image = Image.fromarray(g)
            exif = image.getexif()
            if tagged == "all" or i % 2:
                exif[0x0112] = 6
            image.save(sub / f"v{i:02d}.jpg", quality=95, exif=exif)
        code, _, err = cli("calibrate-camera", "--images", str(sub), "--out", str(tmp_path / f"{tagged}.yaml"), "-q")
        assert code == 0, (tagged, err)
        got = load_calibration(tmp_path / f"{tagged}.yaml")
        assert (got.width, got.height) == SIZE
        assert_recovered(got.K, got.D, got.reprojection_error_px, jpeg=True)
        results.append(got)
    assert np.array_equal(results[0].K, results[1].K)      # the tags change nothing


def test_cli_video_recovers_the_known_camera(synthetic_video, tmp_path, cli):
    out = tmp_path / "cam.yaml"
    code, stdout, err = cli("calibrate-camera", "--video", str(synthetic_video), "--out", str(out), "-q")
    assert code == 0, err
    calib = load_calibration(out)
    assert_recovered(calib.K, calib.D, calib.reprojection_error_px, jpeg=True)
    # each pose is held for 2 frames: the repeated frames are not counted as new views
    views_used = int(stdout.split("views used")[1].split()[1])
    assert N_VIEWS - 5 <= views_used <= N_VIEWS


def test_device_path_with_a_stand_in_camera(synthetic_video, monkeypatch):
    """--camera cannot be tested without a camera: the video stands in for it (same capture loop)."""
    from phonepose.calibration import calibrate as mod

    monkeypatch.setattr(mod, "_open_device", lambda index, size: cv2.VideoCapture(str(synthetic_video)))
    result = calibrate_camera(device=0, max_views=12, device_interval_s=0.0)
    assert len(result.views) == 12                      # stops at --max-views
    e = recovery_errors(result.K, result.D)
    assert abs(e["fx_%"]) < 1.0 and abs(e["cx_px"]) < 3.0


def test_unreadable_image_is_a_warning_and_few_views_are_flagged(synthetic, tmp_path, cli):
    images, _, _ = synthetic
    folder = tmp_path / "five"
    folder.mkdir()
    for i in range(5):
        cv2.imwrite(str(folder / f"v{i}.png"), images[i])
    (folder / "broken.png").write_bytes(b"not a png")
    code, stdout, err = cli("calibrate-camera", "-q", "--images", str(folder), "--out", str(tmp_path / "c.yaml"))
    assert code == 0, err
    lines = err.strip().splitlines()
    assert "phonepose: warning: broken.png: not an image phonepose can read" in lines
    assert any("only 5 views" in line for line in lines)
    assert all(line.startswith("phonepose: warning: ") for line in lines)
    assert load_calibration(tmp_path / "c.yaml").width == SIZE[0]


def test_more_views_than_max_views_are_spread_evenly(synthetic):
    _, _, folder = synthetic
    result = calibrate_camera(images=folder, max_views=10)
    assert len(result.views) == 10 and result.frames_with_board >= 25
    idx = [int(name[5:7]) for name in result.views]
    assert idx[0] <= 1 and idx[-1] >= N_VIEWS - 2       # from the whole sequence, not its first 10


# --- real photos: OpenCV's ChArUco tutorial images ----------------------------------------------

def test_opencv_tutorial_photos_give_opencvs_own_calibration():
    """img_00..03 (5x7 board, 40 mm squares, 20 mm DICT_6X6_250 markers); reference: the intrinsics
    OpenCV's calibrate_camera_charuco sample got from the same photos (RMS 0.18 px). Measured:
    RMS 0.188 px, fx +1.06 %, fy +1.00 %, cx -0.5 px, cy -2.1 px (4 views: OpenCV's own
    1-sigma on fx is 16 px = 3.5 %)."""
    fs = cv2.FileStorage(str(DATA / "tutorial_camera_charuco.yml"), cv2.FILE_STORAGE_READ)
    K_ref, rms_ref = fs.getNode("camera_matrix").mat(), fs.getNode("avg_reprojection_error").real()
    fs.release()
    board = parse_board_spec("squares=5x7 square_mm=40 marker_mm=20 dictionary=DICT_6X6_250")
    folder = DATA / "images"
    finder = BoardFinder(board)
    views = [finder.find(cv2.imread(str(folder / f"img_0{i}.jpg")), f"img_0{i}") for i in range(4)]
    assert all(v is not None and len(v.ids) == 24 for v in views)
    result = calibrate_views(views, (640, 480), board)
    assert abs(result.rms_px - rms_ref) < 0.02
    assert np.all(np.abs(result.K[:2, :2].diagonal() / K_ref[:2, :2].diagonal() - 1) < 0.02)
    assert np.all(np.abs(result.K[:2, 2] - K_ref[:2, 2]) < 4.0)


# --- file, board, marker -------------------------------------------------------------------------

def test_save_load_round_trip(tmp_path):
    from phonepose.calibration.calibrate import CalibrationResult

    r = CalibrationResult(K=K_TRUE.copy(), D=D_TRUE.copy(), width=640, height=480, rms_px=0.123,
                          per_view_rms_px=np.array([0.1]), views=["a"], corners_per_view=[24],
                          std_intrinsics=np.zeros(9))
    save_calibration(tmp_path / "c.yaml", r.to_file())
    back = load_calibration(tmp_path / "c.yaml")
    assert np.array_equal(back.K, K_TRUE) and np.array_equal(back.D, D_TRUE)
    assert (back.width, back.height, back.reprojection_error_px) == (640, 480, 0.123)
    assert parse_board_spec(back.board) == DEFAULT_BOARD


ROS_CAMERA_INFO = """image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [612.0, 0.0, 329.0, 0.0, 607, 236.5, 0.0, 0.0, 1.0]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.26, 0.1, 0.0012, -0.0015, -0.02]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
projection_matrix:
  rows: 3
  cols: 4
  data: [612.0, 0.0, 329.0, 0.0, 0.0, 607.0, 236.5, 0.0, 0.0, 0.0, 1.0, 0.0]
"""


KALIBR_CAMCHAIN = """cam0:
  cam_overlaps: []
  camera_model: pinhole
  distortion_coeffs: [-0.26, 0.1, 0.0012, -0.0015]
  distortion_model: radtan
  intrinsics: [612.0, 607.0, 329.0, 236.5]
  resolution: [640, 480]
  rostopic: /cam0/image_raw
"""


def _opencv_file(path: pathlib.Path, D: np.ndarray, header: str | None = None, **more: str) -> pathlib.Path:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", K_TRUE)
    fs.write("distortion_coefficients", D)
    for key, value in more.items():
        fs.write(key, value)
    fs.release()
    if header is not None:      # OpenCV 3 wrote "%YAML:1.0" (no "---"); OpenCV 4+ writes "%YAML 1.2" and "---"
        lines = path.read_text().splitlines()
        path.write_text("\n".join([header] + lines[2:]) + "\n")
    return path


def test_calibration_files_of_other_tools_read_exactly_or_refused(tmp_path):
    """OpenCV's FileStorage (YAML as OpenCV 3 and 4+ write it, XML, D as a column), ROS's camera_info YAML (no
    !!opencv-matrix tag: "camera_matrix is not a matrix of numbers" before) and a Kalibr camchain of one pinhole camera
    (refused before) give K and D exactly. A lens that is not
    plumb_bob was read as plumb_bob's first 5 numbers, silently: OpenCV's rational model (k4-k6 dropped), a fisheye."""
    d5 = D_TRUE.reshape(1, 5)
    for path in (_opencv_file(tmp_path / "c4.yaml", d5), _opencv_file(tmp_path / "c3.yaml", d5, "%YAML:1.0"),
                 _opencv_file(tmp_path / "c.xml", d5), _opencv_file(tmp_path / "col.yaml", D_TRUE.reshape(5, 1)),
                 _opencv_file(tmp_path / "r0.yaml", np.hstack([d5, np.zeros((1, 3))])),
                 _write(tmp_path / "ros.yaml", ROS_CAMERA_INFO),
                 _write(tmp_path / "ros8.yaml", ROS_CAMERA_INFO.replace("plumb_bob", "rational_polynomial").replace(
                     "cols: 5\n  data: [-0.26, 0.1, 0.0012, -0.0015, -0.02]",
                     "cols: 8\n  data: [-0.26, 0.1, 0.0012, -0.0015, -0.02, 0, 0, 0]"))):
        c = load_calibration(path)
        assert (c.width, c.height) == (640, 480), path.name
        assert np.array_equal(c.K, K_TRUE) and np.array_equal(c.D, D_TRUE), path.name
    kalibr = _write(tmp_path / "camchain.yaml", KALIBR_CAMCHAIN)
    c = load_calibration(kalibr)
    assert (c.width, c.height) == (640, 480) and np.array_equal(c.K, K_TRUE)
    assert np.array_equal(c.D, [*D_TRUE[:4], 0.0])          # radtan: k1 k2 p1 p2, no k3
    refused = {
        _write(tmp_path / "two.yaml", KALIBR_CAMCHAIN + KALIBR_CAMCHAIN.replace("cam0", "cam1")):
            "two.yaml: a Kalibr camchain of several cameras (cam0, cam1, ...): give a file with the display camera "
            "alone, as cam0",
        _write(tmp_path / "kfish.yaml", KALIBR_CAMCHAIN.replace("radtan", "equidistant")):
            "kfish.yaml: distortion model 'equidistant': phonepose models plumb_bob",
        _write(tmp_path / "omni.yaml", KALIBR_CAMCHAIN.replace("pinhole", "omni")):
            "omni.yaml: Kalibr camera_model 'omni': phonepose models a pinhole camera only",
        _write(tmp_path / "k3.yaml", KALIBR_CAMCHAIN.replace("intrinsics: [612.0, 607.0, 329.0, 236.5]",
                                                            "intrinsics: [612.0, 607.0, 329.0]")):
            "k3.yaml: cam0.intrinsics is not a list of 4 numbers",
        _opencv_file(tmp_path / "r8.yaml", np.hstack([d5, [[0.3, 0.1, 0.02]]])):
            "r8.yaml: 8 distortion coefficients, of which the 6th is not zero (OpenCV's rational or thin-prism model): "
            "phonepose models plumb_bob (k1 k2 p1 p2 k3) only; calibrate without CALIB_RATIONAL_MODEL, or with "
            "phonepose calibrate-camera",
        _opencv_file(tmp_path / "t14.xml", np.hstack([d5, np.zeros((1, 8)), [[0.01]]])):
            "t14.xml: 14 distortion coefficients, of which the 14th is not zero",
        _write(tmp_path / "fisheye.yaml", ROS_CAMERA_INFO.replace("plumb_bob", "equidistant").replace(
            "cols: 5\n  data: [-0.26, 0.1, 0.0012, -0.0015, -0.02]", "cols: 4\n  data: [0.1, 0.01, 0.001, 0.0]")):
            "fisheye.yaml: distortion model 'equidistant': phonepose models plumb_bob (k1 k2 p1 p2 k3) only; "
            "calibrate the camera with phonepose calibrate-camera",
        _write(tmp_path / "text.yaml", ROS_CAMERA_INFO.replace("data: [612.0,", "data: [fx,")):
            "text.yaml: camera_matrix is not a matrix of numbers",
    }
    for path, text in refused.items():
        with pytest.raises(InputFileError) as e:
            load_calibration(path)
        assert str(e.value).startswith(f"{path}") and text in str(e.value), str(e.value)


def _write(path: pathlib.Path, text: str) -> pathlib.Path:
    path.write_text(text)
    return path


def test_a_file_that_is_not_yaml_is_one_input_error(tmp_path):
    """opencv-python 5.0 raises SystemError on a YAML parse error: it must still be one clear line."""
    from phonepose.errors import InputFileError

    (tmp_path / "notes.yaml").write_text("these are my notes, not a calibration\n")
    with pytest.raises(InputFileError, match=r"notes\.yaml: not an OpenCV YAML/XML calibration file$"):
        load_calibration(tmp_path / "notes.yaml")
    with pytest.raises(InputFileError, match=r"none\.yaml: no such calibration file$"):
        load_calibration(tmp_path / "none.yaml")


def test_board_spec_round_trip_and_errors():
    b = BoardSpec(9, 6, 25.0, 18.5, "DICT_6X6_250", legacy=True)
    assert parse_board_spec(board_spec(b)) == b
    assert parse_board_spec("squares=5x7") == BoardSpec(5, 7)
    for bad in ("squares=7", "square_mm=abc", "colour=red", "marker_mm=40", "dictionary=DICT_NOPE",
                "squares=30x30 dictionary=DICT_4X4_50"):
        with pytest.raises(ConfigError):
            parse_board_spec(bad)


@pytest.mark.parametrize("dpi", [150, 300])
def test_board_png_has_the_true_size(dpi):
    from PIL import Image

    png = Image.open(io.BytesIO(board_png(dpi=dpi)))
    assert png.size == (round(297 / 25.4 * dpi), round(210 / 25.4 * dpi))     # A4 landscape
    assert png.info["dpi"][0] == pytest.approx(dpi, abs=0.05)     # PNG stores pixels per metre, an integer
    # the board is found in the page, and its squares are 30 mm at that dpi
    page = render_board(dpi=dpi)
    finder = BoardFinder()
    view = finder.find(page, "page")
    assert view is not None and len(view.ids) == DEFAULT_BOARD.n_corners
    order = np.argsort(view.ids)
    pts = view.image_points[order].reshape(DEFAULT_BOARD.squares_y - 1, DEFAULT_BOARD.squares_x - 1, 2)
    square_px = np.diff(pts[..., 0], axis=1).mean()
    assert square_px == pytest.approx(30 / 25.4 * dpi, abs=0.5)


def test_board_does_not_fit(tmp_path, cli):
    code, _, err = cli("board", "--board", "squares=12x8 square_mm=30 marker_mm=22",
                       "--out", str(tmp_path / "b.png"))
    assert code == 5 and err.count("\n") == 1 and "does not fit" in err
    code, _, err = cli("board", "--board", "squares=12x8 square_mm=30 marker_mm=22", "--paper", "a3",
                       "--out", str(tmp_path / "b.png"))
    assert code == 0 and (tmp_path / "b.png").stat().st_size > 0


def test_marker_png_decodes_to_its_id():
    for dictionary, marker_id, side in (("DICT_4X4_50", 7, 400), ("DICT_4X4_50", 0, 97), ("DICT_5X5_100", 42, 300)):
        img = cv2.imdecode(np.frombuffer(marker_png(dictionary, marker_id, side), np.uint8), cv2.IMREAD_GRAYSCALE)
        assert img.shape[0] == img.shape[1] > side
        assert img[0].min() == 255 and img[:, 0].min() == 255      # white quiet zone all round
        det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)))
        corners, ids, _ = det.detectMarkers(img)
        assert ids is not None and ids.ravel().tolist() == [marker_id]
        q = (img.shape[0] - side) / 2                               # the black square is side px
        assert np.allclose(corners[0].reshape(4, 2), [[q, q], [q + side, q], [q + side, q + side], [q, q + side]],
                           atol=1.5)


def test_marker_defaults_are_the_simulators():
    import tomllib

    import phonepose.record.sim as sim

    cfg = tomllib.loads((pathlib.Path(sim.__file__).parent / "default.toml").read_text())["marker"]
    img = marker_image()
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, cfg["dictionary"])))
    assert det.detectMarkers(img)[1].ravel().tolist() == [cfg["id"]]
    assert img.shape == (400 + 2 * 67, 400 + 2 * 67)
    with pytest.raises(ConfigError):
        marker_image(marker_id=50)
    with pytest.raises(ConfigError):
        marker_image(side_px=5)


def test_marker_cli(tmp_path, cli):
    code, stdout, _ = cli("marker", "--out", str(tmp_path / "m.png"), "--id", "3", "--pixels", "200")
    assert code == 0 and "id 3" in stdout
    img = cv2.imread(str(tmp_path / "m.png"), cv2.IMREAD_GRAYSCALE)
    assert cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)).detectMarkers(img)[1] \
        .ravel().tolist() == [3]


# --- errors: one line, documented exit code -------------------------------------------------------

def test_marker_cli_bad_id(tmp_path, cli):
    code, _, err = cli("marker", "--id", "99", "--out", str(tmp_path / "m.png"))
    assert code == 5 and err == "phonepose: error: marker id 99: DICT_4X4_50 has ids 0..49\n"
    assert not (tmp_path / "m.png").exists()


def _noise_images(folder: pathlib.Path, n: int) -> pathlib.Path:
    folder.mkdir()
    rng = np.random.default_rng(3)
    for i in range(n):
        cv2.imwrite(str(folder / f"n{i}.png"), rng.integers(0, 255, (120, 160), np.uint8))
    return folder


ERROR_CASES = [
    ("empty directory", lambda d: ["--images", str(_mk(d / "empty"))], 2, "no images"),
    ("missing directory", lambda d: ["--images", str(d / "nope")], 2, "no such directory"),
    ("images without the board", lambda d: ["--images", str(_noise_images(d / "noise", 3))], 4, "none shows the board"),
    ("images of two sizes", lambda d: ["--images", str(_two_sizes(d / "sizes"))], 4, "one camera resolution"),
    ("both --video and --images", lambda d: ["--images", str(d), "--video", str(d / "v.avi")], 5, "exactly one"),
    ("no source", lambda d: [], 5, "exactly one"),
    ("video that is not a video", lambda d: ["--video", str(_text(d / "v.avi"))], 2, "not a video"),
    ("missing video", lambda d: ["--video", str(d / "nope.mp4")], 2, "no such file"),
    ("camera that does not exist", lambda d: ["--camera", "57"], 2, "cannot be opened"),
    ("bad --board", lambda d: ["--images", str(d), "--board", "squares=7"], 5, "board spec"),
    ("bad --size", lambda d: ["--camera", "0", "--size", "big"], 5, "WIDTHxHEIGHT"),
    ("--size without --camera", lambda d: ["--images", str(d), "--size", "640x480"], 5, "--camera only"),
    ("--out in a missing directory", lambda d: ["--images", str(d), "--out", str(d / "no" / "c.yaml")], 6,
     "does not exist"),
]


def _two_sizes(folder: pathlib.Path) -> pathlib.Path:
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), np.full((48, 64), 128, np.uint8))
    cv2.imwrite(str(folder / "b.png"), np.full((60, 80), 128, np.uint8))
    return folder


def _mk(p: pathlib.Path) -> pathlib.Path:
    p.mkdir()
    return p


def _text(p: pathlib.Path) -> pathlib.Path:
    p.write_text("not a video\n")
    return p


@pytest.mark.parametrize("case", ERROR_CASES, ids=[c[0] for c in ERROR_CASES])
def test_errors_are_one_line(case, tmp_path, cli):
    _, argv, code, text = case
    args = argv(tmp_path)
    if "--out" not in args:
        args += ["--out", str(tmp_path / "cam.yaml")]
    got, _, err = cli("calibrate-camera", "-q", *args)
    assert got == code, err
    assert err.count("\n") == 1 and err.startswith("phonepose: error: ") and text in err, err
    assert not (tmp_path / "cam.yaml").exists()


@pytest.mark.parametrize("suffix", [".mp4", ".mkv", ".mp3"])
def test_ffmpegs_own_lines_stay_off_the_terminal(suffix, tmp_path):
    """OpenCV's video reader is FFmpeg, which writes to file descriptor 2 itself ("moov atom not found"
    for a text file named .mp4): the user sees phonepose's one line only (logs.quiet_libraries)."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "OPENCV_FFMPEG_LOGLEVEL"}
    video = _text(tmp_path / f"v{suffix}")
    r = subprocess.run([sys.executable, "-m", "phonepose", "calibrate-camera", "-q", "--video", str(video),
                        "--out", str(tmp_path / "cam.yaml")], capture_output=True, text=True, env=env, timeout=300)
    assert (r.returncode, r.stderr) == (2, f"phonepose: error: {video}: not a video OpenCV can read\n")


def test_too_few_views_is_one_line(synthetic, tmp_path, cli):
    images, _, _ = synthetic
    folder = _mk(tmp_path / "three")
    for i in range(3):
        cv2.imwrite(str(folder / f"v{i}.png"), images[i])
    code, _, err = cli("calibrate-camera", "-q", "--images", str(folder), "--out", str(tmp_path / "c.yaml"))
    assert code == 4 and err.count("\n") == 1 and "need at least 4" in err, err


def measure(seeds: int = 5) -> None:
    """The numbers in docs/calibration.md: 30 views per seed, calibrated from PNGs and from an MJPG video."""
    import subprocess
    import sys
    import tempfile

    for seed in range(seeds):
        images, _ = synth_images(N_VIEWS, seed)
        with tempfile.TemporaryDirectory() as d:
            folder = pathlib.Path(d) / "views"
            folder.mkdir()
            for i, img in enumerate(images):
                cv2.imwrite(str(folder / f"view_{i:02d}.png"), img)
            video = pathlib.Path(d) / "board.avi"
            writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 15, SIZE, isColor=False)
            for img in images:
                for frame in (img, img, np.full_like(img, 140)):
                    writer.write(frame)
            writer.release()
            for label, source in (("png  ", ["--images", str(folder)]), ("mjpg ", ["--video", str(video)])):
                out = pathlib.Path(d) / "cam.yaml"
                t0 = time.perf_counter()
                subprocess.run([sys.executable, "-m", "phonepose", "calibrate-camera", *source, "--out", str(out),
                                "-q"], check=True, capture_output=True)
                wall = time.perf_counter() - t0
                c = load_calibration(out)
                e = recovery_errors(c.K, c.D)
                print(f"seed {seed} {label} RMS {c.reprojection_error_px:.3f} px, field {field_error_px(c.K, c.D):.2f} px, "
                      f"{wall:.1f} s; " + ", ".join(f"{k} {v:+.4f}" for k, v in e.items()))


def error_table() -> str:
    """The calibration rows of docs/reliability.md, from ERROR_CASES (temporary directory shortened)."""
    import subprocess
    import sys
    import tempfile

    rows = ["| bad input | command | exit | what the user sees (stderr) |", "|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as t:
        for name, argv, _, _ in ERROR_CASES:
            d = pathlib.Path(t) / name.replace(" ", "_").replace("-", "")
            d.mkdir()
            args = argv(d)
            if "--out" not in args:
                args += ["--out", str(d / "cam.yaml")]
            r = subprocess.run([sys.executable, "-m", "phonepose", "calibrate-camera", "-q", *args],
                               capture_output=True, text=True)
            line = r.stderr.strip().replace(str(d) + "/", "").replace(str(d), "DIR")
            rows.append(f"| {name} | `calibrate-camera` | {r.returncode} | `{line}` |")
    return "\n".join(rows)


if __name__ == "__main__":
    import sys

    print(error_table() if "--errors" in sys.argv else measure())


@pytest.mark.parametrize("copies,shift_px", [(12, 0), (8, 1), (6, 2)])
def test_copies_of_one_view_are_one_view_for_every_source(synthetic, tmp_path, copies, shift_px):
    """Copies of one photo, or near-copies (moved by ``shift_px``, re-encoded as JPEG), are one view whether given as
    photos or as a video's frames: --images took twelve copies as twelve views and calibrated from them."""
    images, _, _ = synthetic
    base = images[0]
    frames = [np.roll(base, k * shift_px, axis=1) if k % 2 else base for k in range(copies)]
    folder = tmp_path / "copies"
    folder.mkdir()
    for k, frame in enumerate(frames):
        (folder / f"c{k:02d}.jpg").write_bytes(cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 90 + k % 5])[1])
    video = tmp_path / "copies.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (base.shape[1], base.shape[0]))
    for frame in frames:
        writer.write(frame if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))
    writer.release()
    for source, what in (({"images": folder}, f"of {copies} images"), ({"video": video}, f"of {copies} frames")):
        with pytest.raises(SessionContentError, match=rf"{what}[a-z ]*, {copies} show the board with >= 8 corners "
                                                      r"\(1 distinct views\); need at least 4"):
            calibrate_camera(**source)
    # the same copies beside enough real views: used once, and each other copy named in a warning
    for i in range(1, 6):
        (folder / f"v{i}.png").write_bytes(cv2.imencode(".png", images[i])[1])
    result = calibrate_camera(images=folder)
    assert sorted(result.views) == ["c00.jpg"] + [f"v{i}.png" for i in range(1, 6)]
    assert [line.split(":")[0] for line in result.skipped] == [f"c{k:02d}.jpg" for k in range(1, copies)]
    assert all(line.endswith("the same view as c00.jpg (the board moved less than 2% of the image diagonal); not "
                             "used") for line in result.skipped)
