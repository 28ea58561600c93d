"""What T8 reads of a tick's phonepose.pipeline.types.Observation, as structural types: the package does
not import phonepose.pipeline, whose tracker registry imports it."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from phonepose.geometry import Pose


class FrameInput(Protocol):
    @property
    def t_ns(self) -> int: ...          # the image's capture time


class TickInput(Protocol):
    @property
    def t_ns(self) -> int: ...

    @property
    def imu(self) -> np.ndarray: ...    # rows t_s, gx gy gz, ax ay az received since the last tick

    @property
    def new_frame(self) -> FrameInput | None: ...

    @property
    def T_dvio_display(self) -> Pose | None: ...


class MarkerInput(Protocol):
    @property
    def T_dvio_controller(self) -> Pose | None: ...

    @property
    def ambiguity_ratio(self) -> float: ...


class ObservationInput(Protocol):
    @property
    def tick(self) -> TickInput: ...

    @property
    def marker(self) -> MarkerInput | None: ...

    @property
    def T_dvio_controller_vio(self) -> Pose | None: ...

    @property
    def controller_vio_samples_dvio(self) -> list: ...   # (capture ns, anchor-mapped VIO Pose)

    @property
    def in_view(self) -> bool: ...
