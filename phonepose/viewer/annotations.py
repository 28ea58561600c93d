"""Marker detections as ``foxglove.ImageAnnotations``: Foxglove's Image panel overlays them on the
camera image (``trackers.mcap`` opened beside the session), matched by timestamp, which is the
image's capture time. Rerun 0.41's importer does not map ImageAnnotations (the playback's own
``.rrd`` draws the detection instead); ``/pipeline/markers`` keeps the full detection."""

from __future__ import annotations

import numpy as np
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation

from phonepose.pipeline.types import Observation
from phonepose.viewer.style import MARKER_COLOR

_GREEN = Color(r=MARKER_COLOR[0] / 255, g=MARKER_COLOR[1] / 255, b=MARKER_COLOR[2] / 255, a=1.0)
_WHITE = Color(r=1.0, g=1.0, b=1.0, a=1.0)
_SHADE = Color(r=0.0, g=0.0, b=0.0, a=0.6)


def marker_annotations(obs: Observation) -> ImageAnnotations:
    """The recognised marker's outline (a closed loop through its four corners, pixels) and a
    label with its id, reprojection error and ambiguity ratio; no annotation when nothing was
    recognised, so the overlay clears on that frame."""
    msg = ImageAnnotations()
    stamp = obs.tick.frame_t_ns
    msg.timestamp.FromNanoseconds(int(stamp))
    m = obs.marker
    if m is None:
        return msg
    corners = np.asarray(m.corners_px, dtype=float).reshape(4, 2)
    loop = msg.points.add(type=PointsAnnotation.LINE_LOOP, outline_color=_GREEN, thickness=2.0)
    loop.timestamp.FromNanoseconds(int(stamp))
    for x, y in corners:
        loop.points.add(x=float(x), y=float(y))
    ratio = f", ambiguity {m.ambiguity_ratio:.1f}" if np.isfinite(m.ambiguity_ratio) else ""
    text = msg.texts.add(text=f"id {m.id}: {m.reprojection_error_px:.2f} px{ratio}", font_size=14.0,
                         text_color=_WHITE, background_color=_SHADE)
    text.timestamp.FromNanoseconds(int(stamp))
    text.position.x, text.position.y = float(corners[:, 0].min()), float(corners[:, 1].min()) - 18.0
    return msg
