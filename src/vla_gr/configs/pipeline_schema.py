"""Structured config of the staged training app (``pipeline.*``): a recipe's stages.

``vla-gr train`` with ``pipeline.stages`` non-empty runs the stages in order, each on the
recipe's config with the stage's own ``overrides`` (``key=value``), reading the outputs of
the earlier stages it names in ``inputs``. A stage whose output records the same inputs and
stage config (hashes) is skipped; otherwise it reruns (``pipeline.on_stale=rerun``) or the
run stops naming it (``refuse``). See :mod:`vla_gr.training.pipeline`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from vla_gr.validation import check_choice

#: stage kind -> (what it makes, the inputs it reads in order; "*" = one or more)
STAGE_KINDS: dict[str, tuple[str, tuple[str, ...]]] = {
    "collect": ("an expert episode store (collect.*, expert.*)", ("store?",)),
    "train": ("a trained agent (training.*, model.*)", ("store", "init checkpoint?")),
    "rollout": ("closed-loop episodes of an agent (eval.*)", ("checkpoint",)),
    "dagger": ("a store + the rollouts' states with their true masks", ("rollout", "store")),
    "s1_data": ("S1 inputs + local-teacher labels of rollouts", ("rollout", "checkpoint")),
    "s1": ("the agent with a learned S1 (training.s1.*)", ("checkpoint", "s1_data*")),
    "export": ("a shipping checkpoint with inference settings", ("checkpoint",)),
    "room_type": (
        "the agent + a room-type classifier (training.room_type)",
        ("checkpoint", "store"),
    ),
    "object_category": (
        "the agent + an object-category segmenter (training.object_category)",
        ("checkpoint", "store"),
    ),
    "instruction_reader": ("the agent + an instruction reader", ("checkpoint",)),
    "request_intent": (
        "the agent's reader + a request intent head (training.request_intent)",
        ("checkpoint",),
    ),
    "room_prior": (
        "the agent with room search on, its prior counted from houses (training.room_prior)",
        ("checkpoint",),
    ),
    "source": ("an existing checkpoint or store (path)", ()),
    "graft": ("the agent with another agent's part (part)", ("checkpoint", "donor")),
    "adapt": (
        "the agent with its goal head adapted on a store (training.adapt)",
        ("checkpoint", "store"),
    ),
}
ON_STALE = ("rerun", "refuse")


@dataclass
class StageConfig:
    """One stage of a recipe (``pipeline.stages[i]``)."""

    name: str = ""  # unique in the recipe; its output folder is output_dir/<name>
    kind: str = "train"  # one of STAGE_KINDS
    inputs: list[str] = field(default_factory=list)  # names of earlier stages, in kind order
    overrides: list[str] = field(default_factory=list)  # key=value on the recipe for this stage
    # inference-only model settings: the rollout's agent (eval) or the exported checkpoint
    model_overrides: list[str] = field(default_factory=list)
    path: str | None = None  # kind source: the existing checkpoint or store
    part: str | None = None  # kind graft: the model part taken from the donor, e.g. room_type
    use: str = "best"  # kind train: the run's checkpoint that is the product: best | latest

    def __post_init__(self) -> None:
        if not self.name or not self.name.replace("_", "").replace("-", "").isalnum():
            raise ValueError(
                f"pipeline.stages[].name={self.name!r} must be a non-empty word (letters, "
                "digits, '_' or '-'): it names the stage's output folder"
            )
        check_choice(f"pipeline.stages[{self.name}].kind", self.kind, tuple(STAGE_KINDS))
        check_choice(f"pipeline.stages[{self.name}].use", self.use, ("best", "latest"))
        if (self.kind == "source") != (self.path is not None):
            raise ValueError(
                f"pipeline.stages[{self.name}]: path is given for kind source and only then"
            )
        if (self.kind == "graft") != (self.part is not None):
            raise ValueError(
                f"pipeline.stages[{self.name}]: part is given for kind graft and only then"
            )
        for item in self.overrides:
            if "=" not in item or item.startswith(("pipeline.", "=")):
                raise ValueError(
                    f"pipeline.stages[{self.name}].overrides: {item!r} must be key=value with "
                    "a key outside pipeline.*"
                )


@dataclass
class PipelineConfig:
    """The recipe's stages and where their outputs live (``pipeline.*``)."""

    stages: list[StageConfig] = field(default_factory=list)  # empty: one training run
    output_dir: str = "outputs/pipeline"  # keep it out of temporary space: stages resume here
    on_stale: str = "rerun"  # an output made from other inputs or settings: rerun | refuse

    def __post_init__(self) -> None:
        check_choice("pipeline.on_stale", self.on_stale, ON_STALE)
        seen: list[str] = []
        for stage in self.stages:
            if isinstance(stage, dict):  # OmegaConf hands list items as they were written
                stage = StageConfig(**stage)
            if stage.name in seen:
                raise ValueError(f"pipeline.stages: two stages are named {stage.name!r}")
            unknown = [name for name in stage.inputs if name not in seen]
            if unknown:
                raise ValueError(
                    f"pipeline.stages[{stage.name}].inputs names {unknown[0]!r}, which is not "
                    f"an earlier stage; earlier stages: {', '.join(seen) or 'none'}"
                )
            seen.append(stage.name)
