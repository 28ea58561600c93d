"""phonepose as a library: the names ``import phonepose`` gives, typed (docs/python-api.md).

``phonepose.<name>`` loads them from here on first use; type checkers and IDEs see them through this module
(``from phonepose.api import play``).
"""

from phonepose.api.functions import (
    calibrate_camera,
    calibrate_gt,
    calibrate_hand_eye,
    evaluate,
    play,
    record_sim,
    tracker_names,
)
from phonepose.api.results import (
    Evaluation,
    PlaybackRun,
    ScopeMetrics,
    Stats,
    TotalMetrics,
    TrackerMetrics,
    TrackerRun,
)
from phonepose.api.session import ImuSeries, PoseSeries, Session, open_session
from phonepose.evaluation.trajectory import Trajectory, load_trajectory
from phonepose.geometry import Pose
from phonepose.pipeline.types import Observation

__all__ = [
    "open_session", "Session", "PoseSeries", "ImuSeries",
    "record_sim",
    "play", "tracker_names", "PlaybackRun", "TrackerRun", "TrackerMetrics", "ScopeMetrics", "TotalMetrics",
    "evaluate", "Evaluation", "Stats", "Trajectory", "load_trajectory",
    "calibrate_camera", "calibrate_gt", "calibrate_hand_eye",
    "Pose", "Observation",
]
