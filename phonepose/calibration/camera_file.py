"""The camera calibration file: OpenCV FileStorage YAML, as OpenCV's own calibration samples write it.

ROS's ``camera_info`` YAML (the same keys, matrices as ``rows``/``cols``/``data`` maps without OpenCV's tag, and a
``distortion_model``) and a Kalibr camchain of one pinhole camera are read too; a lens model other than plumb_bob is
refused (:func:`check_plumb_bob`).

Keys: ``image_width``, ``image_height``, ``camera_matrix`` (3x3), ``distortion_coefficients``
(plumb_bob k1 k2 p1 p2 k3), ``reprojection_error`` (RMS px) and, optionally, ``board`` (a text
description of the board used). Any tool that reads OpenCV's sample format reads ours, and a file
written by OpenCV's ``calibrate_camera_charuco`` sample loads here.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from phonepose.errors import InputFileError, OutputError
from phonepose.pipeline.types import check_camera, check_plumb_bob


@dataclass(frozen=True)
class CameraCalibrationFile:
    K: np.ndarray                 # (3, 3)
    D: np.ndarray                 # (5,) k1 k2 p1 p2 k3
    width: int
    height: int
    reprojection_error_px: float = float("nan")
    board: str = ""


# What OpenCV's FileStorage writes, by the name's extension (it reads any of them by their content).
OPENCV_FORMATS = {".yaml": cv2.FILE_STORAGE_FORMAT_YAML, ".yml": cv2.FILE_STORAGE_FORMAT_YAML,
                  ".xml": cv2.FILE_STORAGE_FORMAT_XML, ".json": cv2.FILE_STORAGE_FORMAT_JSON}
OPENCV_WHAT = "an OpenCV FileStorage file (YAML, XML or JSON)"


def opencv_text(write: Callable[[cv2.FileStorage], None], suffix: str = ".yaml") -> str:
    """What ``write(fs)`` puts into an OpenCV FileStorage, as text in the format of ``suffix``: made in
    memory, so the file itself is written by phonepose.files (checked first, complete or not at all)."""
    fs = cv2.FileStorage("", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY
                         | OPENCV_FORMATS.get(suffix.lower(), cv2.FILE_STORAGE_FORMAT_YAML))
    write(fs)
    return fs.releaseAndGetString()


def calibration_text(calib: CameraCalibrationFile, suffix: str = ".yaml") -> str:
    def write(fs: cv2.FileStorage) -> None:
        fs.write("image_width", int(calib.width))
        fs.write("image_height", int(calib.height))
        fs.write("camera_matrix", np.asarray(calib.K, dtype=np.float64).reshape(3, 3))
        fs.write("distortion_coefficients", np.asarray(calib.D, dtype=np.float64).reshape(1, -1))
        fs.write("reprojection_error", float(calib.reprojection_error_px))
        if calib.board:
            fs.write("board", calib.board)
    return opencv_text(write, suffix)


def save_calibration(path: str | Path, calib: CameraCalibrationFile, parameter: str = "out",
                     inputs: Sequence[str | Path] = ()) -> None:
    """Write the file by the output rule (phonepose.files): the extension chooses YAML, XML or JSON."""
    from phonepose.files import write_text_output

    write_text_output(path, calibration_text(calib, Path(path).suffix), parameter, inputs=inputs,
                      suffixes=tuple(OPENCV_FORMATS), what=OPENCV_WHAT)


# A calibration file is a few KiB (a 4x4 matrix and a dozen numbers); one beyond this is the wrong file.
MAX_CALIBRATION_BYTES = 1 << 20
MAX_MATRIX_ELEMENTS = 64      # the largest matrix a calibration file holds is 4x4 (distortion: at most 1x14)


def open_yaml(path: Path, what: str, write: bool = False) -> cv2.FileStorage:
    """An OpenCV YAML/XML file opened for reading (one it cannot parse, or whose top level is not a map of keys,
    is an InputFileError) or for writing (OutputError).

    A file is read by phonepose.files (size, binary content, a UTF-8 byte-order mark) and parsed from memory, so no
    path reaches OpenCV: one that is not UTF-8 crashes it (SIGSEGV)."""
    if not write:
        from phonepose.files import read_text_input
        try:
            text = read_text_input(path, f"{what} file", limit=MAX_CALIBRATION_BYTES,
                                   note="a calibration file is a few KiB")
        except InputFileError:
            if not os.path.lexists(path):
                raise InputFileError(f"{path}: no such {what} file") from None
            raise
    error = ""
    try:
        if write:
            fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
        else:
            fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY) if text.strip() else None
    except (cv2.error, SystemError) as exc:   # opencv-python 5.0 reports a YAML parse error as SystemError
        fs, error = None, f": {exc}"
    if fs is None or not fs.isOpened():
        if write:
            raise OutputError(f"cannot write {path}{error}")
        raise InputFileError(f"{path}: not an OpenCV YAML/XML {what} file")
    if not write and not fs.root().isMap():
        kind = "a list" if fs.root().isSeq() else "not a map of keys"
        fs.release()
        raise InputFileError(f"{path}: not an OpenCV YAML/XML {what} file (its top level is {kind}; expected "
                             "`key: value` lines, as phonepose writes them)")
    return fs


def yaml_number(path: Path, fs: cv2.FileStorage, key: str, default: float | None = None) -> float | None:
    """``key``'s number as a float (``default``, as a float, when it is absent); a node of another type is one line
    naming it (``node.real()`` reads a string or a list as 1.8e308). Always a float: callers use float-only methods
    (``int.is_integer`` is Python 3.12's)."""
    node = fs.getNode(key)
    if node.empty():
        return None if default is None else float(default)
    if not (node.isReal() or node.isInt()):
        raise InputFileError(f"{path}: {key} is not a number (found {_node_kind(node)})")
    return float(node.real())


def yaml_text(path: Path, fs: cv2.FileStorage | cv2.FileNode, key: str) -> str:
    """``key``'s text ("" when it is absent); a node of another type is one line naming it."""
    node = fs.getNode(key)
    if node.empty():
        return ""
    if not node.isString():
        raise InputFileError(f"{path}: {key} is not text (found {_node_kind(node)})")
    return node.string()


def yaml_matrix(path: Path, fs: cv2.FileStorage, key: str) -> np.ndarray | None:
    """``key``'s ``!!opencv-matrix`` (None when it is absent), its type and size checked before OpenCV reads it: a
    nested list is an OpenCV assertion, and ``rows: 100000 cols: 100000`` asks it for 80 GB."""
    node = fs.getNode(key)
    if node.empty():
        return None
    if not node.isMap() or not {"rows", "cols", "data"} <= set(node.keys()):
        raise InputFileError(f"{path}: {key} is not a matrix (found {_node_kind(node)}; expected an "
                             "!!opencv-matrix with rows, cols, dt and data)")
    rows, cols, data = node.getNode("rows"), node.getNode("cols"), node.getNode("data")
    if not (rows.isInt() and cols.isInt() and data.isSeq()) or not (
            0 < rows.real() * cols.real() <= MAX_MATRIX_ELEMENTS) or data.size() != rows.real() * cols.real():
        raise InputFileError(f"{path}: {key} is not a matrix of at most {MAX_MATRIX_ELEMENTS} numbers "
                             "(its rows, cols and data disagree)")
    if node.getNode("dt").empty():
        # ROS's camera_info YAML (camera_calibration_parsers): the same map without the !!opencv-matrix tag and dt,
        # which node.mat() refuses; its data is a list of numbers, read one by one
        items = [data.at(i) for i in range(data.size())]
        if not all(x.isReal() or x.isInt() for x in items):
            raise InputFileError(f"{path}: {key} is not a matrix of numbers")
        return np.array([x.real() for x in items], dtype=float).reshape(int(rows.real()), int(cols.real()))
    try:
        return np.asarray(node.mat(), dtype=float)
    except (cv2.error, SystemError, TypeError, ValueError):
        raise InputFileError(f"{path}: {key} is not a matrix of numbers") from None


def _node_kind(node: cv2.FileNode) -> str:
    return ("a list" if node.isSeq() else "a map" if node.isMap() else "text" if node.isString()
            else "a number" if node.isReal() or node.isInt() else "no value")


def _numbers(path: Path, node: cv2.FileNode, key: str, sizes: tuple[int, ...]) -> np.ndarray:
    """``node[key]`` as a list of numbers of one of ``sizes``, or one line naming it."""
    seq = node.getNode(key)
    items = [seq.at(i) for i in range(seq.size())] if seq.isSeq() else []
    if not seq.isSeq() or len(items) not in sizes or not all(x.isReal() or x.isInt() for x in items):
        raise InputFileError(f"{path}: cam0.{key} is not a list of {' or '.join(map(str, sizes))} numbers")
    return np.array([x.real() for x in items], dtype=float)


# Kalibr's names: its radtan is plumb_bob without k3; "none" is no distortion (an empty list)
KALIBR_MODELS = {"radtan": "plumb_bob", "none": "plumb_bob"}


def _kalibr_camera(path: Path, fs: cv2.FileStorage) -> tuple[np.ndarray, np.ndarray, float, float, str]:
    """K, D, width, height and the lens model of a Kalibr camchain with one camera (``cam0``: ``camera_model``
    pinhole, ``intrinsics`` fu fv pu pv, ``distortion_model``, ``distortion_coeffs``, ``resolution`` w h)."""
    if not fs.getNode("cam1").empty():
        raise InputFileError(f"{path}: a Kalibr camchain of several cameras (cam0, cam1, ...): give a file with the "
                             "display camera alone, as cam0")
    cam = fs.getNode("cam0")
    if not cam.isMap():
        raise InputFileError(f"{path}: cam0 is not a Kalibr camera (expected camera_model, intrinsics, ...)")
    camera_model = yaml_text(path, cam, "camera_model") or "pinhole"
    if camera_model != "pinhole":
        raise InputFileError(f"{path}: Kalibr camera_model {camera_model!r}: phonepose models a pinhole camera only")
    fu, fv, pu, pv = _numbers(path, cam, "intrinsics", (4,))
    width, height = _numbers(path, cam, "resolution", (2,))
    model = yaml_text(path, cam, "distortion_model") or "none"
    coeffs = _numbers(path, cam, "distortion_coeffs", (0, 1, 4, 5)) if not cam.getNode("distortion_coeffs").empty() \
        else np.zeros(0)
    D = np.zeros(5)
    D[:min(5, coeffs.size)] = coeffs[:5]
    K = np.array([[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]])
    return K, D, float(width), float(height), KALIBR_MODELS.get(model, model)


def load_calibration(path: str | os.PathLike) -> CameraCalibrationFile:
    """Read a calibration file; a missing or malformed one is an InputFileError (one line, exit 2)."""
    path = Path(path)
    fs = open_yaml(path, "calibration")
    try:
        if fs.getNode("camera_matrix").empty() and not fs.getNode("cam0").empty():
            K, D, width, height, model = _kalibr_camera(path, fs)
            rms, board = float("nan"), ""
        else:
            K = yaml_matrix(path, fs, "camera_matrix")
            D = yaml_matrix(path, fs, "distortion_coefficients")
            width, height = yaml_number(path, fs, "image_width", 0), yaml_number(path, fs, "image_height", 0)
            rms = yaml_number(path, fs, "reprojection_error", float("nan"))
            board = yaml_text(path, fs, "board")
            model = yaml_text(path, fs, "distortion_model")     # ROS's camera_info; OpenCV's samples write none
    finally:
        fs.release()
    assert width is not None and height is not None and rms is not None      # given defaults
    if K is None or K.shape != (3, 3) or D is None or D.size not in (4, 5, 8, 12, 14) or width <= 0 or height <= 0:
        raise InputFileError(f"{path}: needs camera_matrix (3x3), distortion_coefficients, image_width, image_height")
    check_camera(str(path), K, D, width, height, InputFileError)
    check_plumb_bob(str(path), model, D.ravel(), InputFileError)
    D5 = np.zeros(5)
    D5[: min(5, D.size)] = D.ravel()[:5]
    return CameraCalibrationFile(K.astype(float), D5, int(width), int(height), float(rms), board)
