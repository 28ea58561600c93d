"""Human-like motion of the controller: minimum-jerk moves between key poses, plus tremor.

A :class:`Trajectory` is an analytic function of time (no sampling grid), so every stream
(camera, VIO, IMU, mocap) samples the very same motion at its own instants. The base motion
goes through key poses with the minimum-jerk profile (Flash & Hogan 1985: the smooth
point-to-point reaching of a human arm); on top of it sit physiological tremor (8-12 Hz) and
slow postural sway (0.2-1 Hz), each a sum of sinusoids with seeded frequencies and phases.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.geometry import Pose


def min_jerk(s: np.ndarray) -> np.ndarray:
    """Minimum-jerk position profile on [0, 1]: zero velocity and acceleration at both ends."""
    s = np.clip(s, 0.0, 1.0)
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


@dataclass
class KeyPose:
    t: float                 # seconds from the session start
    position: np.ndarray     # world, (3,)
    rotation: Rotation       # world


class Oscillation:
    """A smooth zero-mean 3-vector signal: a sum of sinusoids in a frequency band, RMS ``amplitude`` per axis."""

    def __init__(self, rng: np.random.Generator, amplitude: float, band_hz: tuple[float, float], n: int = 4):
        self.freq = rng.uniform(*band_hz, size=(n, 3))
        self.phase = rng.uniform(0, 2 * np.pi, size=(n, 3))
        w = rng.uniform(0.5, 1.0, size=(n, 3))
        # RMS of a sum of sinusoids with amplitudes a_i is sqrt(sum a_i^2 / 2).
        self.amp = w / np.sqrt((w ** 2).sum(axis=0) / 2) * amplitude

    def __call__(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)[..., None, None]
        return (self.amp * np.sin(2 * np.pi * self.freq * t + self.phase)).sum(axis=-2)


class Trajectory:
    """The true pose of the controller body in the world, T_world_controller(t)."""

    def __init__(self, keys: list[KeyPose], tremor_pos: Oscillation, tremor_rot: Oscillation,
                 sway_pos: Oscillation, sway_rot: Oscillation):
        keys = sorted(keys, key=lambda k: k.t)
        self.keys = keys
        self.t = np.array([k.t for k in keys])
        if np.any(np.diff(self.t) <= 0):
            raise ValueError("key poses must have increasing times")
        self.p = np.array([k.position for k in keys])
        self.r = Rotation.concatenate([k.rotation for k in keys])
        # Rotation from each key to the next, as a rotation vector in the key's body frame.
        self.dr = (self.r[:-1].inv() * self.r[1:]).as_rotvec()
        self.tremor_pos, self.tremor_rot = tremor_pos, tremor_rot
        self.sway_pos, self.sway_rot = sway_pos, sway_rot

    @property
    def start(self) -> float:
        return float(self.t[0])

    @property
    def end(self) -> float:
        return float(self.t[-1])

    def _segment(self, t: np.ndarray):
        t = np.clip(np.asarray(t, dtype=float), self.t[0], self.t[-1])
        i = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 2)
        s = min_jerk((t - self.t[i]) / (self.t[i + 1] - self.t[i]))
        return i, s

    def base(self, t) -> Pose:
        """The smooth motion without tremor or sway."""
        t = np.atleast_1d(t)
        i, s = self._segment(t)
        pos = self.p[i] + s[:, None] * (self.p[i + 1] - self.p[i])
        rot = self.r[i] * Rotation.from_rotvec(s[:, None] * self.dr[i])
        return Pose(rot, pos)

    def __call__(self, t) -> Pose:
        """T_world_controller at times ``t`` (seconds, array): base motion, tremor and sway."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        b = self.base(t)
        dp = self.tremor_pos(t) + self.sway_pos(t)
        drot = Rotation.from_rotvec(self.tremor_rot(t) + self.sway_rot(t))   # in the body frame
        return Pose(b.rotation * drot, b.translation + dp)


def make_oscillations(rng: np.random.Generator, tremor_m: float, tremor_deg: float, sway_m: float, sway_deg: float):
    return (Oscillation(rng, tremor_m, (8.0, 12.0)), Oscillation(rng, np.deg2rad(tremor_deg), (8.0, 12.0)),
            Oscillation(rng, sway_m, (0.2, 1.0)), Oscillation(rng, np.deg2rad(sway_deg), (0.2, 1.0)))
