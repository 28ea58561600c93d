"""The data that flows from the playback engine through the pipeline to the trackers.

Playback builds one :class:`Tick` every 1/rate s from the session (the engine owns the clock);
the shared stages turn it into one :class:`Observation` (image decode, marker detection,
anchor mapping: once per tick); every tracker steps on that same Observation. The same
objects would run live. Poses follow phonepose.geometry: ``T_a_b`` is frame b in frame a.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from phonepose.geometry import Pose


@dataclass(frozen=True)
class CameraModel:
    """The display camera: OpenCV intrinsics, plumb_bob distortion, and where it sits on the display."""

    K: np.ndarray                 # (3, 3)
    D: np.ndarray                 # (5,) k1 k2 p1 p2 k3
    width: int
    height: int
    T_display_camera: Pose        # display_camera in the display body frame


@dataclass(frozen=True)
class MarkerModel:
    dictionary: str               # e.g. "DICT_4X4_50"
    id: int
    size_m: float
    T_body_marker: Pose           # marker in the controller body frame


@dataclass
class SessionContext:
    """What does not change during a session (read once before the first tick)."""

    camera: CameraModel
    marker: MarkerModel
    T_world_display_vio: Pose | None = None   # mocap world -> display_vio calibration (/gt/calibration)
    task_start_ns: int | None = None
    task_end_ns: int | None = None
    session_info: object | None = None        # phonepose.SessionInfo
    targets: object | None = None             # phonepose.Targets
    path: object | None = None                # phonepose.PathSpec


@dataclass
class Tick:
    """Everything a tracker may know at time ``t_ns`` (display clock), causally."""

    index: int
    t_ns: int
    image: object | None = None               # foxglove CompressedImage: newest frame at or before t
    image_t_ns: int | None = None
    image_is_new: bool = False                # not already carried by the previous tick
    T_dvio_display: Pose | None = None        # display body in display_vio, at image_t (else t)
    T_cvio_controller: Pose | None = None     # controller body in controller_vio, interpolated at t
    T_dvio_anchor: Pose | None = None         # anchor as the display resolved it (latest)
    T_cvio_anchor: Pose | None = None         # anchor as the controller resolved it (latest)
    imu: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)))  # rows t_s, gx gy gz, ax ay az since last tick
    events: list = field(default_factory=list)  # phonepose.CalibrationEvent received since the last tick
    gt_T_dvio_controller: Pose | None = None  # ground truth in display_vio (None: no GT within tolerance)
    in_task: bool = True                      # inside [task_start, task_end]
    # controller VIO samples received since the previous tick: (capture_ns from the message's
    # timestamp, T_cvio_controller), in receipt order (used by T8; the rows above do not need it)
    controller_vio_samples: list = field(default_factory=list)


@dataclass
class MarkerObservation:
    """One recognised marker in this tick's image."""

    corners_px: np.ndarray                    # (4, 2) TL TR BR BL, bias-corrected
    T_camera_marker: Pose
    T_dvio_controller: Pose | None            # controller body in display_vio, from the marker (None: display pose unknown)
    reprojection_error_px: float
    chosen_solution: int
    ambiguity_ratio: float
    id: int


@dataclass
class Observation:
    """The shared stages' output for one tick; every tracker reads the same object."""

    tick: Tick
    marker: MarkerObservation | None          # None: the marker was not recognised (outside the FoV)
    T_dvio_controller_vio: Pose | None        # controller VIO mapped into display_vio through the anchors
    # tick.controller_vio_samples mapped the same way: (capture_ns, T_dvio_controller) (used by T8)
    controller_vio_samples_dvio: list = field(default_factory=list)

    @property
    def in_view(self) -> bool:
        """The paper's practical FoV test: the marker was recognised in this frame."""
        return self.marker is not None


class Tracker(Protocol):
    """A causal streaming tracker (one row of the paper's Table 1)."""

    name: str

    def reset(self) -> None: ...

    def step(self, obs: Observation) -> Pose | None:
        """The controller pose in display_vio at ``obs.tick.t_ns``, or None if it has none yet."""
        ...
