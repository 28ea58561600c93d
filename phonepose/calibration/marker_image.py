"""The controller's ArUco marker as an image: what the phone shows on its screen (``record live``
serves it to the phone page) and what ``phonepose marker`` writes.

Defaults are the simulator's marker (``[marker]`` in ``phonepose/record/sim/default.toml``:
``DICT_4X4_50`` id 7). ``side_px`` is the side of the marker itself, black border included: the
square whose physical side is the session's marker size. The white quiet zone is added around it,
so the image is ``side_px + 2 * quiet_zone_px`` pixels square.
"""

from __future__ import annotations

import cv2
import numpy as np

from phonepose.errors import ConfigError


def _module_count(dictionary: cv2.aruco.Dictionary, border_bits: int) -> int:
    return int(dictionary.markerSize) + 2 * border_bits


def marker_image(dictionary: str = "DICT_4X4_50", marker_id: int = 7, side_px: int = 400, border_bits: int = 1,
                 quiet_zone_px: int | None = None) -> np.ndarray:
    """The marker (uint8 grayscale, 0 black / 255 white) with a white quiet zone around it.

    ``quiet_zone_px`` defaults to one module (one bit cell, ``side_px / (bits + 2 * border_bits)``),
    the least white the ArUco detector needs around the black border to find the square.
    A bad dictionary, id or size is a ConfigError (one line, exit 5).
    """
    from phonepose.pipeline.markers import aruco_dictionary  # the one name -> dictionary map

    d = aruco_dictionary(dictionary)
    n_ids = int(d.bytesList.shape[0])
    if not 0 <= int(marker_id) < n_ids:
        raise ConfigError(f"marker id {marker_id}: {dictionary} has ids 0..{n_ids - 1}")
    if border_bits < 1:
        raise ConfigError(f"marker border_bits {border_bits}: expected >= 1")
    modules = _module_count(d, border_bits)
    if side_px < modules:
        raise ConfigError(f"marker side {side_px} px: {dictionary} with border {border_bits} needs at least "
                          f"{modules} px (one per bit)")
    if quiet_zone_px is None:
        quiet_zone_px = int(np.ceil(side_px / modules))
    if quiet_zone_px < 0:
        raise ConfigError(f"marker quiet zone {quiet_zone_px} px: expected >= 0")
    marker = cv2.aruco.generateImageMarker(d, int(marker_id), int(side_px), borderBits=int(border_bits))
    return cv2.copyMakeBorder(marker, quiet_zone_px, quiet_zone_px, quiet_zone_px, quiet_zone_px,
                              cv2.BORDER_CONSTANT, value=255)


def marker_png(dictionary: str = "DICT_4X4_50", marker_id: int = 7, side_px: int = 400, border_bits: int = 1,
               quiet_zone_px: int | None = None) -> bytes:
    """:func:`marker_image` encoded as PNG."""
    ok, buf = cv2.imencode(".png", marker_image(dictionary, marker_id, side_px, border_bits, quiet_zone_px))
    if not ok:   # cannot happen for a uint8 image; kept so a failure is never an empty response
        raise ConfigError("could not encode the marker as PNG")
    return buf.tobytes()
