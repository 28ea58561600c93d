"""T8 (ours): the fused tracker (docs/pipeline.md#t8-the-fused-tracker-ours)."""

from phonepose.pipeline.t8.config import FusionConfig
from phonepose.pipeline.t8.filter import CorrectionFilter
from phonepose.pipeline.t8.tracker import FusedTracker

__all__ = ["CorrectionFilter", "FusedTracker", "FusionConfig"]
