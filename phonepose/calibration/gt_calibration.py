"""The ground-truth calibration file: what ties a ground truth to the display, applied by
``playback/evaluate/batch/experiment --gt-calibration FILE`` (docs/calibration.md#the-calibration-file).

One format for both calibration commands: OpenCV FileStorage YAML (like the camera calibration
file), ``format: phonepose-gt-calibration``, ``version: 1``. Keys:

* ``method``: ``calibrate-gt`` or ``calibrate-hand-eye``;
* ``time_offset_s``: ground-truth stamps minus recorder stamps of the same instant;
* ``T_controller_gt`` (4x4): the tracked body (mocap rigid body, controller grip) in the phone's
  body frame (X of A X = Z B);
* ``T_world_display_vio`` (4x4, calibrate-gt only): display_vio in the ground truth's world; it
  replaces the session's ``/gt/calibration``. Absent: the session's own is used;
* ``T_world_camera`` (4x4, informational): the display camera in that world (median display pose);
* quality, informational: ``sightings``/``motions``, ``residual_mm``, ``residual_deg``,
  ``sigma_time_offset_ms``, ``sigma_world_rotation_deg``, ``sigma_world_translation_mm``,
  ``sigma_body_rotation_deg``, ``sigma_body_translation_mm`` (1σ, see docs), ``session``,
  ``ground_truth`` (``/gt/controller/pose`` or the trajectory file's name).

A hand-eye file of earlier versions (``T_controller_mocap``, no ``format`` key) loads as version 0.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from phonepose.errors import InputFileError
from phonepose.geometry import Pose
from phonepose.numbers import show_number

FORMAT = "phonepose-gt-calibration"
VERSION = 1
SIGMA_KEYS = ("sigma_time_offset_ms", "sigma_world_rotation_deg", "sigma_world_translation_mm",
              "sigma_body_rotation_deg", "sigma_body_translation_mm")
SUFFIXES = (".yaml", ".yml")
WHAT = "a YAML calibration file"


@dataclass(frozen=True)
class GtCalibration:
    T_controller_gt: Pose                    # X: the tracked body in the phone's body frame
    time_offset_s: float                     # ground-truth stamps minus recorder stamps
    T_world_display_vio: Pose | None = None  # replaces /gt/calibration when given
    T_world_camera: Pose | None = None       # informational
    method: str = "calibrate-gt"
    samples: int = 0                         # sightings (calibrate-gt) or motions (calibrate-hand-eye)
    residual_mm: float = float("nan")
    residual_deg: float = float("nan")
    sigma: dict[str, float] = field(default_factory=dict)   # SIGMA_KEYS that were estimated
    session: str = ""
    ground_truth: str = ""
    warnings: tuple[str, ...] = ()           # not in the file: printed by the command
    version: int = VERSION

    @property
    def body_rotation_deg(self) -> float:
        return float(np.degrees(self.T_controller_gt.rotation.magnitude()))

    def with_(self, **changes) -> GtCalibration:
        return replace(self, **changes)

    def apply(self, stamps_s: np.ndarray | None, T_world_grip: Pose) -> tuple[np.ndarray | None, Pose]:
        """A ground truth re-expressed as playback does it: on the recorder's clock, of the phone's body
        (T_world_grip · X⁻¹) and, when this calibration has its world, in display_vio."""
        poses = T_world_grip @ self.T_controller_gt.inv()
        if self.T_world_display_vio is not None:
            poses = self.T_world_display_vio.inv() @ poses
        return (None if stamps_s is None else np.asarray(stamps_s, dtype=float) - self.time_offset_s), poses

    def metrics_note(self, name: str) -> dict:
        """What metrics.json records under ``ground_truth`` about the calibration applied."""
        note: dict = {"calibration_file": name, "method": self.method,
                      "time_offset_s": round(self.time_offset_s, 6),
                      "body_rotation_deg": round(self.body_rotation_deg, 6),
                      "body_translation_m": [round(float(v), 6) for v in self.T_controller_gt.translation],
                      "world_display_vio": "calibrated" if self.T_world_display_vio is not None else "session"}
        if self.ground_truth:
            note["ground_truth"] = self.ground_truth
        return note


def _write_pose(fs: cv2.FileStorage, key: str, pose: Pose | None) -> None:
    if pose is not None:
        fs.write(key, pose.as_matrix())


def calibration_text(cal: GtCalibration) -> str:
    from phonepose.calibration.camera_file import opencv_text

    def write(fs: cv2.FileStorage) -> None:
        fs.write("format", FORMAT)
        fs.write("version", VERSION)
        fs.write("method", cal.method)
        fs.write("time_offset_s", float(cal.time_offset_s))
        _write_pose(fs, "T_controller_gt", cal.T_controller_gt)
        _write_pose(fs, "T_world_display_vio", cal.T_world_display_vio)
        _write_pose(fs, "T_world_camera", cal.T_world_camera)
        fs.write("sightings" if cal.method == "calibrate-gt" else "motions", int(cal.samples))
        for key, value in (("residual_mm", cal.residual_mm), ("residual_deg", cal.residual_deg),
                           *((k, cal.sigma[k]) for k in SIGMA_KEYS if k in cal.sigma)):
            if math.isfinite(value):
                fs.write(key, float(value))
        if cal.session:
            fs.write("session", cal.session)
        if cal.ground_truth:
            fs.write("ground_truth", cal.ground_truth)
    return opencv_text(write, ".yaml")


def save_gt_calibration(path: str | os.PathLike, cal: GtCalibration, parameter: str = "out",
                        inputs: Sequence[str | os.PathLike] = ()) -> None:
    """Written by the output rule (phonepose.files: checked, temporary name, atomic rename)."""
    from phonepose.files import write_text_output

    write_text_output(path, calibration_text(cal), parameter, inputs=inputs, suffixes=SUFFIXES, what=WHAT)


def _pose(path: Path, fs: cv2.FileStorage, key: str, required: bool) -> Pose | None:
    from phonepose.calibration.camera_file import yaml_matrix
    from phonepose.evaluation.trajectory import MAX_POSITION_M

    T = yaml_matrix(path, fs, key)
    if T is None:
        if required:
            raise InputFileError(f"{path}: not a ground-truth calibration file (expected a 4x4 matrix {key})")
        return None
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise InputFileError(f"{path}: {key} is not a finite 4x4 matrix")
    R = T[:3, :3]
    if abs(np.linalg.det(R) - 1) > 1e-6 or not np.allclose(R.T @ R, np.eye(3), atol=1e-6):
        raise InputFileError(f"{path}: {key}'s rotation part is not a rotation matrix")
    if np.abs(T[:3, 3]).max() > MAX_POSITION_M:     # as a trajectory's positions (1e300 overflowed the metrics)
        raise InputFileError(f"{path}: {key}'s translation {np.abs(T[:3, 3]).max():g} m is beyond ±1e7 m "
                             "(not a place on Earth)")
    return Pose.from_matrix(T)


def load_gt_calibration(path: str | os.PathLike, what: str = "calibration") -> GtCalibration:
    """A file of ``save_gt_calibration`` or an older hand-eye file; a bad one is an InputFileError (exit 2)."""
    from phonepose.calibration.camera_file import open_yaml, yaml_number, yaml_text

    path = Path(path)
    fs = open_yaml(path, what)
    try:
        def real(key: str, default: float = float("nan")) -> float:
            value = yaml_number(path, fs, key, default)
            assert value is not None      # a default is given
            return value

        def count(*keys: str) -> int:
            for key in keys:
                value = real(key)
                if not math.isnan(value):
                    if not (value.is_integer() and 0 <= value <= 1e9):
                        raise InputFileError(f"{path}: {key} {show_number(value)} is not a count")
                    return int(value)
            return 0

        fmt = yaml_text(path, fs, "format")
        version = real("version", 0) if fmt else 0.0
        if fmt and fmt != FORMAT:
            raise InputFileError(f"{path}: format {fmt!r}, expected {FORMAT!r}")
        if not (version.is_integer() and 0 <= version):
            raise InputFileError(f"{path}: version {show_number(version)} is not a version of this file ({VERSION})")
        if version > VERSION:
            raise InputFileError(f"{path}: version {show_number(version)} is newer than this phonepose reads ({VERSION})")
        # version 0 (no format key): an older hand-eye file's T_controller_mocap, or a hand-written T_controller_gt
        keys = ["T_controller_gt"] if version else [k for k in ("T_controller_gt", "T_controller_mocap")
                                                    if not fs.getNode(k).empty()]
        if not keys:
            raise InputFileError(f"{path}: not a ground-truth calibration file (expected a 4x4 matrix T_controller_gt, "
                                 "or an older hand-eye file's T_controller_mocap)")
        X = _pose(path, fs, keys[0], required=True)
        offset = real("time_offset_s", 0.0)
        assert X is not None   # required=True: a missing matrix raised above
        cal = GtCalibration(
            T_controller_gt=X, time_offset_s=float(offset),
            T_world_display_vio=_pose(path, fs, "T_world_display_vio", required=False),
            T_world_camera=_pose(path, fs, "T_world_camera", required=False),
            method=yaml_text(path, fs, "method") or "calibrate-hand-eye",
            samples=count("sightings", "motions", "pairs"),
            residual_mm=real("residual_mm"), residual_deg=real("residual_deg"),
            sigma={k: real(k) for k in SIGMA_KEYS if not fs.getNode(k).empty()},
            session=yaml_text(path, fs, "session"), ground_truth=yaml_text(path, fs, "ground_truth"),
            version=int(version))
    finally:
        fs.release()
    if not (math.isfinite(cal.time_offset_s) and abs(cal.time_offset_s) <= 10):
        raise InputFileError(f"{path}: time_offset_s {show_number(cal.time_offset_s)} is not a clock offset in "
                             "seconds (expected at most 10 s either way)")
    return cal


@dataclass(frozen=True)
class GroundTruthSetup:
    """What a playback applies to its ground truth (``--gt-calibration FILE``, ``--gt FILE``), read and
    checked before any work."""

    calibration: GtCalibration | None = None
    calibration_path: str | None = None
    series: object | None = None          # a calibration.ground_truth.GroundTruthSeries (--gt FILE)
    note: dict | None = None              # metrics.json's "ground_truth"
    rerun_params: dict = field(default_factory=dict)   # what makes the Rerun recording id differ


def ground_truth_setup(calibration: str | os.PathLike | GtCalibration | None, calibration_name: str | None = None,
                       gt_file: str | os.PathLike | None = None, gt_format: str | None = None) -> GroundTruthSetup:
    """The calibration file and the sidecar ground truth, loaded (one line and exit 2 for a bad file)."""
    import hashlib

    cal: GtCalibration | None
    if isinstance(calibration, GtCalibration):      # calibrated in memory (batch --calibrate-gt)
        cal, name, path = calibration, calibration_name or "calibrate-gt", None
    elif calibration is not None:
        cal, name, path = load_gt_calibration(calibration), calibration_name or os.fspath(calibration), os.fspath(calibration)
    else:
        cal, name, path = None, "", None
    series = None
    note = cal.metrics_note(name) if cal is not None else None
    params: dict = {}
    if gt_file is not None:
        from phonepose.calibration.ground_truth import file_ground_truth

        series = file_ground_truth(gt_file, gt_format)
        note = {**(note or {}), "ground_truth_file": os.fspath(gt_file)}
        with open(gt_file, "rb") as f:        # in chunks: the file may be up to 1 GiB (phonepose.files)
            params["gt_file"] = hashlib.file_digest(f, "sha256").hexdigest()
    return GroundTruthSetup(cal, path, series, note, params)
