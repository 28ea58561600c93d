"""The controller's IMU (200 Hz) derived from the true motion, with phone-class noise and bias.

Angular velocity is the body-frame rate of the true orientation, the accelerometer measures the
specific force ``R^T (a - g)`` (gravity included, as Android reports it). Noise is white with the
configured density (sigma per sample = density * sqrt(rate)); each bias is a turn-on offset
plus a random walk.
"""

from __future__ import annotations

import numpy as np

from phonepose.record.sim.config import ImuConfig
from phonepose.record.sim.motion import Trajectory
from phonepose.record.sim.world import GRAVITY_WORLD

_H_ROT = 1e-4   # central-difference step for the angular rate (s)
_H_POS = 1e-3   # step for the acceleration (s): accurate to ~1e-3 relative at 12 Hz tremor


def true_imu(traj: Trajectory, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(gyro rad/s, accel m/s^2) of a perfect IMU in the controller body frame at times ``t``."""
    t = np.asarray(t, dtype=float)
    before, after = traj(t - _H_ROT), traj(t + _H_ROT)
    gyro = (before.rotation.inv() * after.rotation).as_rotvec() / (2 * _H_ROT)
    p_minus, p0, p_plus = traj(t - _H_POS), traj(t), traj(t + _H_POS)
    acc_world = (p_plus.translation - 2 * p0.translation + p_minus.translation) / _H_POS ** 2
    accel = p0.rotation.inv().apply(acc_world - GRAVITY_WORLD)
    return gyro, accel


def simulate_imu(traj: Trajectory, t: np.ndarray, cfg: ImuConfig, rng: np.random.Generator):
    """Measured (gyro, accel) with bias and noise; also returns the biases (for tests)."""
    gyro, accel = true_imu(traj, t)
    n = len(t)
    dt = 1.0 / cfg.rate_hz
    g_bias = rng.normal(size=3) * cfg.gyro_bias_sigma + \
        np.cumsum(rng.normal(size=(n, 3)), axis=0) * cfg.gyro_bias_random_walk * np.sqrt(dt)
    a_bias = rng.normal(size=3) * cfg.accel_bias_sigma + \
        np.cumsum(rng.normal(size=(n, 3)), axis=0) * cfg.accel_bias_random_walk * np.sqrt(dt)
    g_noise = rng.normal(size=(n, 3)) * cfg.gyro_noise_density * np.sqrt(cfg.rate_hz)
    a_noise = rng.normal(size=(n, 3)) * cfg.accel_noise_density * np.sqrt(cfg.rate_hz)
    return gyro + g_bias + g_noise, accel + a_bias + a_noise, (g_bias, a_bias)
