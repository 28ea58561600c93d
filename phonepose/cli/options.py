"""What every command's options share: numbers that are finite and in range, choices as enums.

A numeric option takes ``callback=number(lo, hi, ...)``: NaN, inf, an overflowing value or one
outside the range is one ``phonepose: error:`` line and exit 5 (a ConfigError) before any work,
never a ZeroDivisionError, OverflowError or an endless run further down
(:func:`phonepose.numbers.check_number`, which also checks values parsed from text).

The choice enums are light (no numpy or scipy import, so ``phonepose --help`` stays fast); the
modules that implement each choice keep their own parser, and tests/test_cli_options.py checks
that both list the same values.
"""

from __future__ import annotations

from collections.abc import Callable
from enum import StrEnum
from typing import Any

from phonepose.numbers import SECONDS_MAX, SEED_MAX, check_number


def number(lo=None, hi=None, *, lo_open: bool = False, hi_open: bool = False, integer: bool = False,
           unit: str = "", also: tuple = ()) -> Callable:
    """A typer callback for a numeric option (None, an unset optional option, passes); see check_number."""
    def callback(ctx, param, value):   # untyped, click's order: typer passes (context, parameter, value)
        if value is None:
            return value
        name = max(param.opts, key=len) if getattr(param, "opts", None) else param.name
        if isinstance(value, (list, tuple)):
            return [check_number(name, v, lo, hi, lo_open=lo_open, hi_open=hi_open, integer=integer,
                                 unit=unit, also=also) for v in value]
        return check_number(name, value, lo, hi, lo_open=lo_open, hi_open=hi_open, integer=integer, unit=unit,
                            also=also)
    return callback


# the options most commands share
SEED: dict[str, Any] = dict(callback=number(0, SEED_MAX, integer=True))
SECONDS: dict[str, Any] = dict(callback=number(0, SECONDS_MAX, unit="s"))


# every long-running command takes -q/--quiet with this meaning (tests/test_cli_options.py checks it)
QUIET: dict[str, Any] = dict(help="No progress output (results, warnings and errors still print).")
# a long-running command that prints no progress takes it too, so that a script can pass -q to any of them
QUIET_ACCEPTED: dict[str, Any] = dict(help="Accepted as by every long-running command (this one prints no progress "
                                           "output; results, warnings and errors still print).")


# ----------------------------------------------------------------------------- choices
class CorrectionMath(StrEnum):
    """phonepose.pipeline.corrections.CorrectionMath's values."""
    paper = "paper"
    se3 = "se3"


class Scenario(StrEnum):
    """phonepose.record.sim.scenarios.SCENARIOS."""
    exp1 = "exp1"
    exp2 = "exp2"


class SimPath(StrEnum):
    """phonepose.record.sim.scenarios.PATHS."""
    TRI1 = "TRI1"
    TRI2 = "TRI2"
    REC1 = "REC1"
    REC2 = "REC2"


class Paper(StrEnum):
    """phonepose.calibration.board.PAPER_MM, and fit."""
    a4 = "a4"
    a3 = "a3"
    letter = "letter"
    fit = "fit"


class Metric(StrEnum):
    rpg = "rpg"
    ape = "ape"
    rpe = "rpe"
    paper = "paper"


class Align(StrEnum):
    posyaw = "posyaw"
    se3 = "se3"
    sim3 = "sim3"
    none = "none"


class TrajectoryFormat(StrEnum):
    """phonepose.evaluation.trajectory.FORMATS."""
    tum = "tum"
    euroc = "euroc"
    kitti = "kitti"


class DeltaUnit(StrEnum):
    """evo's RPE delta units."""
    f = "f"
    m = "m"
    d = "d"
    r = "r"


class PoseRelation(StrEnum):
    """evo's pose relations."""
    trans = "trans"
    angle = "angle"
    angle_rad = "angle_rad"
    rot_part = "rot_part"
    full = "full"


TRACKER_HELP = ("Tracker name (repeat, or T1,T4), 'paper' (T1-T7), 'all' (T1-T7, T7L, T8), or your own: "
                "package.module:ClassName or an installed phonepose.trackers entry point (docs/writing-a-tracker.md).")
