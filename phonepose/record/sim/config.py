"""Configuration of the simulated world: typed dataclasses filled from TOML.

Defaults live in ``default.toml`` next to this module (one place, documented in
docs/simulation.md); a user file overrides any subset of it. Unknown sections or keys, wrong
types and out-of-range values raise :class:`~phonepose.errors.ConfigError` naming the key and
the allowed range.
"""

from __future__ import annotations

import dataclasses
import os
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from typing import Any

from phonepose.errors import ConfigError, InputFileError


def _r(lo: float, hi: float, help: str = "") -> Any:
    """A field with an allowed closed range [lo, hi] (no default: defaults come from default.toml)."""
    return field(metadata={"range": (lo, hi), "help": help})


def _choice(*values: str) -> Any:
    return field(metadata={"choices": values})


def _flag() -> Any:
    """A true/false field (typed Any like the others, so mypy does not read a default into ``_r``'s fields)."""
    return field(metadata={})


@dataclass(frozen=True)
class CameraConfig:
    rate_hz: float = _r(1, 120)
    fx: float = _r(100, 2000)
    fy: float = _r(100, 2000)
    k1: float = _r(-0.5, 0.5)
    k2: float = _r(-0.5, 0.5)
    p1: float = _r(-0.05, 0.05)
    p2: float = _r(-0.05, 0.05)
    k3: float = _r(-0.5, 0.5)
    frame_jitter_s: float = _r(0, 0.01)
    drop_rate: float = _r(0, 0.5)
    tilt_down_deg: float = _r(-45, 45)


@dataclass(frozen=True)
class RenderConfig:
    noise_sigma_dn: float = _r(0, 30)
    motion_blur: bool = _flag()
    exposure_s: float = _r(0, 0.05)
    brightness_variation: float = _r(0, 0.5)
    jpeg_quality: int = _r(10, 100)
    screen_white_dn: int = _r(50, 255)
    screen_black_dn: int = _r(0, 200)


@dataclass(frozen=True)
class MarkerConfig:
    dictionary: str = _choice("DICT_4X4_50", "DICT_4X4_100", "DICT_4X4_250", "DICT_5X5_50", "DICT_6X6_250")
    id: int = _r(0, 49)
    size_m: float = _r(0.01, 0.05)   # the marker and its quiet zone must fit on the 67 mm wide screen


@dataclass(frozen=True)
class DisplayVioConfig:
    jitter_m: float = _r(0, 0.05)
    jitter_deg: float = _r(0, 5)
    drift_m_per_sqrt_s: float = _r(0, 0.05)
    yaw_drift_deg_per_sqrt_s: float = _r(0, 5)
    rate_hz: float = _r(1, 120)


@dataclass(frozen=True)
class ControllerVioConfig:
    jitter_m: float = _r(0, 0.05)
    tilt_jitter_deg: float = _r(0, 5)
    drift_m_per_sqrt_s: float = _r(0, 0.05)
    drift_per_path_length: float = _r(0, 0.5)
    yaw_drift_deg_per_sqrt_s: float = _r(0, 5)
    scale_error_sigma: float = _r(0, 0.3)
    jump_rate_per_min: float = _r(0, 60)
    jump_median_m: float = _r(0, 2)
    rate_hz: float = _r(1, 120)


@dataclass(frozen=True)
class AnchorConfig:
    controller_translation_m: float = _r(0, 2)
    controller_yaw_deg: float = _r(0, 45)
    controller_tilt_deg: float = _r(0, 10)
    display_translation_m: float = _r(0, 2)
    display_yaw_deg: float = _r(0, 45)
    display_tilt_deg: float = _r(0, 10)
    distance_m: float = _r(0.1, 5)
    rate_hz: float = _r(0.1, 60)


@dataclass(frozen=True)
class NetworkConfig:
    controller_latency_s: float = _r(0, 1)
    wifi_jitter_s: float = _r(0, 0.5)
    controller_clock_offset_s: float = _r(-1, 1)


@dataclass(frozen=True)
class ImuConfig:
    rate_hz: float = _r(50, 1000)
    drop_rate: float = _r(0, 0.5)
    gyro_noise_density: float = _r(0, 0.01)
    accel_noise_density: float = _r(0, 0.1)
    gyro_bias_sigma: float = _r(0, 0.1)
    accel_bias_sigma: float = _r(0, 1)
    gyro_bias_random_walk: float = _r(0, 0.01)
    accel_bias_random_walk: float = _r(0, 0.1)


@dataclass(frozen=True)
class MocapConfig:
    rate_hz: float = _r(10, 500)
    noise_m: float = _r(0, 0.01)
    noise_deg: float = _r(0, 2)
    hand_eye_rotation_deg: float = _r(0, 45)
    hand_eye_translation_m: float = _r(0, 0.1)
    clock_offset_s: float = _r(-1, 1)
    calibration_translation_m: float = _r(0, 0.1)
    calibration_rotation_deg: float = _r(0, 10)
    exact: bool = _flag()

    # the errors `exact = true` switches off: ground truth = the phone's true pose on the display's clock
    ERRORS = ("noise_m", "noise_deg", "hand_eye_rotation_deg", "hand_eye_translation_m", "clock_offset_s",
              "calibration_translation_m", "calibration_rotation_deg")

    def effective(self) -> MocapConfig:
        """The configuration the simulator uses: with ``exact``, every mocap error is zero (the random
        draws still happen, so every other stream of the session is unchanged)."""
        off: dict[str, Any] = {k: 0.0 for k in self.ERRORS}   # (replace() is typed per field)
        return dataclasses.replace(self, **off) if self.exact else self


@dataclass(frozen=True)
class HumanConfig:
    tremor_m: float = _r(0, 0.01)
    tremor_deg: float = _r(0, 5)
    sway_m: float = _r(0, 0.05)
    sway_deg: float = _r(0, 10)
    orientation_variation_deg: float = _r(0, 40)
    cm1_alignment_m: float = _r(0, 0.05)
    cm1_alignment_deg: float = _r(0, 10)
    speed_variation: float = _r(0, 0.5)


@dataclass(frozen=True)
class SimConfig:
    camera: CameraConfig
    render: RenderConfig
    marker: MarkerConfig
    display_vio: DisplayVioConfig
    controller_vio: ControllerVioConfig
    anchor: AnchorConfig
    network: NetworkConfig
    imu: ImuConfig
    mocap: MocapConfig
    human: HumanConfig

    def to_toml(self) -> str:
        """The full effective configuration as TOML (stored in SessionInfo.config_toml)."""
        return to_toml(dataclasses.asdict(self))

    def replace(self, **sections: dict) -> SimConfig:
        """A copy with some keys changed: ``cfg.replace(render={"noise_sigma_dn": 0})``."""
        data = dataclasses.asdict(self)
        _merge(data, sections, "")
        return _build(data)


_SECTIONS = {f.name: f.type for f in dataclasses.fields(SimConfig)}
_SECTION_TYPES = {
    "camera": CameraConfig, "render": RenderConfig, "marker": MarkerConfig, "display_vio": DisplayVioConfig,
    "controller_vio": ControllerVioConfig, "anchor": AnchorConfig, "network": NetworkConfig, "imu": ImuConfig,
    "mocap": MocapConfig, "human": HumanConfig,
}


def default_toml_text() -> str:
    return resources.files("phonepose.record.sim").joinpath("default.toml").read_text(encoding="utf-8")


def default_config() -> SimConfig:
    return _build(tomllib.loads(default_toml_text()))


# tomllib takes quadratic time in the depth of a dotted key ([a.a.a...]: 40 KB take 3 s); the whole
# default config with its comments is 4.5 KB, so a user's overrides fit well under this bound.
MAX_CONFIG_BYTES = 32 * 1024


def load_config(path: str | os.PathLike | None = None, overrides: dict | None = None) -> SimConfig:
    """Defaults, then the TOML file at ``path`` (any subset), then ``overrides`` (same nesting)."""
    data = tomllib.loads(default_toml_text())
    if path is not None:
        from phonepose.files import read_text_input

        try:
            # a FIFO or device: refused, never opened (it could block); a binary or huge file: refused while
            # read; a UTF-8 byte-order mark (which tomllib refuses) dropped
            text = read_text_input(path, "TOML file", limit=MAX_CONFIG_BYTES,
                                   note=f"every parameter with comments is {len(default_toml_text()) / 1024:.1f} KiB")
            user = tomllib.loads(text)
        except InputFileError as exc:
            raise ConfigError(f"config file {exc}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"config file {os.fspath(path)}: invalid TOML ({exc})") from None
        except RecursionError:
            raise ConfigError(f"config file {os.fspath(path)}: invalid TOML (nested too deeply)") from None
        _merge(data, user, "")
    if overrides:
        _merge(data, overrides, "")
    return _build(data)


def _merge(base: dict, user: dict, where: str) -> None:
    for key, value in user.items():
        name = f"{where}{key}"
        if key not in base:
            known = ", ".join(sorted(base))
            raise ConfigError(f"unknown config key {name!r} (known here: {known})")
        if isinstance(base[key], dict):
            if not isinstance(value, dict):
                raise ConfigError(f"config key {name!r} must be a [section]")
            _merge(base[key], value, f"{name}.")
        else:
            base[key] = value


def _build(data: dict) -> SimConfig:
    sections = {}
    for sname, cls in _SECTION_TYPES.items():
        raw = data.get(sname)
        if not isinstance(raw, dict):
            raise ConfigError(f"config section [{sname}] is missing")
        values = {}
        for f in dataclasses.fields(cls):
            key = f"{sname}.{f.name}"
            if f.name not in raw:
                raise ConfigError(f"config key {key!r} is missing")
            values[f.name] = _check(key, f, raw[f.name])
        extra = set(raw) - {f.name for f in dataclasses.fields(cls)}
        if extra:
            raise ConfigError(f"unknown config key {sname}.{sorted(extra)[0]!r}")
        sections[sname] = cls(**values)
    sections["mocap"] = sections["mocap"].effective()
    extra = set(data) - set(_SECTION_TYPES)
    if extra:
        raise ConfigError(f"unknown config section [{sorted(extra)[0]}]")
    return SimConfig(**sections)


def _check(key: str, f: dataclasses.Field, value: Any) -> Any:
    kind = f.type if isinstance(f.type, str) else f.type.__name__
    if kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"config key {key!r} must be true or false, got {value!r}")
        return value
    if kind == "str":
        choices = f.metadata.get("choices")
        if not isinstance(value, str) or (choices and value not in choices):
            raise ConfigError(f"config key {key!r} must be one of {', '.join(choices or ())}, got {value!r}")
        return value
    lo, hi = f.metadata["range"]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"config key {key!r} must be a number in [{lo}, {hi}], got {value!r}")
    if kind == "int":
        if isinstance(value, float) and not value.is_integer():
            raise ConfigError(f"config key {key!r} must be an integer in [{lo}, {hi}], got {value!r}")
        value = int(value)
    else:
        value = float(value)
    if not (lo <= value <= hi):
        raise ConfigError(f"config key {key!r} = {value!r} is out of range: allowed [{lo}, {hi}]")
    return value


def to_toml(data: dict) -> str:
    """Serialise a two-level dict of scalars as TOML (tomllib reads it back equal)."""
    lines = []
    for sname, section in data.items():
        lines.append(f"[{sname}]")
        for key, value in section.items():
            lines.append(f"{key} = {_toml_value(value)}")
        lines.append("")
    return "\n".join(lines)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    raise TypeError(f"cannot write {v!r} as TOML")
