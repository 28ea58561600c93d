"""phonepose/series.py: the stamps kept as rising, and np.interp for every column at once (to the bit)."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from phonepose.series import interp_columns, interp_columns_inside, newer_than_before


@given(st.lists(st.integers(-5_000_000, 5_000_000), min_size=2, max_size=40, unique=True),
       st.integers(0, 2**32 - 1), st.integers(1, 60))
def test_interpolating_every_column_at_once_is_np_interp_per_column(xp_us, seed, n_x):
    """np.interp per column, to the bit: at a scalar and at fewer and more points than samples, the samples
    themselves, both ends, points outside the samples (numpy's end values) and NaN."""
    xp = np.sort(np.array(xp_us)) * 1e-5
    rng = np.random.default_rng(seed)
    fp = rng.normal(size=(len(xp), 6)) * rng.choice([1e-3, 1.0, 1e3])
    span = xp[-1] - xp[0]
    x = np.sort(np.concatenate([rng.uniform(xp[0], xp[-1], n_x), rng.choice(xp, 2), xp[[0, -1]],
                                [xp[0] - span, xp[-1] + 0.5 * span]]))
    x = np.append(x, np.nan)
    expected = np.stack([np.interp(x, xp, fp[:, j]) for j in range(6)], axis=1)
    assert interp_columns(x, xp, fp).tobytes() == expected.tobytes()
    inside = x[(x >= xp[0]) & (x < xp[-1])]        # (NaN is neither)
    assert np.array_equal(interp_columns_inside(inside, xp, fp), expected[(x >= xp[0]) & (x < xp[-1])])
    for x_one in (float(x[0]), float(x[1]), float(x[len(x) // 2]), float(xp[-1]), float(x[-2])):
        one = np.array([np.interp(x_one, xp, fp[:, j]) for j in range(6)])
        assert interp_columns(x_one, xp, fp).tobytes() == one.tobytes()


def test_repeated_stamps_and_infinite_values_take_numpy_s_own_fallbacks():
    xp = np.array([0.0, 1.0, 1.0, 2.0])          # a repeated stamp: an infinite slope between them
    fp = np.array([[0.0, 1.0], [1.0, 2.0], [3.0, 2.0], [4.0, np.inf]])
    x = np.array([-1.0, 0.5, 1.0, 1.5, 2.0, 3.0])
    expected = np.stack([np.interp(x, xp, fp[:, j]) for j in range(2)], axis=1)
    assert interp_columns(x, xp, fp).tobytes() == expected.tobytes()
    for i, x_one in enumerate(x.tolist()):      # one float at a time: the row path, the same fallbacks
        assert interp_columns(x_one, xp, fp).tobytes() == expected[i].tobytes()


def test_newer_than_before_keeps_each_stamp_above_all_earlier_ones():
    t = np.array([1.0, 2.0, 2.0, 1.5, 3.0, np.nextafter(3.0, 4.0)])
    assert newer_than_before(t).tolist() == [True, True, False, False, True, True]
    assert newer_than_before(t, after=2.0).tolist() == [False, False, False, False, True, True]
    assert newer_than_before(t, after=-np.inf).tolist() == newer_than_before(t).tolist()
    assert newer_than_before(np.zeros(0)).tolist() == []
    # nanosecond stamps beyond 2**53 differ by 1 ns: compared as integers (as floats they would be equal)
    big = 2**62 + np.array([0, 1, 1, 0, 2], dtype=np.int64)
    assert newer_than_before(big).tolist() == [True, True, False, False, True]
    smallest = np.array([np.iinfo(np.int64).min, 5, 4], dtype=np.int64)
    assert newer_than_before(smallest).tolist() == [True, True, False]
    assert newer_than_before(big, after=int(big[1])).tolist() == [False, False, False, False, True]
