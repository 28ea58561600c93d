"""The camera calibration file: OpenCV FileStorage YAML, as OpenCV's own calibration samples write it.

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


def save_calibration(path: str | Path, calib: CameraCalibrationFile, option: str = "--out",
                     inputs: Sequence[str | Path] = ()) -> None:
    """Write the file by the output rule (phonepose.files): the extension chooses YAML, XML or JSON."""
    from phonepose.files import write_text_output

    write_text_output(path, calibration_text(calib, Path(path).suffix), option, inputs=inputs,
                      suffixes=tuple(OPENCV_FORMATS), what=OPENCV_WHAT)


def open_yaml(path: Path, what: str, write: bool = False) -> cv2.FileStorage:
    """An OpenCV YAML/XML file opened for reading (one it cannot parse is an InputFileError) or for
    writing (OutputError)."""
    if not write:
        from phonepose.files import check_input
        try:
            check_input(path, f"{what} file")     # a FIFO or device is refused, never opened
        except InputFileError:
            if not os.path.lexists(path):
                raise InputFileError(f"{path}: no such {what} file") from None
            raise
    error = ""
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE if write else cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:   # opencv-python 5.0 reports a YAML parse error as SystemError
        fs, error = None, f": {exc}"
    if fs is None or not fs.isOpened():
        if write:
            raise OutputError(f"cannot write {path}{error}")
        raise InputFileError(f"{path}: not an OpenCV YAML/XML {what} file")
    return fs


def load_calibration(path: str | os.PathLike) -> CameraCalibrationFile:
    """Read a calibration file; a missing or malformed one is an InputFileError (one line, exit 2)."""
    path = Path(path)
    fs = open_yaml(path, "calibration")
    try:
        K = fs.getNode("camera_matrix").mat()
        D = fs.getNode("distortion_coefficients").mat()
        width, height = fs.getNode("image_width").real(), fs.getNode("image_height").real()
        rms_node, board_node = fs.getNode("reprojection_error"), fs.getNode("board")
        rms = rms_node.real() if not rms_node.empty() else float("nan")
        board = board_node.string() if not board_node.empty() else ""
    finally:
        fs.release()
    if K is None or K.shape != (3, 3) or D is None or D.size not in (4, 5, 8, 12, 14) or width <= 0 or height <= 0:
        raise InputFileError(f"{path}: needs camera_matrix (3x3), distortion_coefficients, image_width, image_height")
    if not (np.isfinite(K).all() and np.isfinite(D).all()):
        raise InputFileError(f"{path}: camera_matrix or distortion_coefficients are not finite")
    D5 = np.zeros(5)
    D5[: min(5, D.size)] = D.ravel()[:5]
    return CameraCalibrationFile(K.astype(float), D5, int(width), int(height), float(rms), board)
