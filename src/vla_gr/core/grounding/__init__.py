"""Language grounding for S2: the goal head (pixels of the instructed object) and its losses."""

from vla_gr.core.grounding.goal_head import GoalHead, GoalHeadConfig
from vla_gr.core.grounding.losses import (
    GroundingConfig,
    confusion_metrics,
    goal_head_loss,
    mask_confusion,
    visible_targets,
)

__all__ = [
    "GoalHead",
    "GoalHeadConfig",
    "GroundingConfig",
    "confusion_metrics",
    "goal_head_loss",
    "mask_confusion",
    "visible_targets",
]
