"""Colours: one per tracker, the same on every entity (pose, trajectory, label, error series) and
in every figure, chosen by name so that T8 has the same colour whichever trackers are played.

The viewers follow the system theme, so every colour must read on white and on near-black:
the ten colours are matplotlib's "tab10", made for white paper (its lightest, olive and cyan, still
reach 2:1 against white) and keeping at least 3:1 against Rerun's near-black dark background
(the darkest, brown: 3.2:1). The ground truth is mid grey, the one colour as far from white as
from black (3.9:1 and 4.8:1), and is drawn thicker than any estimate; the task (experiment 2's
path, experiment 1's targets) is teal and thin. The paper's trackers T1-T7 and the project's own
(T7L, T8) are told apart by line width in the plots (ours thicker), not by colour family, so
that every tracker keeps a colour of its own.
"""

from __future__ import annotations

import zlib

RGB = tuple[int, int, int]

GT_COLOR: RGB = (128, 128, 128)
TASK_COLOR: RGB = (0, 128, 128)
MARKER_COLOR: RGB = (44, 160, 44)          # the recognised marker's outline in the camera image

TRACKER_COLORS: dict[str, RGB] = {
    "T1": (31, 119, 180),     # tab:blue
    "T2": (255, 127, 14),     # tab:orange
    "T3": (23, 190, 207),     # tab:cyan
    "T4": (148, 103, 189),    # tab:purple
    "T5": (188, 189, 34),     # tab:olive
    "T6": (227, 119, 194),    # tab:pink
    "T7": (140, 86, 75),      # tab:brown
    "T7L": (214, 39, 40),     # tab:red
    "T8": (44, 160, 44),      # tab:green
}
COLOR_NAMES: dict[RGB, str] = {(31, 119, 180): "blue", (255, 127, 14): "orange", (23, 190, 207): "cyan",
                               (148, 103, 189): "purple", (188, 189, 34): "olive", (227, 119, 194): "pink",
                               (140, 86, 75): "brown", (214, 39, 40): "red", (44, 160, 44): "green",
                               GT_COLOR: "grey"}
# trackers registered by users (phonepose.pipeline.trackers.register): a stable pick by name
EXTRA_COLORS: list[RGB] = [(0, 95, 115), (174, 32, 18), (202, 103, 2), (106, 76, 147), (25, 130, 196),
                           (138, 201, 38), (255, 89, 94), (255, 202, 58)]

PAPER = ("T1", "T2", "T3", "T4", "T5", "T6", "T7")
LINE_WIDTH_PAPER = 1.5        # error plot lines (ui points)
LINE_WIDTH_OURS = 2.5


def tracker_color(name: str) -> RGB:
    """The colour of tracker ``name`` (the ground truth is ``"GT"``)."""
    if name == "GT":
        return GT_COLOR
    color = TRACKER_COLORS.get(name)
    if color is None:
        color = EXTRA_COLORS[zlib.crc32(name.encode()) % len(EXTRA_COLORS)]
    return color


def color_name(name: str) -> str:
    """The colour of tracker ``name`` in words (the legend): ``blue``, or ``#rrggbb`` for a user's tracker."""
    rgb = tracker_color(name)
    return COLOR_NAMES.get(rgb, hex_color(rgb))


def line_width(name: str) -> float:
    return LINE_WIDTH_PAPER if name in PAPER else LINE_WIDTH_OURS


def hex_color(rgb: RGB) -> str:
    """``#rrggbb`` (matplotlib)."""
    return "#{:02x}{:02x}{:02x}".format(*rgb)
