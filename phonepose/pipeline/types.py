"""The data that flows from the playback engine through the pipeline to the trackers.

Playback builds one :class:`Tick` every 1/rate s from the session (the engine owns the clock);
the shared stages turn it into one :class:`Observation` (image decode, marker detection,
anchor mapping: once per tick); every tracker steps on that same Observation. The same
objects would run live. Poses follow phonepose.geometry: ``T_a_b`` is frame b in frame a.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
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


# Lens models whose first 5 coefficients are plumb_bob's k1 k2 p1 p2 k3 (ROS / Foxglove names, Kalibr's radtan):
# phonepose's camera model is plumb_bob, so a calibration of one of these is read when its further coefficients
# (OpenCV's rational k4 k5 k6, thin prism s1-s4, tilt tx ty) are all zero.
PLUMB_BOB_MODELS = ("", "plumb_bob", "rational_polynomial", "radtan", "radial-tangential")


def check_plumb_bob(where: str, model: str, D: np.ndarray, error: type[Exception]) -> None:
    """``error`` unless distortion model ``model`` with coefficients ``D`` is plumb_bob's (k1 k2 p1 p2 k3): another
    model (fisheye ``equidistant``, ``kannala_brandt``) or non-zero coefficients beyond the fifth would be read
    as plumb_bob's first five, silently: every marker pose would then come from a wrong lens."""
    if model.strip().lower() not in PLUMB_BOB_MODELS:
        raise error(f"{where}: distortion model {model!r}: phonepose models plumb_bob (k1 k2 p1 p2 k3) only; "
                    "calibrate the camera with phonepose calibrate-camera")
    extra = np.flatnonzero(np.asarray(D, dtype=float)[5:])
    if extra.size:
        raise error(f"{where}: {len(D)} distortion coefficients, of which the {_ordinal(6 + int(extra[0]))} is not "
                    "zero (OpenCV's rational or thin-prism model): phonepose models plumb_bob (k1 k2 p1 p2 k3) only; "
                    "calibrate without CALIB_RATIONAL_MODEL, or with phonepose calibrate-camera")


# What a camera calibration may hold, checked where one enters (a calibration file, a session's calibration topic):
# a side beyond this is no camera's (1e9 px frames were planned), a focal length below 1 px or above 1e6 px is no
# lens's (fx = 1e-30 px made every marker pose overflow), a principal point more than an image away from the image
# is no camera's, and plumb_bob coefficients beyond ±1e4 are no lens's (1e300 overflowed the projection).
MAX_IMAGE_SIDE_PX = 100_000
FOCAL_RANGE_PX = (1.0, 1e6)
MAX_DISTORTION = 1e4


def check_camera(where: str, K: np.ndarray, D: np.ndarray, width: float, height: float,
                 error: type[Exception]) -> None:
    """``error`` (one line starting ``where``) unless ``K`` (3x3), ``D``, ``width`` and ``height`` are a camera's:
    the one check of a calibration's values, whichever way it came in (:data:`FOCAL_RANGE_PX` and beside it)."""
    problem = camera_problem(K, D, width, height)
    if problem is not None:
        raise error(f"{where}: {problem}")


def camera_problem(K: np.ndarray, D: np.ndarray, width: float, height: float) -> str | None:
    """Why ``K``, ``D``, ``width`` and ``height`` are not a camera's (:func:`check_camera`), or None."""
    from phonepose.numbers import show_number

    K = np.asarray(K, dtype=float).reshape(3, 3)
    D = np.asarray(D, dtype=float).ravel()
    if not (np.isfinite(K).all() and np.isfinite(D).all()):
        return "the camera matrix or distortion coefficients have NaN/inf values"
    if not (1 <= width <= MAX_IMAGE_SIDE_PX and 1 <= height <= MAX_IMAGE_SIDE_PX
            and float(width).is_integer() and float(height).is_integer()):
        return (f"image size {show_number(float(width))} x {show_number(float(height))} px: expected whole pixels in "
                f"[1, {MAX_IMAGE_SIDE_PX}]")
    fx, fy = float(K[0, 0]), float(K[1, 1])
    lo, hi = FOCAL_RANGE_PX
    if not (lo <= fx <= hi and lo <= fy <= hi):
        return (f"focal lengths fx={show_number(fx)}, fy={show_number(fy)} px: expected {show_number(lo)} to "
                f"{show_number(hi)} px (a camera matrix in pixels)")
    cx, cy = float(K[0, 2]), float(K[1, 2])
    if not (-width <= cx <= 2 * width and -height <= cy <= 2 * height):
        return (f"principal point cx={show_number(cx)}, cy={show_number(cy)} px is not near the "
                f"{int(width)}x{int(height)} image (expected within one image size of it)")
    if not (K[1, 0] == 0 and K[2, 0] == 0 and K[2, 1] == 0 and K[2, 2] == 1 and abs(K[0, 1]) <= hi):
        rows = "; ".join(" ".join(show_number(float(v)) for v in row) for row in K[1:])
        return f"the camera matrix is not [[fx, s, cx], [0, fy, cy], [0, 0, 1]] (its rows 2 and 3 are {rows})"
    big = np.flatnonzero(np.abs(D) > MAX_DISTORTION)
    if big.size:
        return (f"distortion coefficient {show_number(float(D[big[0]]))} (the {_ordinal(int(big[0]) + 1)}) is beyond "
                f"±{show_number(MAX_DISTORTION)}: not a plumb_bob lens's")
    return None


def _ordinal(n: int) -> str:
    return f"{n}{'th' if 10 <= n % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(n % 10, 'th')}"


@dataclass(frozen=True)
class MarkerModel:
    dictionary: str               # e.g. "DICT_4X4_50"
    id: int
    size_m: float
    T_body_marker: Pose           # marker in the controller body frame


@dataclass(frozen=True)
class TaskTarget:
    """One experiment-1 target, as recorded (values unchecked: only the viewer draws them; experiment 1
    reads the hold times from the session itself)."""

    index: int
    position: tuple[float, float, float]               # in TaskTargets.frame_id
    orientation_xyzw: tuple[float, float, float, float]
    inside_view: bool                                  # whether it lies inside the display camera's view


@dataclass(frozen=True)
class TaskTargets:
    """Experiment 1's targets (/experiment/targets)."""

    frame_id: str
    cube_size_m: float
    select_radius_m: float
    targets: tuple[TaskTarget, ...]


@dataclass(frozen=True)
class TaskPath:
    """Experiment 2's path (/experiment/path)."""

    frame_id: str
    name: str                                          # TRI1 | TRI2 | REC1 | REC2
    trial: int
    waypoints: tuple[tuple[float, float, float], ...]
    closed: bool


@dataclass
class SessionContext:
    """What does not change during a session (read once before the first tick)."""

    camera: CameraModel
    marker: MarkerModel
    T_world_display_vio: Pose | None = None   # mocap world -> display_vio calibration (/gt/calibration)
    task_start_ns: int | None = None
    task_end_ns: int | None = None
    session_id: str | None = None             # 16-hex digest of /session/info (None: the session has none)
    targets: TaskTargets | None = None
    path: TaskPath | None = None


def has_camera(context: SessionContext) -> bool:
    return context.camera.width > 0


class CalibrationKind(IntEnum):
    """The kind of a calibration event (the session schema's numbers, so ``kind == 1`` still reads CM1)."""

    UNSPECIFIED = 0
    CM1 = 1     # manual alignment: the user aligned the phone with a fixed CG object
    CM2 = 2     # calibration moment: the phone is held inside the camera's view


@dataclass(frozen=True)
class CalibrationEvent:
    """A correction moment recorded during the session (/events/calibration), decoded by the scheduler.

    ``kind`` is a :class:`CalibrationKind`, or the plain number of a kind this version does not know.
    CM1's poses are display_vio poses: ``pose_fix_vio`` the VIO pose shown as the fixed CG object,
    ``pose_align_vio`` the VIO pose when the user had aligned the phone with it; None where the
    event has none or it is broken (unset, NaN/inf, non-unit quaternion: docs/format.md).
    """

    kind: int
    t_ns: int                                 # the event's stamp (its log time when unset)
    log_time_ns: int                          # when it was recorded: the tick that carries it is the first at or after
    frame_id: str = ""
    pose_fix_vio: Pose | None = None
    pose_align_vio: Pose | None = None
    fix_t_ns: int | None = None               # when the CG object was fixed (None: unset)


@dataclass(frozen=True)
class Frame:
    """The newest camera frame at or before a tick, as the scheduler decided it once.

    ``is_new``: the previous tick did not carry this frame (the shared stages decode and detect
    only then; a frame carried again reuses its recognition). ``t_ns``: the frame's time on the
    display clock, the one every stage pairs it by (its ``log_time``).
    """

    data: bytes                               # the encoded image, as recorded
    format: str                               # "jpeg" or "png" (foxglove CompressedImage.format)
    t_ns: int
    is_new: bool
    T_dvio_display: Pose | None = None        # display body in display_vio at ``t_ns`` (None: not known yet)


@dataclass
class Tick:
    """Everything a tracker may know at time ``t_ns`` (display clock), causally.

    No ground truth: the scheduler hands that beside the tick, to the engine and the metrics only.
    """

    index: int
    t_ns: int
    frame: Frame | None = None                # newest camera frame at or before t (None: none yet, or no camera)
    T_dvio_display: Pose | None = None        # display body in display_vio, at frame.t_ns (else t)
    T_cvio_controller: Pose | None = None     # controller body in controller_vio, interpolated at t
    T_dvio_anchor: Pose | None = None         # anchor as the display resolved it (latest)
    T_cvio_anchor: Pose | None = None         # anchor as the controller resolved it (latest)
    imu: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)))  # rows t_s, gx gy gz, ax ay az since last tick
    events: list[CalibrationEvent] = field(default_factory=list)  # recorded since the last tick
    in_task: bool = True                      # inside [task_start, task_end]
    # controller VIO samples received since the previous tick: (capture_ns from the message's
    # timestamp, T_cvio_controller), in receipt order (used by T8; the rows above do not need it)
    controller_vio_samples: list = field(default_factory=list)

    @property
    def new_frame(self) -> Frame | None:
        """The frame if this tick is the first to carry it, else None."""
        return self.frame if self.frame is not None and self.frame.is_new else None

    @property
    def frame_t_ns(self) -> int:
        """The time this tick's image-derived values refer to: the frame's, else the tick's."""
        return self.frame.t_ns if self.frame is not None else self.t_ns


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
    """A causal streaming tracker (one row of the paper's Table 1, or a user's own: docs/writing-a-tracker.md).

    Capabilities, read by the engine before the first tick: ``needs_camera`` (the session must have
    camera images; refused on one without, before any output) and ``uses_vio_samples`` (the shared
    stages map ``Tick.controller_vio_samples`` into display_vio for it:
    ``Observation.controller_vio_samples_dvio``; skipped when no tracker asks).
    """

    name: str

    @property
    def needs_camera(self) -> bool: ...   # a class attribute satisfies it (read-only)

    @property
    def uses_vio_samples(self) -> bool: ...

    def reset(self) -> None:
        """Forget everything: the next ``step`` is the first tick of a session."""
        ...

    def step(self, obs: Observation) -> Pose | None:
        """The controller pose in display_vio at ``obs.tick.t_ns``, or None if it has none yet."""
        ...


class Stages(Protocol):
    """The stages every tracker shares (phonepose.pipeline.shared.SharedStages), run once per tick."""

    map_vio_samples: bool      # map Tick.controller_vio_samples (set by the engine from the trackers' capabilities)
    frames_decoded: int        # camera frames decoded so far
    frames_undecodable: int    # of which could not be decoded (reported once by the engine)
    frames_wrong_size: int     # of which are not of the calibration's size (reported once by the engine)
    wrong_size: str            # what the first of those is ("1280x960 px, not the calibration's 640x480")
    frames_damaged: int        # decoded as far as they go; the decoder called them damaged (reported once)
    damaged: str               # what it said of the first ("Corrupt JPEG data: premature end of data segment")

    def process(self, tick: Tick) -> Observation: ...
