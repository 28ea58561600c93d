"""Lag, jitter and availability (phonepose.evaluation.controller) on hand-built trajectories with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from phonepose.evaluation.controller import (
    LAG_RESOLUTION_S,
    availability,
    controller_metrics,
    jitter,
    lag,
    lag_curve,
    still_ticks,
)
from phonepose.geometry import Pose

TICK = 0.05


def _path(t: np.ndarray) -> np.ndarray:
    """A hand-like motion: 20 cm sweeps at 0.4 Hz and 0.7 Hz."""
    return np.column_stack([0.2 * np.sin(2 * np.pi * 0.4 * t), 0.1 * np.cos(2 * np.pi * 0.7 * t), 0.05 * t])


def _still(n: int, offsets: np.ndarray | None = None, rotvecs: np.ndarray | None = None) -> tuple[Pose, Pose]:
    gt = Pose(Rotation.from_rotvec(np.tile([0.1, 0.2, 0.3], (n, 1))), np.tile([0.0, 0.5, 1.0], (n, 1)))
    est_t = gt.translation + (0 if offsets is None else offsets)
    est_r = gt.rotation if rotvecs is None else Rotation.from_rotvec(rotvecs) * gt.rotation
    return gt, Pose(est_r, est_t)


def test_a_pure_100_ms_delay_is_a_lag_of_100_ms():
    t = np.arange(0, 20, TICK)
    assert lag(t, _path(t), t, _path(t - 0.1)) == pytest.approx(0.1, abs=1e-12)
    assert lag(t, _path(t), t, _path(t + 0.05)) == pytest.approx(-0.05, abs=1e-12)   # ahead: negative
    assert lag(t, _path(t), t, _path(t)) == 0.0
    # a delay between two grid points is found to the resolution
    assert abs(lag(t, _path(t), t, _path(t - 0.1234)) - 0.1234) <= LAG_RESOLUTION_S / 2 + 1e-3


def _lag_by_definition(t_gt, p_gt, t_est, p_est) -> tuple[float | None, list[float]]:
    """The module docstring's lag, one shift at a time: (the argmin, every shift's mean squared error)."""
    best, best_err, errors = None, np.inf, []
    steps = round(0.5 / LAG_RESOLUTION_S)
    for k in range(-steps, steps + 1):
        tau = k * LAG_RESOLUTION_S
        q = t_gt + tau
        use = (q >= t_est[0]) & (q <= t_est[-1])
        if use.sum() < max(2, t_gt.size // 2):
            continue
        moved = np.column_stack([np.interp(q[use], t_est, p_est[:, i]) for i in range(3)])
        errors.append(float(np.mean(np.sum((moved - p_gt[use]) ** 2, axis=1))))
        if errors[-1] < best_err:
            best, best_err = tau, errors[-1]
    return best, errors


@pytest.mark.parametrize("n", [3, 40, 290, 2257])   # one block of shifts up to ~300 stamps, several beyond
def test_lag_is_its_definition_shift_by_shift(n):
    """lag_curve() interpolates many shifts per call (a short session's playback spent a fifth of its time in
    per-shift calls); every shift's error is the definition's to the bit, so lag()'s choice is too."""
    rng = np.random.default_rng(n)
    t_gt = np.sort(rng.uniform(0, n * TICK, n))
    p_gt = _path(t_gt) + rng.normal(0, 0.002, (n, 3))
    t_est = np.unique(rng.uniform(-0.2, n * TICK + 0.2, max(2, n - 3)))
    p_est = _path(t_est - 0.12) + rng.normal(0, 0.002, (len(t_est), 3))
    shifts, errors = lag_curve(t_gt, p_gt, t_est, p_est)
    want, want_errors = _lag_by_definition(t_gt, p_gt, t_est, p_est)
    assert np.array(errors).tobytes() == np.array(want_errors).tobytes() and len(shifts) == len(errors)
    assert lag(t_gt, p_gt, t_est, p_est) == want
    assert n < 40 or abs(want - 0.12) < 0.02           # and it finds the delay


def test_lag_curve_interpolates_as_np_interp_inside_the_estimate_stamps():
    """The interpolation under lag_curve, point by point, to the bit: at the stamps themselves (the last one
    included), between them, and shifted by the lag grid (points outside are left out of the curve)."""
    from phonepose.evaluation.controller import _Segments
    from phonepose.series import interp_columns

    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0, 10, 200))
    p = rng.normal(size=(200, 3)) * 0.3
    x = np.concatenate([t, rng.uniform(-1, 11, 500), (t[None, :] + np.arange(-3, 4)[:, None] * LAG_RESOLUTION_S).ravel()])
    inside = (x >= t[0]) & (x <= t[-1])
    assert np.column_stack(_Segments(t, p).columns(x))[inside].tobytes() == interp_columns(x, t, p)[inside].tobytes()


@pytest.mark.parametrize("n", [40, 2257])
def test_lag_on_the_ticks_themselves_is_its_definition(n):
    """As a playback scores it: the estimate on the truth's own 20 Hz stamps, so that shifted stamps meet
    estimate stamps exactly (every one at shift 0, the last one at the end): np.interp's sample values there,
    to the bit; a repeated stamp takes np.interp's own fallbacks."""
    t = np.round(np.arange(n) * TICK, 9)
    rng = np.random.default_rng(n)
    p_gt = _path(t) + rng.normal(0, 0.002, (n, 3))
    p_est = _path(t - 0.1) + rng.normal(0, 0.002, (n, 3))
    _, errors = lag_curve(t, p_gt, t, p_est)
    want, want_errors = _lag_by_definition(t, p_gt, t, p_est)
    assert np.array(errors).tobytes() == np.array(want_errors).tobytes() and lag(t, p_gt, t, p_est) == want
    t_rep = t.copy()
    t_rep[n // 2] = t_rep[n // 2 - 1]                  # a repeated stamp: an infinite slope
    _, errors = lag_curve(t, p_gt, t_rep, p_est)
    assert np.array(errors).tobytes() == np.array(_lag_by_definition(t, p_gt, t_rep, p_est)[1]).tobytes()


def test_white_noise_while_still_has_jitter_sigma_root_3_and_drift_none():
    n = 40_000
    rng = np.random.default_rng(1)
    t = np.arange(n) * TICK
    gt, est = _still(n, rng.normal(size=(n, 3)) * 0.001, rng.normal(size=(n, 3)) * np.radians(0.1))
    j_p, j_r = jitter(t, gt, est, np.ones(n, bool))
    assert j_p == pytest.approx(0.001 * np.sqrt(3), rel=0.02)
    assert j_r == pytest.approx(0.1 * np.sqrt(3), rel=0.02)
    # a constant offset and a linear drift are error, not jitter
    gt, est = _still(n, np.outer(t, [0.001, -0.002, 0.0005]) + 0.03, np.outer(t, [0.0, 0.0, 1e-4]))
    j_p, j_r = jitter(t, gt, est, np.ones(n, bool))
    assert j_p < 1e-12 and j_r < 1e-9


def test_gaps_count_against_availability_and_break_jitter_runs():
    t = np.arange(100) * TICK
    assert availability(100, 75) == 0.75 and availability(0, 0) is None
    # 10 ticks without an estimate, and the error steps by 5 cm across the gap: no triple spans it
    keep = np.r_[0:40, 50:100]
    offsets = np.where(t[keep, None] < 2.2, 0.0, 0.05) * np.ones((1, 3))
    gt, est = _still(keep.size, offsets)
    j_p, _ = jitter(t[keep], gt, est, np.ones(keep.size, bool))
    assert j_p == 0.0
    # without the gap the same step is jitter: one triple of 3 per side of the step
    gt, est = _still(100, np.where(t[:, None] < 2.2, 0.0, 0.05) * np.ones((1, 3)))
    j_p, _ = jitter(t, gt, est, np.ones(100, bool))
    assert j_p == pytest.approx(np.sqrt(2 * 3 * 0.05 ** 2 / (6 * 98)), rel=1e-12)


def test_still_ticks_are_where_the_truth_stays_within_a_centimetre():
    t = np.arange(0, 6, TICK)
    p = np.zeros((t.size, 3))
    p[:, 0] = np.clip(t - 2.0, 0.0, 1.0) * 0.2          # 20 cm between 2 s and 3 s, still before and after
    still = still_ticks(t, p)
    assert still[(t > 0.3) & (t < 1.7)].all() and not still[(t > 2.0) & (t < 3.0)].any()
    assert still[(t > 3.3) & (t < 5.7)].all() and not still[t < 0.2].any()      # the window must fit


def test_controller_metrics_of_a_delayed_tracker_with_gaps():
    t = np.arange(0, 20, TICK)
    gt = Pose(Rotation.identity(t.size), _path(t))
    keep = np.arange(t.size) % 4 != 0                     # a quarter of the ticks without an estimate
    est = Pose(Rotation.identity(int(keep.sum())), _path(t[keep] - 0.1))
    common, i_gt, i_est = np.intersect1d(t, t[keep], return_indices=True)
    m = controller_metrics(t, gt, t[keep], est, common, i_gt, i_est)
    assert m["availability"] == 0.75 and m["lag_resolution_s"] == LAG_RESOLUTION_S
    assert abs(m["lag_s"] - 0.1) <= 0.01        # the gaps leave straight lines over 2 ticks: within 2 grid steps
    assert m["jitter_m"] is None and m["still_ticks"] == 0        # never held still
