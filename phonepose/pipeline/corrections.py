"""Correction methods CM1-CM3 of the paper (section 3.2, equations 1-6), in two maths.

A correction is an offset computed once from a *reference* pose (what the controller truly
is, as far as the system knows) and the *VIO* pose read at the same moment; it is then applied
to every later VIO pose.

``CorrectionMath.PAPER`` follows equations (1)-(6) literally: position and orientation are
corrected independently,

    x_CM = x_ref - x_vio            q_CM = q_ref * q_vio^-1          (eqs. 1-4)
    x_final = x_CM + x_now          q_final = q_CM * q_now           (eqs. 5-6)

``CorrectionMath.SE3`` treats the offset as a rigid transform of the VIO frame,

    T_CM = T_ref · T_vio^-1         T_final = T_CM · T_now,

which differs only in that the rotational part of the offset also rotates the position
(``x_final = R_CM x_now + t_CM``). A VIO frame that is rotated against the truth (a heading error
of the anchor, say) is removed exactly by SE3 everywhere, while PAPER is exact only at the
pose where the offset was taken and leaves a residual growing with the distance from it.

Where the reference comes from:

- CM2 / CM3: ref = the marker pose, vio = the anchor-mapped VIO pose at the same tick (eqs. 3-4).
- CM1 (**stated deviation from the paper's text**): the event carries ``pose_fix_vio`` (the VIO
  pose frozen as the green CG object) and ``pose_align_vio`` (VIO when the user had physically
  put the phone onto that object). At the align moment the phone truly *is* at ``pose_fix``, and
  VIO reads ``pose_align``, so the offset that maps VIO to truth uses ref = fix, vio = align:
  ``x_CM1 = x_fix - x_align``. The paper's eq. (1) literally reads ``x_align - x_fix``; combined
  with eq. (5) that would add the VIO error a second time instead of removing it. The literal
  reading is available as ``CM1Reading.PAPER_LITERAL`` for comparison (docs/pipeline.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.errors import ConfigError
from phonepose.geometry import Pose, compose_rotations


def _parse_choice(cls, value, what: str):
    """``value`` as a member of the str Enum ``cls`` (case-insensitive); ConfigError naming the allowed values."""
    if isinstance(value, cls):
        return value
    try:
        return cls(str(value).lower())
    except ValueError:
        allowed = ", ".join(m.value for m in cls)
        raise ConfigError(f"unknown {what} {value!r}; allowed: {allowed}") from None


class CorrectionMath(StrEnum):
    PAPER = "paper"   # equations (1)-(6): position difference + left-multiplied quaternion
    SE3 = "se3"       # rigid offset: T_CM = T_ref · T_vio^-1

    @classmethod
    def parse(cls, value: CorrectionMath | str) -> CorrectionMath:
        return _parse_choice(cls, value, "correction math")


class CM1Reading(StrEnum):
    CONSISTENT = "consistent"        # ref = pose_fix_vio, vio = pose_align_vio (default; see module doc)
    PAPER_LITERAL = "paper-literal"  # eq. (1)-(2) as printed: ref = pose_align_vio, vio = pose_fix_vio

    @classmethod
    def parse(cls, value: CM1Reading | str) -> CM1Reading:
        return _parse_choice(cls, value, "CM1 reading")


@dataclass(frozen=True)
class Correction:
    """An offset (x_CM, q_CM) and the math that applies it.

    Both maths share the rotation ``q_CM = q_ref * q_vio^-1``; they differ in the translation
    (``x_ref - x_vio`` vs ``x_ref - R_CM x_vio``) and in whether applying it rotates the position.
    The offset is kept as a single Pose, so that the per-tick products run geometry's scalar code
    (the same numbers as scipy's Rotation, without its per-call cost).
    """

    math: CorrectionMath
    offset: Pose              # rotation q_CM, translation x_CM (paper) or t_CM (se3)

    @property
    def rotation(self) -> Rotation:
        """q_CM."""
        return self.offset.rotation

    @property
    def translation(self) -> np.ndarray:
        """x_CM (paper) or t_CM (se3)."""
        return self.offset.translation

    @classmethod
    def between(cls, ref: Pose, vio: Pose, math: CorrectionMath | str = CorrectionMath.PAPER) -> Correction:
        """The offset that maps ``vio`` onto ``ref`` (eqs. 1-4, or T_ref · T_vio^-1)."""
        math = CorrectionMath.parse(math)
        rotation = compose_rotations(ref, vio, None, invert_second=True)
        if math is CorrectionMath.PAPER:
            translation = ref.translation - vio.translation
        else:
            translation = ref.translation - rotation.rotate(vio.translation)
        return cls(math, rotation.with_translation(np.asarray(translation, dtype=float)))

    def apply(self, vio_now: Pose) -> Pose:
        """The corrected pose (eqs. 5-6, or T_CM · T_now)."""
        if self.math is CorrectionMath.PAPER:
            return compose_rotations(self.offset, vio_now, self.offset.translation + vio_now.translation)
        return self.offset @ vio_now

    def as_pose(self) -> Pose:
        """The offset as a Pose (for logging); for SE3 this is T_CM itself."""
        return self.offset


def cm1_correction(pose_fix_vio: Pose, pose_align_vio: Pose, math: CorrectionMath | str = CorrectionMath.PAPER,
                   reading: CM1Reading | str = CM1Reading.CONSISTENT) -> Correction:
    """CM1 from the alignment event's two VIO poses (see the module docstring for the reading)."""
    if CM1Reading.parse(reading) is CM1Reading.CONSISTENT:
        return Correction.between(ref=pose_fix_vio, vio=pose_align_vio, math=math)
    return Correction.between(ref=pose_align_vio, vio=pose_fix_vio, math=math)


def marker_correction(marker_pose: Pose, vio_pose: Pose, math: CorrectionMath | str = CorrectionMath.PAPER) -> Correction:
    """CM2 / CM3 (eqs. 3-4): marker pose and anchor-mapped VIO pose at the same tick."""
    return Correction.between(ref=marker_pose, vio=vio_pose, math=math)
