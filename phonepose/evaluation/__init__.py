"""Trajectory evaluation: rpg_trajectory_evaluation's ATE/RE and evo's APE/RPE, vectorised.

See docs/evaluation.md. Public API:

- :class:`Trajectory`, :func:`load_tum`, :func:`load_euroc`, :func:`load_kitti`,
  :func:`load_trajectory`, :func:`write_tum`
- :func:`associate_rpg`, :func:`associate_evo`
- :func:`align` / :class:`Alignment` (posyaw, se3, sim3, none; ``num_frames``)
- :func:`evaluate_rpg` (ATE + RE), :func:`evaluate_ape`, :func:`evaluate_rpe` (evo-compatible)
- :func:`paper_metrics` (the paper's p_ATE, r_ATE, p_RE inside/outside/total, for playback)
"""

from phonepose.evaluation.alignment import Alignment, align, umeyama
from phonepose.evaluation.association import associate_evo, associate_rpg
from phonepose.evaluation.paper import paper_metrics
from phonepose.evaluation.rpg import evaluate_rpg
from phonepose.evaluation.stats import statistics
from phonepose.evaluation.trajectory import (
    Trajectory,
    load_euroc,
    load_kitti,
    load_trajectory,
    load_tum,
    write_tum,
)

__all__ = [
    "Alignment", "align", "umeyama", "associate_evo", "associate_rpg", "paper_metrics", "evaluate_rpg",
    "statistics", "Trajectory", "load_euroc", "load_kitti", "load_trajectory", "load_tum", "write_tum",
]
