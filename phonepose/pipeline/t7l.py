"""T7L (ours): T7 with a latency-aware CM3 (docs/pipeline.md#t7l-latency-aware-cm3-ours)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from phonepose.geometry import Pose, interpolate, is_finite
from phonepose.pipeline.corrections import CM1Reading, Correction, CorrectionMath, marker_correction
from phonepose.pipeline.types import Observation

if TYPE_CHECKING:
    from phonepose.pipeline.trackers import TrackerSpec


class LatencyAwareCM3Tracker:
    """T7L (ours): T7 with a latency-aware CM3: marker inside the view, VIO + CM3 outside (se3 math).

    The controller's VIO reaches the display ~latency after its capture (log_time = receipt,
    message ``timestamp`` = capture). T7 pairs a marker with the VIO pose *received* by then, so
    its offset absorbs speed × latency. T7L instead:

    1. keeps the recent marker observations (image capture time, marker pose) and the received
       VIO samples (capture time, anchor-mapped pose); an observation is paired with the VIO
       pose interpolated at its image time as soon as a VIO sample captured after that time has
       arrived (about one latency later), and that pair renews the offset
       ``T_CM = T_marker · T_VIO^-1``;
    2. outside the view, predicts the newest VIO sample forward from its capture time to the
       tick time (constant velocity over ``velocity_window_ns``; orientation held) and applies
       the offset.

    Causal: only samples carried by this or earlier ticks are used. Before any offset it reports
    uncorrected VIO (as T7); without any stamped VIO sample it falls back to T7's VIO pose.
    """

    needs_camera = True
    uses_vio_samples = True             # reads obs.controller_vio_samples_dvio (the shared stages map them only then)
    velocity_window_ns = 100_000_000    # velocity from the newest sample and one ~0.1 s older
    max_prediction_ns = 500_000_000     # never predict further than this (the scheduler's largest gap)
    buffer_ns = 1_000_000_000           # VIO history kept

    def __init__(self, spec: TrackerSpec, correction_math: CorrectionMath = CorrectionMath.SE3,
                 cm1_reading: CM1Reading = CM1Reading.CONSISTENT):
        self.spec = spec
        self.name = spec.name
        self.correction_math = CorrectionMath.SE3
        self.reset()

    def reset(self) -> None:
        self.current: Correction | None = None
        self._pending: list[tuple[int, Pose]] = []     # (image capture ns, marker T_dvio_controller)
        self._vio: list[tuple[int, Pose]] = []         # (capture ns, anchor-mapped VIO), ascending

    def _vio_at(self, t_ns: int) -> Pose | None:
        """VIO interpolated at capture time ``t`` if samples bracket it, else None."""
        vio = self._vio
        for i in range(len(vio) - 1, 0, -1):
            t1, p1 = vio[i]
            t0, p0 = vio[i - 1]
            if t0 <= t_ns <= t1:
                return interpolate(t0, p0, t1, p1, t_ns) if t_ns != t0 else p0
        return None

    def _predict(self, t_ns: int) -> Pose | None:
        """The newest VIO sample moved to ``t`` at the velocity of the last ``velocity_window_ns``."""
        if not self._vio:
            return None
        tn, pn = self._vio[-1]
        dt = min(t_ns - tn, self.max_prediction_ns)
        if dt <= 0 or len(self._vio) < 2:
            return pn
        older = [s for s in self._vio[:-1] if tn - s[0] >= self.velocity_window_ns]
        to, po = older[-1] if older else self._vio[0]
        velocity = (pn.translation - po.translation) / (tn - to)
        return pn.with_translation(pn.translation + velocity * dt)

    def _take_vio(self, obs: Observation) -> None:
        """The tick's finite VIO samples newer than the newest kept, then the history pruned to ``buffer_ns``."""
        for capture_ns, pose in obs.controller_vio_samples_dvio:
            if is_finite(pose) and (not self._vio or capture_ns > self._vio[-1][0]):
                self._vio.append((capture_ns, pose))
        if self._vio:
            horizon = self._vio[-1][0] - self.buffer_ns
            while len(self._vio) > 2 and self._vio[1][0] < horizon:
                self._vio.pop(0)

    def _pair_pending(self) -> None:
        """Renew the offset from every observation whose image time VIO captures now bracket."""
        keep = []
        for image_ns, marker in self._pending:
            if self._vio and self._vio[-1][0] >= image_ns:
                vio = self._vio_at(image_ns)
                if vio is not None:
                    self.current = marker_correction(marker, vio, CorrectionMath.SE3)
                # else older than the VIO history: dropped
            else:
                keep.append((image_ns, marker))
        self._pending = keep

    def step(self, obs: Observation) -> Pose | None:
        self._take_vio(obs)
        frame = obs.tick.new_frame   # an observation counts once, on the tick that first carries its frame
        if obs.marker is not None and is_finite(obs.marker.T_dvio_controller) and frame is not None:
            self._pending.append((frame.t_ns, obs.marker.T_dvio_controller))
        self._pair_pending()
        if obs.marker is not None:   # in view; a non-finite marker pose gives no estimate, as for T1-T7
            return obs.marker.T_dvio_controller if is_finite(obs.marker.T_dvio_controller) else None
        vio = self._predict(obs.tick.t_ns)
        if vio is None:
            vio = obs.T_dvio_controller_vio
        if not is_finite(vio):
            return None
        est = vio if self.current is None else self.current.apply(vio)
        return est if is_finite(est) else None

    def __repr__(self) -> str:
        return f"{self.name}(marker/VIO/latency-aware CM3, se3)"
