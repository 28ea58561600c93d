"""Fig. 11-style plots: front and side views of ground truth and each tracker (matplotlib, PNG)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, never a window
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402

from phonepose.geometry import Pose  # noqa: E402
from phonepose.viewer.style import PAPER, hex_color, tracker_color  # noqa: E402

# the trackers' colours of the Rerun view (phonepose/viewer/style.py), so a tracker looks the same here
GT_COLOR = "black"
OUTSIDE_COLOR = "#ffb000"   # the band under the ground truth where the marker is out of the camera's view
# the two panels: (horizontal axis, vertical axis) of the display axes, and what each shows
VIEWS = (((0, 1), "front view: x-y, seen along z from the camera"),
         ((2, 1), "side view: z-y, seen along x"))
AXIS_LABELS = ("x (cm, right)", "y (cm, up)", "z (cm, forward)")
DASHED = ("T1", "T2", "T4", "T5")   # the paper's rows drawn dashed, so the overlapping ones stay apart


def to_display_view(T_dvio_camera: Pose, poses: Pose) -> np.ndarray:
    """Positions in the paper's display axes: x right, y up, z forward (from the camera's optical frame)."""
    p = T_dvio_camera.inv().apply(poses.translation)  # x right, y down, z forward
    return np.column_stack([p[:, 0], -p[:, 1], p[:, 2]])


def tracker_label(name: str) -> str:
    """The legend's name of a tracker: the paper's T1-T7 as they are, the others marked as ours."""
    return name if name in PAPER else f"{name} (ours)"


def outside_runs(inside: np.ndarray) -> list[tuple[int, int]]:
    """The stretches ``[start, stop)`` of consecutive samples where ``inside`` is False."""
    out = np.concatenate([[False], ~np.asarray(inside, bool), [False]])
    edges = np.flatnonzero(np.diff(out.astype(np.int8)))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True))


def plot_fig11(path: str | Path, title: str, T_dvio_camera: Pose, gt: Pose, estimates: dict[str, Pose],
               gt_inside: np.ndarray | None = None) -> Path:
    """Front view (x-y, seen along z) and side view (z-y, seen along x) in cm, like the paper's Fig. 11; the
    stretches where the marker is out of the camera's view are a band under the ground truth, and where it
    leaves the view a marked point."""
    path = Path(path)
    gt_xyz = to_display_view(T_dvio_camera, gt) * 100.0 if len(gt) else np.zeros((0, 3))
    xyz_of = {name: gt_xyz if name == "GT" else to_display_view(T_dvio_camera, poses) * 100.0
              for name, poses in {"GT": gt, **estimates}.items() if len(poses)}
    # each panel about as wide as its data at one scale (equal aspect), within limits that keep titles readable
    span = np.ptp(np.vstack(list(xyz_of.values())), axis=0) if xyz_of else np.ones(3)
    span = np.maximum(span, 0.2 * span.max() + 1e-9)
    fig, axes = plt.subplots(1, 2, figsize=(12, 6.2),
                             gridspec_kw={"width_ratios": [np.clip(span[h] / span[v], 1.0, 2.5) for (h, v), _ in VIEWS]})
    marks: dict[str, Line2D] = {}   # the legend's entries of the view's marks, after the lines'
    lines: dict[str, Line2D] = {}
    runs = outside_runs(gt_inside) if gt_inside is not None and len(gt) else []
    for ax, ((h, v), view_title) in zip(axes, VIEWS, strict=True):
        for start, stop in runs:   # drawn first: under every line
            seg = gt_xyz[start:stop]
            band = ax.plot(seg[:, h], seg[:, v], color=OUTSIDE_COLOR, lw=13, alpha=0.4, solid_capstyle="round",
                           marker="o" if len(seg) == 1 else None, ms=13, zorder=1)[0]
            marks.setdefault("marker outside the camera's view", band)
        for start, stop in runs:   # a stretch at either end of the path was not seen leaving or coming back
            if start > 0:
                leave = ax.plot(gt_xyz[start, h], gt_xyz[start, v], ls="none", marker="o", ms=9, mfc="white",
                                mec="black", mew=1.6, zorder=6)[0]
                marks.setdefault("marker leaves the view", leave)
            if stop < len(gt_xyz):
                back = ax.plot(gt_xyz[stop, h], gt_xyz[stop, v], ls="none", marker="o", ms=8, mfc="black",
                               mec="black", zorder=6)[0]
                marks.setdefault("marker back in view", back)
        ax.set(xlabel=AXIS_LABELS[h], ylabel=AXIS_LABELS[v], title=view_title)
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
    for name, xyz in xyz_of.items():
        if name == "GT":
            style = dict(color=GT_COLOR, lw=2.6, ls="-", zorder=4)
        elif name in PAPER:
            style = dict(color=hex_color(tracker_color(name)), lw=1.1, ls="--" if name in DASHED else "-", zorder=2)
        else:
            style = dict(color=hex_color(tracker_color(name)), lw=2.0, ls="-", zorder=3)
        for ax, ((h, v), _) in zip(axes, VIEWS, strict=True):
            line = ax.plot(xyz[:, h], xyz[:, v], **style)[0]
        lines["ground truth" if name == "GT" else tracker_label(name)] = line
    order = ("marker outside the camera's view", "marker leaves the view", "marker back in view")
    handles = {**lines, **{k: marks[k] for k in order if k in marks}}   # one legend for both panels, under them
    fig.legend(list(handles.values()), list(handles), loc="lower center", ncol=min(len(handles), 7), fontsize=9,
               frameon=False)
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.09, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
