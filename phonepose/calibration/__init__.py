"""Camera calibration for real recordings: ChArUco boards, intrinsics, and the calibration file.

``camera_file`` is the file the recorder reads (``record live --calibration cam.yaml``); the board
and the calibration routine (``phonepose board``, ``phonepose calibrate-camera``) live beside it.
"""

from phonepose.calibration.camera_file import CameraCalibrationFile, load_calibration, save_calibration

__all__ = ["CameraCalibrationFile", "load_calibration", "save_calibration"]
