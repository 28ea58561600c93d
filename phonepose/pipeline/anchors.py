"""Controller VIO mapped into the display's VIO frame through the shared anchor (paper 3.1.1).

Each device resolves the same physical anchor in its own VIO world: ``T_dvio_anchor`` on the
display, ``T_cvio_anchor`` on the controller. The controller pose in display_vio is then

    T_dvio_controller = T_dvio_anchor · T_cvio_anchor^-1 · T_cvio_controller.

Any error in how either device resolved the anchor becomes a rigid error of the whole mapped
trajectory; that is what the corrections CM1-CM3 are for.
"""

from __future__ import annotations

from phonepose.geometry import Pose


def controller_in_display_vio(T_dvio_anchor: Pose | None, T_cvio_anchor: Pose | None,
                              T_cvio_controller: Pose | None) -> Pose | None:
    """The anchor-mapped controller VIO pose, or None while any of the three is unknown."""
    if T_dvio_anchor is None or T_cvio_anchor is None or T_cvio_controller is None:
        return None
    return T_dvio_anchor @ T_cvio_anchor.inv() @ T_cvio_controller


class AnchorMap:
    """:func:`controller_in_display_vio` for a stream of ticks, with ``T_dvio_anchor · T_cvio_anchor^-1``
    composed once per pair of anchors (the anchors change rarely; the controller pose every tick).

    The product is the same left-to-right composition as the function's, so the results are
    bit-identical to it.
    """

    def __init__(self) -> None:
        self._anchors: tuple[Pose, Pose] | None = None
        self._T_dvio_cvio: Pose | None = None

    def __call__(self, T_dvio_anchor: Pose | None, T_cvio_anchor: Pose | None,
                 T_cvio_controller: Pose | None) -> Pose | None:
        if T_dvio_anchor is None or T_cvio_anchor is None or T_cvio_controller is None:
            return None
        cached = self._anchors
        if cached is None or cached[0] is not T_dvio_anchor or cached[1] is not T_cvio_anchor:
            self._anchors = (T_dvio_anchor, T_cvio_anchor)
            self._T_dvio_cvio = T_dvio_anchor @ T_cvio_anchor.inv()
        T_dvio_cvio = self._T_dvio_cvio
        assert T_dvio_cvio is not None   # composed with the anchors above
        return T_dvio_cvio @ T_cvio_controller
