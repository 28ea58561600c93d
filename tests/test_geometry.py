"""Property tests of phonepose.geometry (hypothesis)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp

from phonepose.geometry import (
    Pose,
    interpolate,
    interpolate_many,
    quat_apply_rows,
    quat_as_rotvec,
    quat_from_rotvec,
    quat_inv,
    quat_matrix,
    quat_mul,
    quat_normalised,
    quat_rotate,
    quat_slerp,
    raw_compose,
    raw_interpolate,
    rotation_inverse,
    rotation_product,
)

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
    assert np.allclose(p.quat_xyzw, [0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4)])


def test_cv_round_trip():
    p = Pose.from_rotvec([0.1, 0.2, 0.3], [0.3, -0.2, 0.1])
    rvec, tvec = p.as_cv()
    assert Pose.from_cv(rvec, tvec).allclose(p, atol=1e-12)


# ----------------------------------------------------------------------------- raw poses against scipy
unit_quat = quat.map(lambda q: tuple(q / np.linalg.norm(q)))
fractions = st.floats(0, 1)


def _angle(q_a, q_b) -> float:
    """Rotation angle between two quaternions (q and -q are the same rotation)."""
    return float((Rotation.from_quat(q_a).inv() * Rotation.from_quat(q_b)).magnitude())


def _scipy_slerp(q0, q1, a: float):
    return Slerp([0.0, 1.0], Rotation.from_quat([q0, q1]))([a]).as_quat()[0]


@given(unit_quat, unit_quat, fractions)
def test_slerp_matches_scipy(q0, q1, a):
    got = quat_slerp(q0, q1, a)
    assert abs(np.linalg.norm(got) - 1.0) < 1e-12
    assert _angle(got, _scipy_slerp(q0, q1, a)) < 1e-7


@given(unit_quat, unit_quat, fractions)
def test_slerp_takes_the_short_way_when_the_dot_product_is_negative(q0, q1, a):
    flipped = tuple(-v for v in q1)            # the same rotation, the other hemisphere: dot < 0 for one of them
    assert _angle(quat_slerp(q0, flipped, a), quat_slerp(q0, q1, a)) < 1e-7
    assert _angle(quat_slerp(q0, flipped, a), _scipy_slerp(q0, q1, a)) < 1e-7


@given(unit_quat, vec3.filter(lambda v: np.linalg.norm(v) > 1e-3), st.floats(1e-9, 1.9e-3), fractions, st.booleans())
def test_slerp_of_near_parallel_quaternions_blends_linearly_and_matches_scipy(q0, axis, angle, a, flip):
    """Below 2e-3 rad apart (|dot| > 0.9999995) the blend is linear: its error is ~angle^3, far below 1e-9 rad."""
    r1 = Rotation.from_quat(q0) * Rotation.from_rotvec(angle * axis / np.linalg.norm(axis))
    q1 = tuple(r1.as_quat() * (-1 if flip else 1))
    assert abs(np.dot(q0, q1)) > 0.9999995          # the branch under test
    got = quat_slerp(q0, q1, a)
    assert _angle(got, _scipy_slerp(q0, q1, a)) < 1e-9
    assert abs(_angle(q0, got) - a * angle) < 1e-9


def test_slerp_end_points_and_the_exact_opposite_sign():
    q = (0.0, 0.0, np.sin(0.3), np.cos(0.3))
    assert quat_slerp(q, q, 0.5) == q
    assert np.allclose(quat_slerp(q, tuple(-v for v in q), 0.25), q)   # -q is q: no turn at all


@given(unit_quat, unit_quat)
def test_quat_mul_matches_scipy(a, b):
    assert _angle(quat_mul(a, b), (Rotation.from_quat(a) * Rotation.from_quat(b)).as_quat()) < 1e-9


@given(unit_quat, vec3)
def test_quat_rotate_matches_scipy(q, v):
    assert np.allclose(quat_rotate(q, tuple(v)), Rotation.from_quat(q).apply(v), atol=1e-9)


@given(poses, poses)
def test_raw_compose_is_pose_composition(a, b):
    got = Pose.from_raw(raw_compose(a.as_raw(), b.as_raw()))
    assert got.allclose(a @ b, atol=1e-9)


@given(poses, poses, fractions)
def test_raw_interpolate_is_pose_interpolation(a, b, s):
    # half a turn apart, the two arcs are equally short and either midpoint is right
    assume(abs(float(np.dot(a.quat_xyzw, b.quat_xyzw))) > 1e-6)
    got = Pose.from_raw(raw_interpolate(a.as_raw(), b.as_raw(), s))
    assert got.allclose(interpolate(0.0, a, 1.0, b, s), atol=1e-7)


@given(poses)
def test_raw_round_trip(p):
    raw = p.as_raw()
    assert len(raw) == 7 and all(type(v) is float for v in raw)
    assert Pose.from_raw(raw).allclose(p, atol=1e-12)


# ----------------------------------------------------------------------------- single poses = scipy, bit for bit
# A single Pose computes with the scalar code at the end of phonepose.geometry instead of scipy's
# Rotation (for speed); these tests hold it to scipy's exact bits, since playback outputs must not
# change. Quaternions span many scales, rotation vectors include scipy's small-angle branch.
any_quat = st.tuples(*[st.floats(-1e3, 1e3, allow_nan=False, allow_subnormal=False)] * 4).filter(
    lambda q: np.linalg.norm(q) > 1e-6).map(np.array)
rotvec = st.one_of(st.tuples(*[st.floats(-4, 4, allow_nan=False)] * 3),
                   st.tuples(*[st.floats(-1e-3, 1e-3, allow_nan=False)] * 3)).map(np.array)
wide_vec3 = st.tuples(*[st.floats(-1e4, 1e4, allow_nan=False)] * 3).map(np.array)


def _same(a, b) -> bool:
    return np.asarray(a, dtype=float).tobytes() == np.asarray(b, dtype=float).tobytes()


def _scipy(p: Pose) -> tuple[Rotation, np.ndarray]:
    """p as scipy holds it (its quaternion as is: normalising it again could move the last bit)."""
    return Rotation(p.quat_xyzw, normalize=False), p.translation


@given(wide_vec3, any_quat)
def test_from_xyzw_is_scipys(t, q):
    assert _same(Pose.from_xyzw(t, q).quat_xyzw, Rotation.from_quat(q).as_quat())


@given(wide_vec3, rotvec)
def test_from_rotvec_and_back_are_scipys(t, rv):
    p = Pose.from_rotvec(t, rv)
    assert _same(p.quat_xyzw, Rotation.from_rotvec(rv).as_quat())
    assert _same(p.as_cv()[0].ravel(), Rotation.from_rotvec(rv).as_rotvec())
    flipped = Pose._of(tuple((-p.quat_xyzw).tolist()), t)    # as_rotvec takes the canonical (w >= 0) quaternion
    assert _same(flipped.as_cv()[0].ravel(), Rotation(-p.quat_xyzw, normalize=False).as_rotvec())


@given(st.builds(Pose.from_xyzw, wide_vec3, any_quat), st.builds(Pose.from_xyzw, wide_vec3, any_quat))
def test_algebra_is_scipys(a, b):
    ra, ta = _scipy(a)
    rb, tb = _scipy(b)
    ab = a @ b
    assert _same(ab.quat_xyzw, (ra * rb).as_quat()) and _same(ab.translation, ra.apply(tb) + ta)
    inv = a.inv()
    assert _same(inv.quat_xyzw, ra.inv().as_quat()) and _same(inv.translation, -ra.inv().apply(ta))
    assert _same(a.apply(tb), ra.apply(tb) + ta)
    assert _same(a.angle_to(b), (ra.inv() * rb).magnitude())


@given(st.builds(Pose.from_xyzw, wide_vec3, any_quat), st.builds(Pose.from_rotvec, vec3, rotvec),
       st.integers(0, 10**9), st.integers(1, 10**9), st.integers(0, 10**9))
def test_interpolate_is_scipys(a, step, t0, dt, dt_query):
    b = a @ step            # includes tiny relative rotations (scipy's small-angle branches)
    t1, t = t0 + dt, t0 + dt_query % (dt + 1)
    got = interpolate(t0, a, t1, b, t)
    ra, rb = _scipy(a)[0], _scipy(b)[0]
    s = (t - t0) / (t1 - t0)
    want = ra * Rotation.from_rotvec(s * (ra.inv() * rb).as_rotvec())
    assert _same(got.quat_xyzw, want.as_quat())
    assert _same(got.translation, (1.0 - s) * a.translation + s * b.translation)


def test_single_pose_builds_its_scipy_rotation_on_demand():
    p = Pose.from_raw((0.0, 0.0, 0.6, 0.8, 1.0, 2.0, 3.0))
    assert p.single and isinstance(p.rotation, Rotation)
    assert _same(p.rotation.as_quat(), [0.0, 0.0, 0.6, 0.8])
    m = p.translation[None, :].T[:, 0]           # a non-contiguous vector takes the same path as in scipy
    assert _same(p.apply(m), p.rotation.apply(m) + p.translation)
    stack = Pose(Rotation.from_quat([[0, 0, 0.6, 0.8], [0.6, 0, 0, 0.8]]), np.ones((2, 3)))
    assert not stack.single and len(stack @ p) == 2
# ---------------------------------------------------------------- single rotations in closed form (T8's per-tick path)
# rotation vectors up to pi, and tiny ones on both sides of scipy's 1e-3 rad Taylor switch
rotvecs = st.one_of(
    st.tuples(*[st.floats(-1.8, 1.8, allow_nan=False)] * 3).filter(lambda v: np.linalg.norm(v) < np.pi - 1e-6),
    st.tuples(*[st.floats(-1e-3, 1e-3, allow_nan=False)] * 3)).map(np.array)


@given(rotvecs)
def test_quat_from_rotvec_is_scipys(v):
    np.testing.assert_allclose(quat_from_rotvec(v), Rotation.from_rotvec(v).as_quat(), rtol=0, atol=1e-15)


@given(unit_quat.filter(lambda q: abs(q[3]) > 1e-6))   # w = 0 (a half turn): +-pi are both right
def test_quat_as_rotvec_is_scipys_both_signs(q):
    want = Rotation.from_quat(q).as_rotvec()
    np.testing.assert_allclose(quat_as_rotvec(tuple(q)), want, rtol=0, atol=1e-14)
    np.testing.assert_allclose(quat_as_rotvec(tuple(-np.asarray(q))), want, rtol=0, atol=1e-14)   # w < 0: same rotation


@given(rotvecs)
def test_rotvec_round_trip_and_small_angles(v):
    np.testing.assert_allclose(quat_as_rotvec(quat_from_rotvec(v)), v, rtol=0, atol=1e-13)


@given(st.lists(quat, min_size=1, max_size=8), st.lists(st.floats(-100, 100), min_size=24, max_size=24),
       st.sampled_from([1e-3, 1.0, 3.0, 1e3]))
def test_quat_apply_rows_is_scipys_apply(qs, vs, scale):
    """T8 turns 1-60 accelerometer samples a tick with it: scipy's Rotation.apply row by row, to rounding (the
    same products summed in another order), for quaternions of any norm (normalised as scipy does)."""
    q = np.array(qs) * scale
    v = np.array(vs[:3 * len(qs)] + [0.0] * max(0, 3 * len(qs) - len(vs))).reshape(-1, 3)
    want = Rotation.from_quat(q).apply(v)
    np.testing.assert_allclose(quat_apply_rows(q, v), want, rtol=0, atol=1e-13)
    # each row alone, as the one-quaternion matrix turns it
    one = np.array(quat_matrix(quat_normalised(q[0]))) @ v[0]
    np.testing.assert_allclose(quat_apply_rows(q[:1], v[:1])[0], one, rtol=0, atol=1e-13)


@given(unit_quat, unit_quat)
def test_quat_matrix_and_inverse_are_scipys(a, b):
    np.testing.assert_allclose(np.array(quat_matrix(tuple(a))), Rotation.from_quat(a).as_matrix(), rtol=0, atol=1e-15)
    composed = quat_mul(tuple(a), quat_inv(tuple(b)))
    assert _angle(composed, (Rotation.from_quat(a) * Rotation.from_quat(b).inv()).as_quat()) < 1e-9
    assert quat_normalised((2 * a[0], 2 * a[1], 2 * a[2], 2 * a[3])) == pytest.approx(tuple(a), abs=1e-15)



@given(st.lists(any_quat, min_size=1, max_size=20), st.lists(any_quat, min_size=1, max_size=20), st.booleans())
def test_stack_products_are_scipys(qa, qb, single_first):
    a = Rotation.from_quat(qa[0]) if single_first else Rotation.from_quat(np.array(qa))
    b = Rotation.from_quat(np.array(qb))
    if not single_first and len(a) != len(b) and len(a) > 1:
        a = a[:1]
    got = rotation_product(a, b)
    assert _same(got.as_quat(), (a * b).as_quat()) and got.single == (a * b).single
    assert _same(rotation_inverse(b).as_quat(), b.inv().as_quat())
    stack = Pose(b, np.arange(3.0 * len(b)).reshape(-1, 3))
    assert _same(stack[::2].quat_xyzw, b[::2].as_quat()) and _same(stack[-1].quat_xyzw, b[-1].as_quat())
