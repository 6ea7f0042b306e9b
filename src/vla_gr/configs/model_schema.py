"""Structured config of the navigation agent (``model.*``): encoders, action head, PEFT."""

from __future__ import annotations

from dataclasses import dataclass, field

from vla_gr.validation import check_choice, check_positive

TEXT_ENCODERS = ("hashed", "minilm")
VISION_POOLS = ("grid", "spatial_softmax")
OBJECTIVES = ("flow_matching", "diffusion", "l1")
DENOISERS = ("unet1d", "transformer")
PREDICTION_TYPES = ("epsilon", "sample", "v_prediction")
SAMPLERS = {
    "flow_matching": ("euler", "midpoint"),
    "diffusion": ("ddim", "ddpm"),
    "l1": ("none", "euler", "midpoint", "ddim", "ddpm"),
}
PEFT_METHODS = ("lora", "oft", "adapter")
FREEZABLE = ("vision", "text", "pose", "fusion", "head")


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
    """The agent: RGB-D CNN + instruction encoder + pose MLP -> tokens -> action head."""

    # Observation / action layout (LeRobot names).
    n_obs_steps: int = 2
    horizon: int = 16
    n_action_steps: int = 8
    action_dim: int = 3
    image_size: int = 64
    # Encoders.
    dim: int = 128  # width D of every context token
    vision_channels: list[int] = field(default_factory=lambda: [32, 64, 64])
    vision_pool: str = "grid"
    vision_tokens: int = 4  # grid: tokens per frame (a square); spatial_softmax: keypoints
    max_depth: float = 10.0  # metres; depth is clipped and scaled to [0, 1]
    text_encoder: str = "hashed"
    text_buckets: int = 4096  # hashed bag-of-words vocabulary
    pose_hidden: int = 64
    fusion_layers: int = 1  # transformer blocks over the context tokens (0 = none)
    fusion_heads: int = 4
    dropout: float = 0.0
    # Action head (core.diffusion_policy.DiffusionPolicy).
    objective: str = "flow_matching"
    denoiser: str = "unet1d"
    hidden_dim: int = 128
    head_layers: int = 2  # transformer denoiser / L1 head blocks
    head_heads: int = 4
    num_diffusion_steps: int = 100
    prediction_type: str = "epsilon"
    num_inference_steps: int = 5
    sampler: str = "euler"  # flow_matching: euler | midpoint; diffusion: ddim | ddpm; l1: none
    # Memory / fine-tuning.
    gradient_checkpointing: bool = False
    freeze: list[str] = field(default_factory=list)  # submodules whose weights stay fixed
    peft: PeftConfig = field(default_factory=PeftConfig)

    def __post_init__(self) -> None:
        for key in ("n_obs_steps", "horizon", "n_action_steps", "action_dim", "dim"):
            check_positive(f"model.{key}", getattr(self, key))
        if self.n_action_steps > self.horizon:
            raise ValueError(
                f"model.n_action_steps={self.n_action_steps} must be <= "
                f"model.horizon={self.horizon}"
            )
        if not 16 <= self.image_size <= 512:
            raise ValueError(f"model.image_size={self.image_size} must be in [16, 512]")
        if not self.vision_channels or min(self.vision_channels) < 1:
            raise ValueError(
                f"model.vision_channels={self.vision_channels} must be a non-empty "
                "list of positive widths"
            )
        check_choice("model.vision_pool", self.vision_pool, VISION_POOLS)
        check_positive("model.vision_tokens", self.vision_tokens)
        if self.vision_pool == "grid" and int(self.vision_tokens**0.5) ** 2 != self.vision_tokens:
            raise ValueError(
                f"model.vision_tokens={self.vision_tokens} must be a square (1, 4, 9, ...) "
                "with model.vision_pool=grid"
            )
        check_positive("model.max_depth", self.max_depth)
        check_choice("model.text_encoder", self.text_encoder, TEXT_ENCODERS)
        check_positive("model.text_buckets", self.text_buckets)
        check_positive("model.pose_hidden", self.pose_hidden)
        check_positive("model.fusion_layers", self.fusion_layers, allow_zero=True)
        check_positive("model.fusion_heads", self.fusion_heads)
        if self.dim % self.fusion_heads:
            raise ValueError(
                f"model.dim={self.dim} must be divisible by model.fusion_heads={self.fusion_heads}"
            )
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"model.dropout={self.dropout} must be in [0, 1)")
        check_choice("model.objective", self.objective, OBJECTIVES)
        check_choice("model.denoiser", self.denoiser, DENOISERS)
        check_positive("model.hidden_dim", self.hidden_dim)
        check_positive("model.num_diffusion_steps", self.num_diffusion_steps)
        check_choice("model.prediction_type", self.prediction_type, PREDICTION_TYPES)
        check_positive("model.num_inference_steps", self.num_inference_steps)
        check_positive("model.head_layers", self.head_layers)
        check_positive("model.head_heads", self.head_heads)
        check_choice(
            f"model.sampler (objective {self.objective})", self.sampler, SAMPLERS[self.objective]
        )
        for name in self.freeze:
            check_choice("model.freeze[]", name, FREEZABLE)
