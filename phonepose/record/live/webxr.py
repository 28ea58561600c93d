"""WebXR's axis conventions and the one place a headset's poses become the project's (``gt_world``).

WebXR (the Device API spec, "Spatial tracking"): every reference space is right-handed, metres,
``+y`` up, ``-z`` forward, ``+x`` right; a pose is ``XRRigidTransform``: ``position`` (x, y, z) and
``orientation`` a unit quaternion (x, y, z, w), the transform *from* the pose's space (the viewer,
a controller's grip space) *to* the reference space: ``T_ref_body``.

The headset page (static/headset.js) sends those numbers untouched, in its one stationary space
(``local-floor``, else ``local``). Here that space becomes :data:`Frame.GT_WORLD`, z up like
display_vio and the simulator's mocap world, so viewers show the trajectories upright:

    gt_world x = -xr z (forward at session start),  y = -xr x (left),  z = xr y (up)

i.e. ``T_gtworld_body = R_GTWORLD_XR · T_xr_body``. The bodies keep WebXR's own axes (a grip space:
``-z`` along the controller's pointing ray, ``+y`` out of the back of the hand, ``+x`` towards the
palm's side; the viewer: ``-z`` the view direction, ``+y`` up): calibrate-gt estimates the grip's
pose on the phone's body whatever its axes (T_controller_gt), so no body rotation is guessed here.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.geometry import Pose

# columns: the xr axes expressed in gt_world (xr x -> -y, xr y -> +z, xr z -> -x)
R_GTWORLD_XR = np.array([[0.0, 0.0, -1.0],
                         [-1.0, 0.0, 0.0],
                         [0.0, 1.0, 0.0]])
T_GTWORLD_XR = Pose(Rotation.from_matrix(R_GTWORLD_XR), np.zeros(3))


def xr_to_gt_world(p: Sequence[float], q_xyzw: Sequence[float]) -> Pose:
    """A WebXR pose (position, orientation x,y,z,w in the reference space) as ``T_gtworld_body``."""
    return T_GTWORLD_XR @ Pose.from_xyzw(np.asarray(p, dtype=float), np.asarray(q_xyzw, dtype=float))


def gt_world_to_xr(pose: Pose) -> tuple[list[float], list[float]]:
    """The inverse: ``T_gtworld_body`` as WebXR's (position, orientation x,y,z,w), e.g. to drive an emulator."""
    xr = T_GTWORLD_XR.inv() @ pose
    return [float(v) for v in np.ravel(xr.translation)], [float(v) for v in np.ravel(xr.quat_xyzw)]
