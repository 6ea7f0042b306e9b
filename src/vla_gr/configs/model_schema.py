"""Structured config of the navigation agent (``model.*``).

Nests one config per component; each lives beside its component in ``vla_gr.core``
(``model.encoders``: :mod:`vla_gr.core.encoders.config`, ``model.head``:
:mod:`vla_gr.core.diffusion_policy.config`, ``model.gr_field``:
:mod:`vla_gr.core.gr_field.config`, ``model.navigator``:
:mod:`vla_gr.agent.navigator.config` (one section per concern), ``model.schedule``
and ``model.s1``: :mod:`vla_gr.core.dual_system.config`, ``model.pursuit``:
:mod:`vla_gr.agent.followers.pure_pursuit`, ``model.goal_head``, ``model.grounding``,
``model.room_type``, ``model.object_category``, ``model.perception``:
:mod:`vla_gr.agent.perception`,
``model.instruction_reader``: :mod:`vla_gr.agent.reading`), so the defaults are written once.
The seed's latent ``DualSystemArchitecture`` (:class:`~vla_gr.core.dual_system.DualSystemConfig`)
is a building block no agent runs: it has no section here.

``model.agent`` picks the agent's class: ``dual_system`` (the VLA-GR agent, the default: S2 the
goal head and the GR field, S1 the controller) or ``end_to_end`` (encoders -> fusion -> action
head: the ablation without the GR field, which recipes name explicitly).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from vla_gr.agent.followers.pure_pursuit import PursuitConfig
from vla_gr.agent.navigator.config import NavigatorConfig
from vla_gr.agent.perception import (
    GoalHeadConfig,
    GroundingConfig,
    ObjectCategoryConfig,
    PerceptionConfig,
    RoomTypeConfig,
)
from vla_gr.agent.reading import ReaderConfig
from vla_gr.core.diffusion_policy.config import HeadConfig
from vla_gr.core.dual_system.config import S1Config, ScheduleConfig
from vla_gr.core.encoders.config import EncodersConfig
from vla_gr.core.gr_field.config import GRFieldConfig
from vla_gr.validation import check_choice, check_positive

PEFT_METHODS = ("lora", "oft", "adapter")
AGENTS = ("end_to_end", "dual_system")
#: Submodules ``model.freeze`` may name, per ``model.agent``.
FREEZABLE = {
    "end_to_end": ("vision", "text", "pose", "fusion", "head"),
    "dual_system": ("goal_head", "s1"),
}
#: Component fields that follow a model key (``(component, field) -> key``).
FOLLOWS = {
    ("head", "action_dim"): "action_dim",
    ("head", "horizon"): "horizon",
    ("head", "context_dim"): "encoders.dim",
    ("instruction_reader", "categories"): "object_category.categories",
    ("instruction_reader", "room_types"): "room_type.room_types",
}


@dataclass
class PeftConfig:
    """Parameter-efficient fine-tuning (``model.peft.*``), applied after building the model."""

    enabled: bool = False  # wrap target_modules with adapters (merged away for inference)
    method: str = "lora"  # lora | oft | adapter (bottleneck)
    lora_rank: int = 8  # LoRA rank r
    lora_alpha: float = 16.0  # LoRA scale: the update is multiplied by alpha / r
    lora_dropout: float = 0.0  # dropout on the LoRA branch's input
    oft_rank: int = 4  # number of OFT blocks (peft r); in_features must be divisible by it
    adapter_bottleneck: int = 32  # width of the bottleneck adapter
    target_modules: list[str] = field(
        default_factory=lambda: ["q_proj", "k_proj", "v_proj", "out_proj"]
    )  # names of the Linear layers adapted

    def __post_init__(self) -> None:
        check_choice("model.peft.method", self.method, PEFT_METHODS)
        check_positive("model.peft.lora_rank", self.lora_rank)
        check_positive("model.peft.lora_alpha", self.lora_alpha)
        if not 0.0 <= self.lora_dropout < 1.0:
            raise ValueError(f"model.peft.lora_dropout={self.lora_dropout} must be in [0, 1)")
        check_positive("model.peft.oft_rank", self.oft_rank)
        check_positive("model.peft.adapter_bottleneck", self.adapter_bottleneck)
        if self.enabled and not self.target_modules:
            raise ValueError("model.peft.target_modules must name at least one module")


@dataclass
class ModelConfig:
    """The agent: observation layout, one config per component, freezing and PEFT.

    The fields in ``FOLLOWS`` (``head.action_dim``, ``head.horizon``, ``head.context_dim``,
    ``categories`` / ``room_types`` of ``instruction_reader``)
    follow the model's keys (set those); setting them to something else fails.
    ``model.agent=dual_system`` composes ``goal_head`` (S2's grounding), ``navigator`` on
    ``gr_field`` (S2's plan) and ``s1`` (the learned S1; ``pursuit`` when
    ``s1.kind=pure_pursuit``), scheduled by ``schedule``'s ``planning_frequency_hz`` /
    ``control_frequency_hz``; the end-to-end agent uses ``encoders`` and ``head``.
    """

    # Observation / action layout (LeRobot names), shared with the training windows.
    n_obs_steps: int = 2  # observation frames per decision (the latest and history)
    horizon: int = 16  # actions per predicted chunk
    n_action_steps: int = 8  # actions of a chunk executed before the next prediction
    action_dim: int = 3  # the world's action: (linear, angular, stop)
    image_size: int = 64  # the agent's input size (follows env.image_size)
    agent: str = "dual_system"  # dual_system (S2 goal head + GR field, S1) | end_to_end
    encoders: EncodersConfig = field(default_factory=EncodersConfig)
    head: HeadConfig = field(default_factory=HeadConfig)
    gr_field: GRFieldConfig = field(default_factory=GRFieldConfig)
    goal_head: GoalHeadConfig = field(default_factory=GoalHeadConfig)  # S2's grounding
    grounding: GroundingConfig = field(default_factory=GroundingConfig)  # its loss, metrics
    room_type: RoomTypeConfig = field(default_factory=RoomTypeConfig)  # S2's room check
    object_category: ObjectCategoryConfig = field(
        default_factory=ObjectCategoryConfig
    )  # S2's object-category check
    instruction_reader: ReaderConfig = field(
        default_factory=ReaderConfig
    )  # the request read into fields: what the goal head and the checks look for
    perception: PerceptionConfig = field(
        default_factory=PerceptionConfig
    )  # what runs S2's networks at inference: torch | onnxruntime (the checkpoint's export)
    navigator: NavigatorConfig = field(default_factory=NavigatorConfig)  # S2's behaviour
    schedule: ScheduleConfig = field(default_factory=ScheduleConfig)  # S2 and S1 rates
    pursuit: PursuitConfig = field(default_factory=PursuitConfig)  # S1 ablation: follower
    s1: S1Config = field(default_factory=S1Config)  # S1: the learned controller
    freeze: list[str] = field(default_factory=list)  # submodules whose weights stay fixed
    peft: PeftConfig = field(default_factory=PeftConfig)

    def __post_init__(self) -> None:
        for key in ("n_obs_steps", "horizon", "n_action_steps", "action_dim"):
            check_positive(f"model.{key}", getattr(self, key))
        if self.n_action_steps > self.horizon:
            raise ValueError(
                f"model.n_action_steps={self.n_action_steps} must be <= "
                f"model.horizon={self.horizon}"
            )
        if not 16 <= self.image_size <= 512:
            raise ValueError(f"model.image_size={self.image_size} must be in [16, 512]")
        check_choice("model.agent", self.agent, AGENTS)
        for name in self.freeze:
            check_choice(f"model.freeze[] (model.agent={self.agent})", name, FREEZABLE[self.agent])
        for check in ("room_type", "object_category", "instruction_reader"):
            if getattr(self, check).enabled and self.agent != "dual_system":
                raise ValueError(
                    f"model.{check}.enabled=true needs model.agent=dual_system (got {self.agent})"
                )
        stride = 2 ** len(self.goal_head.channels)
        if self.agent == "dual_system" and self.image_size % stride:
            raise ValueError(
                f"model.image_size={self.image_size} must be divisible by {stride} for the goal "
                f"head's {len(self.goal_head.channels)} stages (model.goal_head.channels)"
            )
        for (component, attr), key in FOLLOWS.items():
            setattr(self, component, _follow(self, component, attr, key))


def _follow(model: ModelConfig, component: str, attr: str, key: str):
    """``model.<component>`` with ``attr`` set to ``model.<key>``.

    A field left at its default follows the model; one set to another value is an error.
    """
    config = getattr(model, component)
    value = model
    for part in key.split("."):
        value = getattr(value, part)
    current = getattr(config, attr)
    if current not in (value, getattr(type(config)(), attr)):
        raise ValueError(
            f"model.{component}.{attr}={current} contradicts model.{key}={value}; "
            f"set model.{key} instead"
        )
    return replace(config, **{attr: value})
