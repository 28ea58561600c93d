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
