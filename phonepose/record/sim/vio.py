"""What the phones' VIO and the Wi-Fi link get wrong (docs/simulation.md has the numbers).

Each VIO estimate is the true pose in that phone's VIO world, disturbed by
- a per-session scale error of the positions,
- a position random walk plus a drift proportional to the distance travelled,
- a yaw random walk (roll and pitch stay observable through gravity: white noise only),
- white jitter per pose.
Random walks live on a fixed internal grid, so sampling the same model at other instants (e.g.
to know where the CM1 CG object was fixed) gives the same drift.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.geometry import Pose
from phonepose.series import interp_columns

GRID_HZ = 100.0


@dataclass(frozen=True)
class VioErrorParams:
    jitter_m: float
    jitter_tilt_deg: float
    jitter_yaw_deg: float
    drift_m_per_sqrt_s: float
    drift_per_path_length: float
    yaw_drift_deg_per_sqrt_s: float
    scale_error_sigma: float
    jump_rate_per_min: float = 0.0       # relocalisation jumps (Poisson)
    jump_median_m: float = 0.03          # lognormal jump size: median, and 95 % below ~10x the median


class VioErrorModel:
    def __init__(self, params: VioErrorParams, duration_s: float, rng: np.random.Generator):
        self.params = params
        n = int(np.ceil(duration_s * GRID_HZ)) + 2
        self.grid = np.arange(n) / GRID_HZ
        dt = 1.0 / GRID_HZ
        steps = rng.normal(size=(n, 4)) * np.sqrt(dt)
        steps[0] = 0.0
        self.rw_pos = np.cumsum(steps[:, :3], axis=0) * params.drift_m_per_sqrt_s
        # Relocalisation jumps: the estimate steps by a lognormal distance in a random direction.
        # Drawn from a separate generator so that switching jumps on does not move other draws.
        jr = np.random.default_rng(rng.integers(1 << 62))
        n_jumps = jr.poisson(params.jump_rate_per_min * duration_s / 60.0)
        self.jump_times = np.sort(jr.uniform(0, duration_s, n_jumps))
        for t_jump in self.jump_times:
            d = jr.normal(size=3)
            size = params.jump_median_m * np.exp(jr.normal() * 1.4)
            self.rw_pos[int(np.ceil(t_jump * GRID_HZ)):] += d / np.linalg.norm(d) * size
        self.rw_yaw = np.cumsum(steps[:, 3]) * np.deg2rad(params.yaw_drift_deg_per_sqrt_s)
        self.drift_dir = rng.normal(size=3)
        self.drift_dir /= np.linalg.norm(self.drift_dir)
        self.scale = 1.0 + rng.normal() * params.scale_error_sigma
        self.path_length = np.zeros(n)

    def set_path(self, base_positions_on_grid: np.ndarray) -> None:
        """Cumulative distance travelled by the smooth motion (tremor does not make VIO drift)."""
        d = np.linalg.norm(np.diff(base_positions_on_grid, axis=0), axis=1)
        self.path_length = np.concatenate([[0.0], np.cumsum(d)])

    def _interp(self, t: np.ndarray, values: np.ndarray) -> np.ndarray:
        if values.ndim == 1:
            return np.interp(t, self.grid, values)
        return interp_columns(t, self.grid, values)

    def apply(self, t: np.ndarray, T_vio_body_true: Pose, white: np.ndarray | None = None) -> Pose:
        """VIO estimates of ``T_vio_body_true`` (a stack) sampled at times ``t`` (seconds)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        p = self.params
        drift = self._interp(t, self.rw_pos) + np.outer(self._interp(t, self.path_length),
                                                         self.drift_dir * p.drift_per_path_length)
        yaw = self._interp(t, self.rw_yaw)
        rot_err = Rotation.from_euler("z", yaw[:, None])
        pos = self.scale * T_vio_body_true.translation + drift
        if white is not None:
            # white: (n, 6) standard normal draws, made by the caller for the whole stream so that
            # sampling one instant again gives the same jitter
            pos = pos + white[:, :3] * p.jitter_m
            angles = white[:, 3:] * np.deg2rad([p.jitter_tilt_deg, p.jitter_tilt_deg, p.jitter_yaw_deg])
            rot_err = rot_err * Rotation.from_euler("xyz", angles)
        return Pose(rot_err * T_vio_body_true.rotation, pos)


def arrival_times(capture_s: np.ndarray, latency_s: float, jitter_mean_s: float, rng: np.random.Generator) -> np.ndarray:
    """When the display receives each controller message: capture + latency + an exponential
    Wi-Fi delay, never overtaking the previous message (one ordered TCP/UDP stream)."""
    extra = rng.exponential(jitter_mean_s, size=len(capture_s)) if jitter_mean_s > 0 else np.zeros(len(capture_s))
    return np.maximum.accumulate(capture_s + latency_s + extra)
