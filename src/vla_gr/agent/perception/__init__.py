"""Language grounding for S2: the goal head (pixels of the instructed object), its losses,
the room-type check of room instructions, the object-category check of every goal, and the
reader of what an instruction names in words the templates do not use, and the lexicon that
says such an instruction again in template words; :mod:`.percept` puts them together as S2's
perception, one typed percept per tick (and the privileged ablations' perceptions)."""

from vla_gr.agent.perception.goal_head import GoalHead, GoalHeadConfig
from vla_gr.agent.perception.instruction_reader import (
    InstructionReader,
    InstructionReaderConfig,
    Reading,
    read_instruction,
)
from vla_gr.agent.perception.lexicon import (
    InstructionLexicon,
    InstructionLexiconConfig,
    LexiconReading,
)
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
    "LearnedPerception",
    "Percept",
    "Perception",
    "TrueCategoryGate",
    "TrueMaskPerception",
    "GoalHead",
    "GoalHeadConfig",
    "GroundingConfig",
    "InstructionLexicon",
    "InstructionLexiconConfig",
    "InstructionReader",
    "InstructionReaderConfig",
    "LexiconReading",
    "ObjectCategoryConfig",
    "ObjectCategorySegmenter",
    "ObjectEvidence",
    "Reading",
    "RoomTypeClassifier",
    "RoomTypeConfig",
    "category_match",
    "confusion_metrics",
    "goal_head_loss",
    "instructed_anchor",
    "instructed_category",
    "instructed_room",
    "mask_confusion",
    "read_instruction",
    "visible_targets",
]
