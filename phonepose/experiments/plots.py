"""Fig. 11-style plots: top and side views of ground truth and each tracker (matplotlib, PNG)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, never a window
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from phonepose.geometry import Pose  # noqa: E402
from phonepose.viewer.style import TRACKER_COLORS, hex_color  # noqa: E402

# the trackers' colours of the Rerun view (phonepose/viewer/style.py), so a tracker looks the same here
COLORS = {"GT": "black", **{name: hex_color(rgb) for name, rgb in TRACKER_COLORS.items()}}


def to_display_view(T_dvio_camera: Pose, poses: Pose) -> np.ndarray:
    """Positions in the paper's display axes: x right, y up, z forward (from the camera's optical frame)."""
    p = T_dvio_camera.inv().apply(poses.translation)  # x right, y down, z forward
    return np.column_stack([p[:, 0], -p[:, 1], p[:, 2]])


def plot_fig11(path: str | Path, title: str, T_dvio_camera: Pose, gt: Pose, estimates: dict[str, Pose],
               gt_inside: np.ndarray | None = None) -> Path:
    """Top view (x-y, seen along z) and side view (z-y, seen along x) in cm, like the paper's Fig. 11."""
    path = Path(path)
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.5))
    series = {"GT": gt, **estimates}
    for name, poses in series.items():
        if len(poses) == 0:
            continue
        xyz = to_display_view(T_dvio_camera, poses) * 100.0
        style = dict(color=COLORS.get(name), lw=2.4 if name == "GT" else (1.8 if name == "T8" else 1.2), label=name,
                     ls="-" if name in ("GT", "T8", "T7", "T6", "T3") else "--")
        axes[0].plot(xyz[:, 0], xyz[:, 1], **style)
        axes[1].plot(xyz[:, 2], xyz[:, 1], **style)
    if gt_inside is not None and len(gt):
        xyz = to_display_view(T_dvio_camera, gt) * 100.0
        out = ~np.asarray(gt_inside, bool)
        axes[0].scatter(xyz[out, 0], xyz[out, 1], s=8, color="black", marker="x", label="GT outside view", zorder=5)
    axes[0].set(xlabel="x (cm, right)", ylabel="y (cm, up)", title="top view (seen along z)")
    axes[1].set(xlabel="z (cm, forward)", ylabel="y (cm, up)", title="side view (seen along x)")
    for ax in axes:
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
    axes[1].legend(loc="best", fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
