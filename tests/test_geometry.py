"""Property tests of phonepose.geometry (hypothesis)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from phonepose.geometry import Pose, interpolate, interpolate_many

finite = st.floats(-10, 10, allow_nan=False)
vec3 = st.tuples(finite, finite, finite).map(np.array)
quat = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1).map(np.array)
poses = st.builds(Pose.from_xyzw, vec3, quat)


@given(poses)
def test_inverse(p):
    assert (p @ p.inv()).allclose(Pose.identity(), atol=1e-9)
    assert (p.inv() @ p).allclose(Pose.identity(), atol=1e-9)


@given(poses, poses, poses)
def test_associativity(a, b, c):
    assert ((a @ b) @ c).allclose(a @ (b @ c), atol=1e-8)


@given(poses, vec3)
def test_compose_matches_matrices(p, x):
    m = p.as_matrix()
    assert np.allclose(p.apply(x), (m @ np.append(x, 1.0))[:3], atol=1e-9)
    assert Pose.from_matrix(m).allclose(p, atol=1e-9)


@given(poses, poses)
def test_relative_pose(a, b):
    assert (b @ a.relative_to(b)).allclose(a, atol=1e-8)


@given(poses)
def test_foxglove_round_trip(p):
    assert Pose.from_foxglove(p.to_foxglove()).allclose(p, atol=1e-12)


@given(poses, poses, st.floats(0, 1))
def test_interpolation_end_points_and_monotone(a, b, s):
    assert interpolate(1.0, a, 3.0, b, 1.0).allclose(a, atol=1e-9)
    assert interpolate(1.0, a, 3.0, b, 3.0).allclose(b, atol=1e-9)
    mid = interpolate(1.0, a, 3.0, b, 1.0 + 2.0 * s)
    total = a.angle_to(b)
    assert np.isclose(a.angle_to(mid), s * total, atol=1e-7)
    assert np.allclose(mid.translation, a.translation + s * (b.translation - a.translation), atol=1e-9)


def test_interpolate_many_matches_single():
    rng = np.random.default_rng(0)
    times = np.array([0.0, 1.0, 2.5])
    stack = Pose(Rotation.random(3, random_state=1), rng.normal(size=(3, 3)))
    q = np.array([0.2, 1.7, 2.5])
    many = interpolate_many(times, stack, q)
    for k, t in enumerate(q):
        i = 0 if t <= 1.0 else 1
        single = interpolate(times[i], stack[i], times[i + 1], stack[i + 1], t)
        assert many[k].allclose(single, atol=1e-9)


def test_quaternion_order_is_xyzw():
    p = Pose.from_xyzw([0, 0, 0], [0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4)])  # 90 deg about z
    assert np.allclose(p.apply([1, 0, 0]), [0, 1, 0])
    fg = p.to_foxglove()
    assert np.isclose(fg.orientation.w, np.cos(np.pi / 4)) and np.isclose(fg.orientation.z, np.sin(np.pi / 4))


def test_cv_round_trip():
    p = Pose.from_rotvec([0.1, 0.2, 0.3], [0.3, -0.2, 0.1])
    rvec, tvec = p.as_cv()
    assert Pose.from_cv(rvec, tvec).allclose(p, atol=1e-12)
