"""Values a user's files and options may hold: text inputs read within a bound, finite but absurd numbers
refused where they are read, never printed or written as metrics (docs/reliability.md, "Bad inputs tried").

The one-line errors themselves are cases of tests/test_reliability_cli.py (they generate the docs table);
these tests check what those cases cannot: what is still accepted, and how the checks read.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from phonepose.errors import InputFileError
from phonepose.files import read_text_input

BOM = b"\xef\xbb\xbf"
TUM = b"".join(b"%.1f %.3f %.3f 0 0 0 0 1\n" % (k / 10, k / 50, (k % 7) / 40) for k in range(40))


def test_read_text_input_stops_at_the_limit_and_at_the_first_nul(tmp_path):
    p = tmp_path / "t.txt"
    p.write_bytes(b"a" * 101)
    with pytest.raises(InputFileError, match=r"t\.txt: larger than 100 bytes, the most phonepose reads as a "
                                             r"trajectory file \(why\): check that it is the right file$"):
        read_text_input(p, "trajectory file", limit=100, note="why")
    assert read_text_input(p, "trajectory file", limit=101) == "a" * 101
    # a NUL far into the file (past the first chunk) is found where it is
    p.write_bytes(b"1 2 3\n" * 400_000 + b"\0" + b"x" * 10)
    with pytest.raises(InputFileError, match=r"not a trajectory file \(binary data: a NUL byte at byte 2400000\)$"):
        read_text_input(p, "trajectory file")
    p.write_bytes(BOM + "é\n".encode())
    assert read_text_input(p) == "é\n"


def test_a_byte_order_mark_is_accepted_in_tum_euroc_and_toml(tmp_path, cli):
    from phonepose.record.sim.config import load_config

    (tmp_path / "gt.txt").write_bytes(BOM + TUM)
    code, out, err = cli("evaluate", "--gt", tmp_path / "gt.txt", "--est", tmp_path / "gt.txt", "--json")
    assert code == 0 and err == "", err
    assert json.loads(out)["n_matched"] == 40
    csv = b"#timestamp,p_x,p_y,p_z,q_w,q_x,q_y,q_z\n" + b"".join(
        b"%d,%.3f,0,0,1,0,0,0\n" % (k * 10**8, k / 50) for k in range(40))
    (tmp_path / "gt.csv").write_bytes(BOM + csv)
    code, out, err = cli("evaluate", "--gt", tmp_path / "gt.csv", "--est", tmp_path / "gt.csv", "--gt-format", "euroc",
                         "--metric", "ape", "--json")
    assert code == 0 and err == "", err
    (tmp_path / "c.toml").write_bytes(BOM + b"[camera]\nrate_hz = 24\n")
    assert load_config(tmp_path / "c.toml").camera.rate_hz == 24


@pytest.mark.parametrize("encoding", ["utf-16", "utf-16-le", "utf-16-be"])
def test_utf16_text_with_its_byte_order_mark_is_read(tmp_path, cli, encoding):
    """Excel's "Unicode text" export (tab-separated) and Windows PowerShell's `>` write UTF-16 with a byte-order mark:
    it was refused as "binary data: a NUL byte at byte 3". Read as the same text; a NUL character in it is still
    binary data, and UTF-16 without its mark stays refused (nothing says it is text)."""
    import numpy as np

    from phonepose.calibration import load_calibration
    from phonepose.calibration.camera_file import CameraCalibrationFile, calibration_text

    text = TUM.decode().replace(" ", "\t").replace("\n", "\r\n")
    bom = {"utf-16": b"", "utf-16-le": b"\xff\xfe", "utf-16-be": b"\xfe\xff"}[encoding]
    (tmp_path / "gt.txt").write_bytes(bom + text.encode(encoding))
    assert read_text_input(tmp_path / "gt.txt") == text
    code, out, err = cli("evaluate", "--gt", tmp_path / "gt.txt", "--est", tmp_path / "gt.txt", "--metric", "ape",
                         "--json")
    assert code == 0 and json.loads(out)["n_matched"] == 40, err
    calib = CameraCalibrationFile(np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]), np.zeros(5), 640, 480)
    (tmp_path / "c.yaml").write_bytes(bom + calibration_text(calib).encode(encoding))
    assert load_calibration(tmp_path / "c.yaml").width == 640
    (tmp_path / "nul.txt").write_bytes(bom + "1 2\0".encode(encoding))
    with pytest.raises(InputFileError, match=r"nul\.txt: not a text file \(binary data: a NUL character at "
                                             r"character 3\)$"):
        read_text_input(tmp_path / "nul.txt")
    (tmp_path / "nobom.txt").write_bytes(text.encode("utf-16-le"))
    with pytest.raises(InputFileError, match=r"binary data: a NUL byte at byte 1\)$"):
        read_text_input(tmp_path / "nobom.txt")


def test_a_non_finite_metric_is_never_printed_nor_written(tmp_path, cli, monkeypatch):
    """Whatever still overflows is one line, never a NaN in the table or a failing --json."""
    from phonepose.evaluation import evo_metrics

    real = evo_metrics.evaluate_ape

    def overflowing(*args, **kwargs):
        result = real(*args, **kwargs)
        result["ape"]["rmse"] = math.inf
        return result

    monkeypatch.setattr(evo_metrics, "evaluate_ape", overflowing)
    (tmp_path / "gt.txt").write_bytes(TUM)
    for extra in ((), ("--json",)):
        code, out, err = cli("evaluate", "--gt", tmp_path / "gt.txt", "--est", tmp_path / "gt.txt", "--metric", "ape",
                             *extra)
        assert code == 4 and out == "", out
        assert err.strip().endswith("gt.txt are not finite numbers (ape.rmse): check the trajectories' values and "
                                    "units"), err
        assert len(err.strip().splitlines()) == 1


def test_georeferenced_trajectories_still_load(tmp_path, cli):
    """UTM-like coordinates (northing 5.4e6 m) are within the bound, and evaluate as well as near the origin."""
    rows = b"".join(b"%.1f %.3f %.3f 310.5 0 0 0 1\n" % (k / 10, 500000 + k / 50, 5400000 + (k % 7) / 40)
                    for k in range(40))
    (tmp_path / "utm.txt").write_bytes(rows)
    code, out, err = cli("evaluate", "--gt", tmp_path / "utm.txt", "--est", tmp_path / "utm.txt", "--json")
    assert code == 0 and err == "", err
    assert json.loads(out)["ate"]["trans_m"]["rmse"] < 1e-6


@pytest.mark.parametrize("body, message", [
    (b"- 1\n- 2\n", r"not an OpenCV YAML/XML calibration file \(its top level is a list"),
    (b"camera_matrix: [[1,0,0],[0,1,0],[0,0,1]]\n", r"camera_matrix is not a matrix \(found a list"),
    (b"camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [1,0,0,0,1,0,0,0,1]\n"
     b"distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [0,0,0,0,0]\n"
     b"image_width: wide\nimage_height: 480\n", r"image_width is not a number \(found text\)$"),
    (b"camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [1,0,0,0,1,0,0,0,1]\n"
     b"distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [0,0,0,0,0]\n"
     b"image_width: 1e300\nimage_height: 480\n", r"image size 1e\+300 x 480 px: expected whole pixels in \[1, 100000\]$"),
])
def test_a_camera_calibration_file_is_read_node_by_node(tmp_path, body, message):
    from phonepose.calibration import load_calibration

    (tmp_path / "c.yaml").write_bytes(b"%YAML:1.0\n---\n" + body)
    with pytest.raises(InputFileError, match=message):
        load_calibration(tmp_path / "c.yaml")


def _png_claiming(width: int, height: int) -> bytes:
    """A PNG whose header claims ``width`` x ``height`` px (OpenCV refuses to decode more than 2^30 px)."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(bytes(100))) + chunk(b"IEND", b""))


def _phonepose(*args, cwd: Path):
    """A real process: its stderr writes a non-UTF-8 name as the terminal shows it (backslash-escaped)."""
    return subprocess.run([sys.executable, "-m", "phonepose", *args], cwd=cwd, capture_output=True, text=True,
                          errors="backslashreplace")


def test_images_opencv_cannot_decode_and_names_that_are_not_utf8(tmp_path):
    """--images: a header claiming 60000x60000 px (an OpenCV assertion) is skipped with a warning, never decoded, and
    so is an empty file; an image whose name is not UTF-8 (cv2.imread: SIGSEGV) is read; a --video of such a name is one line."""
    import cv2
    from test_calibration import synth_images

    folder = tmp_path / "imgs"
    folder.mkdir()
    for i, image in enumerate(synth_images(6, seed=1)[0]):
        name = f"v{i}.png" if i else os.fsdecode(b"i\xfe.png")
        (folder / name).write_bytes(cv2.imencode(".png", image)[1].tobytes())
    (folder / "huge.png").write_bytes(_png_claiming(60000, 60000))
    (folder / "zero.png").write_bytes(b"")
    cut = cv2.imencode(".jpg", synth_images(1, seed=2)[0][0])[1].tobytes()
    (folder / "cut.jpg").write_bytes(cut[:len(cut) // 2] + b"\xff\xd9")
    r = _phonepose("calibrate-camera", "-q", "--images", "imgs", "--out", "c.yaml", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "phonepose: warning: huge.png: more than 178 Mpx by its header, more than the 80 Mpx phonepose decodes" \
        in r.stderr.splitlines()
    assert "phonepose: warning: zero.png: not an image phonepose can read" in r.stderr.splitlines()
    assert ("phonepose: warning: cut.jpg: damaged image data (Corrupt JPEG data: premature end of data segment); read "
            "as far as it goes") in r.stderr.splitlines()
    assert "Corrupt JPEG data" not in r.stderr.replace("(Corrupt JPEG data", "")    # libjpeg's own line is gone
    assert "6 with board / 7 read" in r.stdout
    (tmp_path / os.fsdecode(b"v\xfe.avi")).write_bytes(b"not a video")
    # named as an argument, the CLI refuses it before any work (cli/__init__.py); from Python, the reader does
    from phonepose.calibration.calibrate import opencv_path

    r = _phonepose("calibrate-camera", "-q", "--video", os.fsdecode(b"v\xfe.avi"), "--out", "c2.yaml", cwd=tmp_path)
    assert r.returncode == 5 and r.stdout == ""
    assert r.stderr == ("phonepose: error: the argument 'v\\xfe.avi' is not UTF-8 text (a file name in another "
                        "encoding?): rename the file with a UTF-8 name\n")
    with pytest.raises(InputFileError, match="OpenCV cannot open a video whose name is not UTF-8 text; rename it"):
        opencv_path(tmp_path / os.fsdecode(b"v\xfe.avi"), "a video")


def test_a_calibration_file_whose_name_is_not_utf8_is_read(tmp_path):
    """The YAML is parsed from memory: a non-UTF-8 name crashed cv2.FileStorage (SIGSEGV)."""
    from phonepose.calibration.gt_calibration import load_gt_calibration

    name = tmp_path / os.fsdecode(b"h\xfe.yaml")
    name.write_bytes(b"%YAML:1.0\n---\nformat: phonepose-gt-calibration\nversion: 1\ntime_offset_s: 0.25\n"
                     b"T_controller_gt: !!opencv-matrix\n   rows: 4\n   cols: 4\n   dt: d\n"
                     b"   data: [1,0,0,0, 0,1,0,0, 0,0,1,0.5, 0,0,0,1]\n")
    cal = load_gt_calibration(name)
    assert cal.time_offset_s == 0.25 and cal.T_controller_gt.translation[2] == 0.5


def test_record_rehearse_refuses_an_out_folder_opencv_cannot_write_into(tmp_path):
    r = _phonepose("record", "rehearse", "--out", os.fsdecode(b"o\xfe"), cwd=tmp_path)
    assert r.returncode == 5 and r.stderr == (
        "phonepose: error: the argument 'o\\xfe' is not UTF-8 text (a file name in another encoding?): rename the "
        "file with a UTF-8 name\n")
    assert list(tmp_path.iterdir()) == []


GT_OPTIONAL_KEYS = {b"format": b"format: phonepose-gt-calibration\n", b"version": b"version: 1\n",
                    b"time_offset_s": b"time_offset_s: 0.125\n", b"method": b"method: calibrate-gt\n",
                    b"sightings": b"sightings: 7\n", b"residual_mm": b"residual_mm: 2.5\n"}


@pytest.mark.parametrize("body_key, keys", [
    (body_key, keys) for n in range(len(GT_OPTIONAL_KEYS) + 1) for keys in itertools.combinations(GT_OPTIONAL_KEYS, n)
    for body_key in ("T_controller_gt", "T_controller_mocap") if body_key == "T_controller_gt" or b"format" not in keys],
    ids=lambda v: "+".join(k.decode() for k in v) or "matrix-only" if isinstance(v, tuple) else v)
def test_a_hand_written_gt_calibration_without_its_optional_keys_is_read(tmp_path, keys, body_key):
    """Every subset of the optional keys (a missing `version` was read as the int 0, whose `is_integer` is
    Python 3.12's): the values given, the documented defaults for the rest. A hand-written file without `format`
    names its matrix T_controller_gt or, as older hand-eye files do, T_controller_mocap."""
    from phonepose.calibration.gt_calibration import load_gt_calibration

    matrix = (f"{body_key}: !!opencv-matrix\n   rows: 4\n   cols: 4\n   dt: d\n"
              "   data: [1,0,0,0.25, 0,1,0,0, 0,0,1,-0.5, 0,0,0,1]\n").encode()
    (tmp_path / "gt.yaml").write_bytes(b"%YAML:1.0\n---\n" + b"".join(GT_OPTIONAL_KEYS[k] for k in keys) + matrix)
    cal = load_gt_calibration(tmp_path / "gt.yaml")
    assert cal.T_controller_gt.translation.tolist() == [0.25, 0.0, -0.5]
    assert cal.time_offset_s == (0.125 if b"time_offset_s" in keys else 0.0)
    assert cal.method == ("calibrate-gt" if b"method" in keys else "calibrate-hand-eye")
    assert cal.samples == (7 if b"sightings" in keys else 0)
    assert cal.residual_mm == 2.5 if b"residual_mm" in keys else math.isnan(cal.residual_mm)
    assert cal.version == (1 if b"version" in keys and b"format" in keys else 0)   # a version belongs to a format
    assert cal.T_world_display_vio is None


# ----------------------------------------------------------------------------- calibration values
def _k(fx=500.0, fy=500.0, cx=160.0, cy=120.0, bottom=(0.0, 0.0, 1.0)) -> list[float]:
    return [fx, 0.0, cx, 0.0, fy, cy, *bottom]


# (what, K, D, width, height, the problem every route names): degenerate values of each kind, generated around the
# bounds in pipeline/types.py
BAD_CAMERAS = [
    *((f"fx={fx:g}", _k(fx=fx), [0.0] * 5, 320, 240, f"focal lengths fx={show}, fy=500 px: expected 1 to 1000000 px")
      for fx, show in ((0.0, "0"), (1e-300, "1e-300"), (1e-30, "1e-30"), (0.999, "0.999"), (-500.0, "-500"),
                       (1e6 + 1, "1000001"), (1e300, "1e+300"))),
    ("fy=1e-30", _k(fy=1e-30), [0.0] * 5, 320, 240, "focal lengths fx=500, fy=1e-30 px: expected 1 to 1000000 px"),
    ("cx=1e300", _k(cx=1e300), [0.0] * 5, 320, 240, "principal point cx=1e+300, cy=120 px is not near the 320x240 image"),
    ("cy=-241", _k(cy=-241.0), [0.0] * 5, 320, 240, "principal point cx=160, cy=-241 px is not near the 320x240 image"),
    ("K[8]=1e-300", _k(bottom=(0.0, 0.0, 1e-300)), [0.0] * 5, 320, 240,
     "the camera matrix is not [[fx, s, cx], [0, fy, cy], [0, 0, 1]] (its rows 2 and 3 are 0 500 120; 0 0 1e-300)"),
    ("k1=1e300", _k(), [1e300, 0.0, 0.0, 0.0, 0.0], 320, 240,
     "distortion coefficient 1e+300 (the 1st) is beyond ±10000: not a plumb_bob lens's"),
    ("k3=-2e4", _k(), [0.0, 0.0, 0.0, 0.0, -2e4], 320, 240,
     "distortion coefficient -20000 (the 5th) is beyond ±10000: not a plumb_bob lens's"),
    ("size 1e9", _k(), [0.0] * 5, 10**9, 10**9, "image size 1000000000 x 1000000000 px: expected whole pixels in "
                                                 "[1, 100000]"),
]


def _calibration_yaml(K, D, width, height) -> bytes:
    def numbers(values):
        return ", ".join(repr(float(v)) for v in values)
    return (f"%YAML:1.0\n---\nimage_width: {width}\nimage_height: {height}\n"
            f"camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [{numbers(K)}]\n"
            f"distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [{numbers(D)}]\n"
            ).encode()


@pytest.fixture(scope="module")
def session_2s(tmp_path_factory) -> Path:
    from phonepose.testing.playback_session import write_test_session

    path = tmp_path_factory.mktemp("good") / "good.mcap"
    write_test_session(path, duration_s=2.0)
    return path


@pytest.mark.parametrize("what,K,D,width,height,problem", BAD_CAMERAS, ids=[c[0] for c in BAD_CAMERAS])
def test_a_degenerate_camera_calibration_is_refused_alike_by_every_route(session_2s, tmp_path, cli, what, K, D, width,
                                                                          height, problem):
    """A calibration file (record live --calibration reads it so), a session's calibration topic (playback,
    calibrate-gt), the viewer and calibrate-camera's own fit all apply pipeline.types.camera_problem: fx = 1e-30 px
    was "Found zero norm quaternions" (a bug in phonepose) in playback."""
    from test_reliability_cli import _static, rewrite

    from phonepose.calibration import load_calibration
    from phonepose.pipeline.types import camera_problem
    from phonepose.schemas.topics import Topic
    from phonepose.session import SessionReader
    from phonepose.viewer.frames import FrameTree

    assert camera_problem(K, D, width, height) is not None and camera_problem(K, D, width, height).startswith(problem)
    (tmp_path / "c.yaml").write_bytes(_calibration_yaml(K, D, width, height))
    with pytest.raises(InputFileError) as e:
        load_calibration(tmp_path / "c.yaml")
    assert str(e.value).startswith(f"{tmp_path / 'c.yaml'}: {problem}")

    def degenerate(m):
        m.K[:] = K
        del m.D[:]
        m.D.extend(D)
        m.width, m.height = width, height

    bad = rewrite(session_2s, tmp_path / "k.mcap", _static(Topic.CAMERA_CALIBRATION, degenerate))
    for command in (["playback", str(bad), "-q", "-t", "T1", "--out", str(tmp_path / "o")],
                    ["calibrate-gt", str(bad), "-o", str(tmp_path / "gt.yaml")]):
        code, out, err = cli(*command)
        assert code == 4 and out == "", err
        assert err.startswith(f"phonepose: error: {bad}: camera calibration: {problem}") and err.count("\n") == 1
    with SessionReader(bad) as r:
        calib = next(m.msg for m in r.messages([Topic.CAMERA_CALIBRATION]))
    assert FrameTree().derive(Topic.CAMERA_CALIBRATION, calib, 0) == []   # no frustum drawn from it


@given(fx=st.floats(min_value=-1e308, max_value=1e308), fy=st.floats(min_value=1.0, max_value=1e6))
def test_focal_lengths_are_accepted_exactly_within_their_range(fx, fy):
    from phonepose.pipeline.types import FOCAL_RANGE_PX, camera_problem

    problem = camera_problem(_k(fx=fx, fy=fy), [0.0] * 5, 320, 240)
    assert (problem is None) == (FOCAL_RANGE_PX[0] <= fx <= FOCAL_RANGE_PX[1])
    assert problem is None or problem.startswith("focal lengths fx=")


@settings(deadline=None, max_examples=60)
@given(exponent=st.floats(min_value=150.5, max_value=307.5), mantissas=st.lists(
    st.floats(min_value=-1.0, max_value=1.0).filter(lambda v: abs(v) > 1e-3), min_size=4, max_size=4))
def test_quaternions_of_huge_components_are_normalised_like_small_ones(tmp_path_factory, exponent, mantissas):
    """Components of 1e150-1e308: the norm overflowed to inf and scipy called the quaternion zero (a bug in
    phonepose). The rotation read is the one of the same components scaled to a small size, and the warning names
    the norm."""
    from scipy.spatial.transform import Rotation

    from phonepose.evaluation import load_tum

    q = [float(v) for v in np.array(mantissas) * 10.0 ** exponent]
    p = tmp_path_factory.mktemp("q") / "big.tum"
    p.write_text("".join(f"{k / 10:.1f} {k / 50:.3f} 0 0 {q[0]!r} {q[1]!r} {q[2]!r} {q[3]!r}\n" for k in range(5)))
    traj = load_tum(p)
    expected = Rotation.from_quat(np.array(q) / np.abs(q).max()).as_matrix()
    assert np.allclose(traj.poses.rotation.as_matrix(), expected, atol=1e-12)
    assert traj.stamps.tolist() == [k / 10 for k in range(5)]


def test_a_quaternion_too_small_to_normalise_names_its_line(tmp_path):
    from phonepose.evaluation import load_tum

    p = tmp_path / "tiny.tum"
    p.write_text("# t x y z qx qy qz qw\n0 0 0 0 0 0 0 1\n\n0.1 0 0 0 1e-170 0 0 1e-200\n")
    with pytest.raises(InputFileError, match=r"tiny\.tum:4: pose 1 has a zero quaternion \(\|q\| 0\): check the "
                                             r"file's columns$"):
        load_tum(p)


# ----------------------------------------------------------------------------- image headers
def _jpeg_claiming(width: int, height: int) -> bytes:
    """A real 32x24 JPEG whose SOF0 header claims ``width`` x ``height`` px."""
    import struct

    import cv2

    data = cv2.imencode(".jpg", np.full((24, 32), 128, np.uint8))[1].tobytes()
    i = data.index(b"\xff\xc0")
    return data[:i + 5] + struct.pack(">HH", height, width) + data[i + 9:]


@settings(deadline=None, max_examples=80)
@given(kind=st.sampled_from(["png", "jpeg"]), width=st.integers(1, 65500), height=st.integers(1, 65500))
def test_an_image_larger_than_the_limit_is_refused_from_its_header_never_decoded(kind, width, height):
    """Sizes come from the header (Pillow); a frame of another size than expected, or above MAX_DECODE_PIXELS, is
    never handed to OpenCV (65500x65500 failed its validateInputImageSize; 20000x20000 decoded 400 Mpx a frame)."""
    from phonepose.pipeline import shared

    data = _png_claiming(width, height) if kind == "png" else _jpeg_claiming(width, height)
    huge = width * height > 2 * 89_478_485       # beyond twice Pillow's limit it keeps the size to itself
    assert shared.image_size(data) == (shared.HUGE if huge else (width, height))
    shown = "more than 178 Mpx" if huge else f"{width}x{height} px"
    if (width, height) != (32, 24):
        assert shared.decode_gray(data, (32, 24)) == shared.Decoded(None, f"{shown}, not the calibration's 32x24", True)
    if width * height > shared.MAX_DECODE_PIXELS:
        assert shared.decode_gray(data) == shared.Decoded(
            None, f"{shown} by its header, more than the 80 Mpx phonepose decodes")


def test_the_decoders_own_diagnostics_are_counted_not_printed(capfd):
    """libjpeg prints "Corrupt JPEG data" to the process's stderr whatever OpenCV's log level; decode_gray returns it
    instead, and what another writer put on stderr meanwhile still arrives."""
    import cv2

    from phonepose.pipeline.shared import c_stderr_captured, decode_gray

    rng = np.random.default_rng(3)
    for cut in rng.integers(700, 1500, size=5):
        data = cv2.imencode(".jpg", rng.integers(0, 255, (64, 80), dtype=np.uint8))[1].tobytes()
        damaged = decode_gray(data[:int(cut)] + b"\xff\xd9")
        assert damaged.gray is not None and damaged.gray.shape == (64, 80)
        assert damaged.damaged.startswith("Corrupt JPEG data") or damaged.damaged.startswith("Premature end")
        whole = decode_gray(data)
        assert whole.damaged == "" and np.array_equal(whole.gray, cv2.imdecode(np.frombuffer(data, np.uint8), 0))
    with c_stderr_captured() as said:
        os.write(2, b"someone else's line\n")
    assert said == []
    out, err = capfd.readouterr()
    assert err == "someone else's line\n"
