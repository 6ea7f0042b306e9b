"""Structured config of the navigation agent (``model.*``).

Nests one config per component; each lives beside its component in ``vla_gr.core``
(``model.encoders``: :mod:`vla_gr.core.encoders.config`, ``model.head``:
:mod:`vla_gr.core.diffusion_policy.config`, ``model.gr_field``:
:mod:`vla_gr.core.gr_field.config`, ``model.dual_system``:
:mod:`vla_gr.core.dual_system.config`), so the defaults are written once.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from vla_gr.core.diffusion_policy.config import HeadConfig
from vla_gr.core.dual_system.config import DualSystemConfig
from vla_gr.core.encoders.config import EncodersConfig
from vla_gr.core.gr_field.config import GRFieldConfig
from vla_gr.validation import check_choice, check_positive

PEFT_METHODS = ("lora", "oft", "adapter")
FREEZABLE = ("vision", "text", "pose", "fusion", "head")
#: Component fields that follow a model key (``(component, field) -> key``).
FOLLOWS = {
    ("head", "action_dim"): "action_dim",
    ("head", "horizon"): "horizon",
    ("head", "context_dim"): "encoders.dim",
    ("dual_system", "action_dim"): "action_dim",
}


@dataclass
class PeftConfig:
    """Parameter-efficient fine-tuning (``model.peft.*``), applied after building the model."""

    enabled: bool = False
    method: str = "lora"
    lora_rank: int = 8
    lora_alpha: float = 16.0
    lora_dropout: float = 0.0
    oft_rank: int = 4  # number of OFT blocks (peft r); in_features must be divisible by it
    adapter_bottleneck: int = 32
    target_modules: list[str] = field(
        default_factory=lambda: ["q_proj", "k_proj", "v_proj", "out_proj"]
    )

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
    ``dual_system.action_dim``) follow the model's keys (set those); setting them to
    something else fails.
    ``gr_field`` and ``dual_system`` configure components that ``VLAGRPolicy`` does not
    compose yet.
    """

    # Observation / action layout (LeRobot names), shared with the training windows.
    n_obs_steps: int = 2
    horizon: int = 16
    n_action_steps: int = 8
    action_dim: int = 3  # the world's action: (linear, angular, stop)
    image_size: int = 64
    encoders: EncodersConfig = field(default_factory=EncodersConfig)
    head: HeadConfig = field(default_factory=HeadConfig)
    gr_field: GRFieldConfig = field(default_factory=GRFieldConfig)
    dual_system: DualSystemConfig = field(default_factory=DualSystemConfig)
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
        for name in self.freeze:
            check_choice("model.freeze[]", name, FREEZABLE)
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
