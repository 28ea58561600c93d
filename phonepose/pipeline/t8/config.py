"""T8's parameters (docs/pipeline.md#t8-configuration). Noise figures are 1-sigma; none is tuned per sequence."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from phonepose.errors import ConfigError

_TRUE, _FALSE = ("1", "true", "yes", "on"), ("0", "false", "no", "off")


@dataclass(frozen=True)
class FusionConfig:
    """T8's parameters, with defaults for phone-class sensors."""

    # the correction filter (docs/pipeline.md#the-correction-filter)
    init_time_offset_s: float = 0.10                 # prior sigma of the VIO time offset d once it is estimated
    time_offset_after: int = 20                      # sightings that fix C (with d = 0) before d is estimated
    rotation_walk_deg_per_sqrt_s: float = 0.1        # C's heading random walk (phone VIO drift)
    tilt_deg: float = 0.5                            # C's largest tilt (both VIO worlds are gravity aligned)
    tilt_walk_deg_per_sqrt_s: float = 0.01           # C's tilt random walk
    translation_walk_m_per_sqrt_s: float = 0.002     # C's translation random walk over time
    translation_per_path_length: float = 0.02        # C's translation drift per metre travelled
    time_offset_walk_s_per_sqrt_s: float = 1e-4      # d's random walk
    offset_velocity_window_s: float = 0.2            # window of the centred line fit in d's Jacobian (#the-time-offset)
    marker_lateral_m: float = 0.002                  # a sighting's position noise across the line of sight
    marker_depth_m: float = 0.006                    # a sighting's position noise along the line of sight
    marker_rotation_deg: float = 3.0                 # a sighting's orientation noise
    vio_position_m: float = 0.002                    # the paired VIO position's noise
    lever_arm: bool = True                           # position residuals inform C's rotation through the lever arm
    gate_chi2: float = 22.46                         # innovation gate: chi-square, 6 dof, 99.9 %
    max_rejections: int = 10                         # rejections in a row that re-initialise the filter
    # predicting the VIO to the tick (docs/pipeline.md#predicting-the-vio-to-the-tick)
    velocity_fit_degree: int = 2                     # VIO fit without the accelerometer: 1 line, 2 quadratic
    velocity_window_s: float = 0.3                   # that fit's window of newest VIO samples
    use_gyro: bool = True                            # turn the newest VIO orientation on by the gyro
    gyro_window_s: float = 0.15                      # the held rate: mean of the newest gyro samples of this window
    # the held rate decays with a correlation time estimated online (docs/pipeline.md#the-gyros-held-rate)
    gyro_rate_adapt_s: float = 5.0                   # memory of that estimate (0: the time fixed at gyro_rate_time_s)
    gyro_rate_adapt_min_s: float = 2.0               # gyro history before that estimate is used
    gyro_rate_time_s: float = math.inf               # the correlation time before then, or always when fixed
    max_prediction_s: float = 0.5                    # never extrapolate further
    history_s: float = 1.0                           # VIO / IMU kept for pairing
    # the accelerometer (docs/pipeline.md#the-accelerometer)
    accel_prediction: bool = True                    # predict the position with the accelerometer (False: the VIO fit alone)
    accel_window_s: float = 1.0                      # VIO samples fitted, less the acceleration's double integral
    accel_fit_degree: int = 2                        # that fit's degree (its curvature takes up the accelerometer's bias)
    accel_recent_s: float = 0.05                     # the newest acceleration: mean over this window
    accel_smooth_s: float = 0.2                      # centred moving average of the acceleration (takes out tremor)
    accel_carry_time_s: float = 0.0                  # correlation time of the acceleration past the newest IMU sample
    # the output (docs/pipeline.md#the-output)
    marker_gain: float = 1.0                         # weight of a sighting against the previous output moved (1: the sighting)
    pull_marker_rotation_deg: float = 1.0            # a sighting's orientation error in the output's pull
    pull_vio_rotation_deg: float = 0.3               # the corrected VIO orientation's error where it has data
    pull_prediction_deg_per_s: float = 12.0          # growth of the predicted orientation's error past the data
    rotation_ambiguity_ref: float = 13.0             # a typical sighting's ambiguity ratio (#the-sightings-ambiguity); 0: off
    marker_velocity_window_s: float = 0.2            # the marker's velocity, used when it leaves the view
    blend_time_s: float = 0.1                        # decay of the offset carried across a source switch
    marker_to_tick: bool = True                      # move a sighting from its image time to the tick
    # correlation time of the acceleration carried over a tick entering the view (#entering-and-leaving-the-view)
    entry_acceleration_time_s: float = 0.05

    @classmethod
    def from_dict(cls, values: dict) -> FusionConfig:
        """The defaults with ``values`` (name -> number, or true/false/1/0 for a flag, as strings or values)."""
        known = {f.name: f.type for f in fields(cls)}
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise ConfigError(f"unknown T8 parameter(s) {', '.join(unknown)}; valid: {', '.join(known)}")
        out: dict[str, Any] = {k: _parse(k, v, str(known[k])) for k, v in values.items()}
        return cls(**out)


def _parse(name: str, value: Any, kind: str) -> bool | int | float:
    if kind in ("bool", str(bool)):
        text = str(value).strip().lower()
        if text in _TRUE or text in _FALSE:
            return text in _TRUE
        raise ConfigError(f"T8 parameter {name}={value!r} is not a flag: give true or false (1 or 0)")
    try:
        return int(value) if kind in ("int", str(int)) else float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"T8 parameter {name}={value!r} is not a number") from None
