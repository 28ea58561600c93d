"""CM1-CM3 corrections: equations (1)-(6) of the paper, and the rigid (se3) variant."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from phonepose.errors import ConfigError
from phonepose.geometry import Pose
from phonepose.pipeline.anchors import controller_in_display_vio
from phonepose.pipeline.corrections import CM1Reading, Correction, CorrectionMath, cm1_correction, marker_correction

REF = Pose.from_rotvec([0.31, -0.12, 0.45], [0.2, 0.5, -0.9])
VIO = Pose.from_rotvec([0.36, -0.05, 0.40], [0.23, 0.47, -0.86])
NOW = Pose.from_rotvec([-0.2, 0.9, 0.1], [0.6, 0.1, -0.4])


def test_paper_math_is_equations_3_to_6():
    corr = marker_correction(REF, VIO, "paper")
    # eq. (3): x_CM = x_marker - x_VIO ; eq. (4): q_CM = q_marker * q_VIO^-1
    np.testing.assert_allclose(corr.translation, REF.translation - VIO.translation, atol=1e-12)
    assert (corr.rotation * (REF.rotation * VIO.rotation.inv()).inv()).magnitude() < 1e-12
    final = corr.apply(NOW)
    # eq. (5): x_final = x_CM + x_current ; eq. (6): q_final = q_CM * q_current
    np.testing.assert_allclose(final.translation, REF.translation - VIO.translation + NOW.translation, atol=1e-9)
    expected_q = REF.rotation * VIO.rotation.inv() * NOW.rotation
    assert (final.rotation.inv() * expected_q).magnitude() < 1e-9
    # hand-computed numbers, so a change in conventions (e.g. right-multiplication) fails too
    x = Correction.between(Pose.from_xyzw([1, 2, 3], [0, 0, 0, 1]), Pose.from_xyzw([0.5, 2.5, 1], [0, 0, 0, 1]))
    np.testing.assert_allclose(x.apply(Pose.from_xyzw([10, 0, 0], [0, 0, 0, 1])).translation, [10.5, -0.5, 2.0])


def test_quaternion_is_left_multiplied():
    # q_CM = Rz(90) (ref = Rz(90), vio = identity); now = Rx(90): q_final = Rz(90) * Rx(90) != Rx(90) * Rz(90)
    corr = Correction.between(Pose(Rotation.from_euler("z", 90, degrees=True), np.zeros(3)), Pose.identity(), "paper")
    final = corr.apply(Pose(Rotation.from_euler("x", 90, degrees=True), np.zeros(3)))
    np.testing.assert_allclose(final.rotation.as_matrix(), [[0, 0, 1], [1, 0, 0], [0, 1, 0]], atol=1e-12)


def test_every_correction_reproduces_the_reference_at_its_own_moment():
    for math in CorrectionMath:
        assert marker_correction(REF, VIO, math).apply(VIO).allclose(REF, atol=1e-9)


def test_se3_math_is_a_rigid_offset():
    corr = marker_correction(REF, VIO, "se3")
    assert corr.as_pose().allclose(REF @ VIO.inv(), atol=1e-12)
    assert corr.apply(NOW).allclose(REF @ VIO.inv() @ NOW, atol=1e-9)


def test_se3_removes_a_rigid_frame_error_where_paper_leaves_a_residual():
    # VIO lives in a frame rotated 10 deg and shifted against the truth (a mis-resolved anchor).
    axis = np.array([0.2, 0.3, 0.93]) / np.linalg.norm([0.2, 0.3, 0.93])
    frame_error = Pose.from_rotvec([0.3, -0.1, 0.05], np.radians(10) * axis)
    truth_then, truth_later = REF, NOW
    vio_then, vio_later = frame_error @ truth_then, frame_error @ truth_later
    se3 = marker_correction(truth_then, vio_then, "se3").apply(vio_later)
    paper = marker_correction(truth_then, vio_then, "paper").apply(vio_later)
    assert se3.allclose(truth_later, atol=1e-9)
    # paper: orientation is exact (the left-multiplied quaternion is the frame rotation) but the
    # position offset is not rotated, so the error grows with the distance travelled
    assert np.degrees(paper.angle_to(truth_later)) < 1e-7
    moved = truth_later.translation - truth_then.translation
    residual = paper.translation - truth_later.translation
    np.testing.assert_allclose(residual, frame_error.rotation.apply(moved) - moved, atol=1e-9)  # (R - I)·moved
    assert np.linalg.norm(residual) > 0.1


def test_pure_translation_error_is_removed_by_both():
    shift = Pose(Rotation.identity(), np.array([0.05, -0.02, 0.1]))
    for math in CorrectionMath:
        out = marker_correction(REF, shift @ REF, math).apply(shift @ NOW)
        assert out.allclose(NOW, atol=1e-9)


def test_cm1_consistent_reading_maps_vio_to_the_fixed_pose():
    fix = Pose.from_rotvec([0.1, 0.2, 0.3], [0.4, 0.0, -0.5])   # shown as the green CG object
    align = Pose.from_rotvec([0.12, 0.17, 0.35], [0.43, 0.02, -0.47])  # VIO once the phone sits on it
    corr = cm1_correction(fix, align, "paper")
    np.testing.assert_allclose(corr.translation, fix.translation - align.translation, atol=1e-12)
    assert corr.apply(align).allclose(fix, atol=1e-9)  # truth at the align moment is the fixed pose
    # eq. (1)-(2) as printed (x_align - x_fix) pushes the estimate the wrong way: twice the error
    literal = cm1_correction(fix, align, "paper", CM1Reading.PAPER_LITERAL)
    np.testing.assert_allclose(literal.translation, align.translation - fix.translation, atol=1e-12)
    out = literal.apply(align)
    np.testing.assert_allclose(out.translation - fix.translation, 2 * (align.translation - fix.translation), atol=1e-12)


def test_parsing_names():
    assert CorrectionMath.parse("SE3") is CorrectionMath.SE3
    assert CM1Reading.parse("paper-literal") is CM1Reading.PAPER_LITERAL
    with pytest.raises(ConfigError, match="paper, se3"):
        CorrectionMath.parse("quaternion")


def test_anchor_mapping():
    T_dvio_anchor = Pose.from_rotvec([0.0, 0.0, 0.7], [1.0, 2.0, 0.0])
    T_cvio_anchor = Pose.from_rotvec([0.0, 0.0, -0.2], [-0.5, 0.3, 0.1])
    T_cvio_controller = Pose.from_rotvec([0.1, 0.2, 0.3], [0.2, 0.3, 0.4])
    out = controller_in_display_vio(T_dvio_anchor, T_cvio_anchor, T_cvio_controller)
    # the controller's pose relative to the anchor is the same in both worlds
    assert (T_dvio_anchor.inv() @ out).allclose(T_cvio_anchor.inv() @ T_cvio_controller, atol=1e-12)
    # the anchor itself maps onto the display's anchor
    assert controller_in_display_vio(T_dvio_anchor, T_cvio_anchor, T_cvio_anchor).allclose(T_dvio_anchor, atol=1e-12)
    assert controller_in_display_vio(None, T_cvio_anchor, T_cvio_controller) is None
