"""OpenCV FileStorage files (YAML/XML/JSON), read with one clear error and written in memory, so that
the file itself goes through phonepose.files (checked first, complete or not at all). The camera
calibration file (calibration/camera_file.py) and the ground-truth calibration file
(evaluation/gt_calibration.py) are both such files.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable

import cv2

from phonepose.errors import InputFileError, OutputError

# What OpenCV's FileStorage writes, by the name's extension (it reads any of them by their content).
FORMATS = {".yaml": cv2.FILE_STORAGE_FORMAT_YAML, ".yml": cv2.FILE_STORAGE_FORMAT_YAML,
           ".xml": cv2.FILE_STORAGE_FORMAT_XML, ".json": cv2.FILE_STORAGE_FORMAT_JSON}


def opencv_text(write: Callable[[cv2.FileStorage], None], suffix: str = ".yaml") -> str:
    """What ``write(fs)`` puts into an OpenCV FileStorage, as text in the format of ``suffix``: made in
    memory, so the file itself is written by phonepose.files (checked first, complete or not at all)."""
    fs = cv2.FileStorage("", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY
                         | FORMATS.get(suffix.lower(), cv2.FILE_STORAGE_FORMAT_YAML))
    write(fs)
    return fs.releaseAndGetString()


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
