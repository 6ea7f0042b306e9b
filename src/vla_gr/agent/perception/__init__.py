"""Language grounding for S2: the goal head (pixels of the instructed object), its losses,
the room-type check of room instructions and the object-category check of every goal;
:mod:`.percept` puts them together with the instruction reader (:mod:`vla_gr.agent.reading`)
as S2's perception, one typed percept per tick (and the privileged ablations' perceptions);
:mod:`.engine` picks what runs the networks (PyTorch or their ONNX Runtime export)."""

from vla_gr.agent.perception.engine import ENGINES, PerceptionConfig
from vla_gr.agent.perception.goal_head import GoalHead, GoalHeadConfig
from vla_gr.agent.perception.losses import (
    GroundingConfig,
    confusion_metrics,
    goal_head_loss,
    mask_confusion,
    visible_targets,
)
from vla_gr.agent.perception.object_category import (
    ObjectCategoryConfig,
    ObjectCategorySegmenter,
    ObjectEvidence,
    category_match,
    instructed_anchor,
    instructed_category,
)
from vla_gr.agent.perception.percept import (
    LearnedPerception,
    Percept,
    Perception,
    TrueCategoryGate,
    TrueMaskPerception,
)
from vla_gr.agent.perception.room_type import RoomTypeClassifier, RoomTypeConfig, instructed_room

__all__ = [
    "ENGINES",
    "LearnedPerception",
    "Percept",
    "Perception",
    "PerceptionConfig",
    "TrueCategoryGate",
    "TrueMaskPerception",
    "GoalHead",
    "GoalHeadConfig",
    "GroundingConfig",
    "ObjectCategoryConfig",
    "ObjectCategorySegmenter",
    "ObjectEvidence",
    "RoomTypeClassifier",
    "RoomTypeConfig",
    "category_match",
    "confusion_metrics",
    "goal_head_loss",
    "instructed_anchor",
    "instructed_category",
    "instructed_room",
    "mask_confusion",
    "visible_targets",
]
