"""phonepose: record, replay and evaluate smartphone-as-6DoF-controller AR sessions.

    import phonepose
    run = phonepose.play("s.mcap", ["T4", "T8"])     # docs/python-api.md
    run["T8"].total.p_ate_m, run.to_table()

The names below load on first use (PEP 562): ``import phonepose`` and ``phonepose --help`` import none of
numpy, OpenCV or the session reader. No import statement of a submodule here: the modules that read
``__version__`` import this one (tests/test_imports.py).
"""

from __future__ import annotations

TYPE_CHECKING = False      # not typing's: importing typing would double the import's time (type checkers know the name)
if TYPE_CHECKING:
    from typing import Any

__version__ = "0.1.0"

_ERRORS = ("PhoneposeError", "InputFileError", "DamagedFileError", "SessionContentError", "ConfigError",
           "OutputError", "TrackerError")
_API = ("open_session", "Session", "PoseSeries", "ImuSeries",
        "record_sim",
        "play", "tracker_names", "PlaybackRun", "TrackerRun", "TrackerMetrics", "ScopeMetrics", "TotalMetrics",
        "evaluate", "Evaluation", "Stats", "Trajectory", "load_trajectory",
        "calibrate_camera", "calibrate_gt", "calibrate_hand_eye",
        "Pose", "Observation")
# public name -> the module that defines it (the errors without numpy: catching one loads nothing else)
_LAZY = {**dict.fromkeys(_API, "phonepose.api"), **dict.fromkeys(_ERRORS, "phonepose.errors")}

__all__ = [*_API, *_ERRORS]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'phonepose' has no attribute {name!r}")
    value = getattr(__import__(module, fromlist=[name]), name)   # the builtin: no importlib to load
    globals()[name] = value    # later lookups are plain attribute reads
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
